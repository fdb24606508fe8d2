"""The simulated rig as imperfect as a real one: it renders the true pose, and the light, the room and the
lamp are not ideal either ([simulation.misalignment], hidden from the controller)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import model as m
from model.mitsuba.materials import to_mitsuba
from rig.instrument.alignment import Alignment, aligned_forward, aligned_pose
from rig.instrument.clock import ManualClock
from rig.instrument.kinematics import Joints, forward, inverse, require, world_pose
from rig.run.config.files import ConfigError, parse, rig_config
from rig.run.config.schema import RigFile
from simulator.from_config import spec_from
from simulator.render.spec import CameraSpec, LightSpec
from simulator.rig import SimRigSpec, SimulatedRig

pytestmark = pytest.mark.mitsuba

MISALIGNED = Alignment(
    light_zero_deg=0.6, camera_zero_deg=-0.4, tilt_zero_deg=0.3, roll_zero_deg=0.8,
    sample_tilt_deg=0.7, sample_tilt_azimuth_deg=35.0, sample_offset_mm=(1.0, -1.5, 0.8),
)  # fmt: skip


def _at(rig: SimulatedRig, joints: Joints) -> Joints:
    with rig.open_link() as link:
        link.move_to(joints.as_dict())
        return Joints.from_dict(link.wait_in_position(timeout_s=30.0))


def test_frames_come_from_the_true_pose_and_the_roi_from_the_drawn_one() -> None:
    spec = SimRigSpec(material=m.Lambert(0.5), seed=4, misalignment=MISALIGNED, camera=CameraSpec((32, 32)))
    with SimulatedRig(spec) as rig:
        joints = _at(rig, require(inverse(spec.geometry, 30.0, 0.0, 40.0, 180.0)))
        got = rig.radiance_now()
        drawn = world_pose(spec.geometry, joints)
        true = aligned_pose(spec.geometry, joints, MISALIGNED)
        crop = rig.renderer.roi(drawn)
        want = rig.renderer.render(true, to_mitsuba(spec.material), crop=crop, key=repr(spec.material), seed=spec.seed)
        np.testing.assert_array_equal(got, want)
        nominal = rig.renderer.render(drawn, to_mitsuba(spec.material), crop=crop, key=repr(spec.material),
                                       seed=spec.seed)
        assert not np.allclose(got, nominal, rtol=1e-3)


def _peak_camera(mis: Alignment, cameras: np.ndarray, start: Joints) -> float:
    """Camera angle (deg, reported) of a near-mirror's brightest ROI, to a fraction of the scan's step."""
    material = m.CookTorrance(alpha=0.02, eta=1.5, fresnel="dielectric")
    spec = SimRigSpec(material=material, seed=1, misalignment=mis, camera=CameraSpec((16, 16), roi=(7, 7, 9, 9)))
    with SimulatedRig(spec) as rig:
        assert rig.bus is not None
        readings = []
        for c in cameras:
            joints = dataclasses.replace(start, camera=float(c))
            for a in rig.axes:  # place the servos directly: this test is about the optics, not the motion
                rig.bus.servo(int(a.address)).place(a.to_units(joints.as_dict()[a.name]))
            readings.append(float(np.mean(rig.radiance_now())))
    k = int(np.clip(np.argmax(readings), 1, len(readings) - 2))
    lo, mid, hi = readings[k - 1 : k + 2]
    step = float(cameras[1] - cameras[0])
    return float(cameras[k]) + 0.5 * step * (lo - hi) / (lo - 2 * mid + hi)  # the parabola's vertex


def test_a_glossy_peak_moves_where_the_true_geometry_puts_it() -> None:
    """Scanning the camera through a near-mirror's peak finds it where aligned_forward says, not forward."""
    g = SimRigSpec().geometry
    mis = Alignment(camera_zero_deg=0.5)
    start = require(inverse(g, 30.0, 0.0, 30.0, 180.0))
    cameras = start.camera + np.linspace(-1.5, 1.5, 61)
    # Against the same scan on the perfect rig: a 2 x 2 px ROI of a 16 px frame sees the peak a little off the
    # ideal direction on both, and the difference is the joint's zero alone.
    perfect = _peak_camera(Alignment(), cameras, start)
    peak = _peak_camera(mis, cameras, start)
    # The camera physically stands at reported - zero: the mirror sits 0.5 deg further along.
    assert peak - perfect == pytest.approx(0.5, abs=0.02)
    at_peak = dataclasses.replace(start, camera=peak - (perfect - start.camera))
    # The true geometry puts the mirror direction there; the drawn kinematics would call it 29.5 deg.
    assert abs(aligned_forward(g, at_peak, mis).theta_o - 30.0) < 0.02
    assert abs(forward(g, at_peak).theta_o - 29.5) < 0.02


def test_a_disk_light_keeps_the_intensity_and_blurs_a_mirror() -> None:
    g = SimRigSpec().geometry
    joints = require(inverse(g, 30.0, 0.0, 30.0, 180.0))
    roi = CameraSpec((256, 256), roi=(127, 127, 129, 129))  # pixels far finer than the lobe
    readings = {}
    for name, material in (
        ("matte", m.Lambert(0.5)),
        ("mirror", m.CookTorrance(alpha=0.005, eta=1.5, fresnel="dielectric")),
    ):
        for size in (0.0, 0.02):
            spec = SimRigSpec(
                material=material, light=LightSpec(intensity=1.0, size_m=size), camera=dataclasses.replace(roi, spp=64)
            )
            with SimulatedRig(spec) as rig:
                assert rig.bus is not None
                for a in rig.axes:
                    rig.bus.servo(int(a.address)).place(a.to_units(joints.as_dict()[a.name]))
                readings[name, size] = float(np.mean(rig.radiance_now()))
    assert readings["matte", 0.02] == pytest.approx(readings["matte", 0.0], rel=0.01)
    # A 20 mm disk at 0.5 m spans 2.3 deg, far wider than the alpha 0.005 lobe: the peak drops by far.
    assert readings["mirror", 0.02] < 0.5 * readings["mirror", 0.0]


def test_beam_falloff_dims_the_spot_by_its_fraction_at_the_edge() -> None:
    g = SimRigSpec().geometry
    light = LightSpec(falloff=0.2)
    edge = light.edge_deg(g)
    assert edge == pytest.approx(math.degrees(math.atan2(0.025, 0.5)))
    joints = require(inverse(g, 0.0, 0.0, 30.0, 180.0))
    cam = CameraSpec((64, 64))
    flat, dim = (SimRigSpec(material=m.Lambert(0.5), light=lt, camera=cam) for lt in (LightSpec(), light))
    images = []
    for spec in (flat, dim):
        with SimulatedRig(spec) as rig:
            assert rig.bus is not None
            for a in rig.axes:
                rig.bus.servo(int(a.address)).place(a.to_units(joints.as_dict()[a.name]))
            images.append(rig.radiance_now(full_frame=True)[..., 1])
    ratio = images[1] / np.where(images[0] > 0, images[0], np.nan)
    assert np.nanmax(ratio) == pytest.approx(1.0, abs=1e-3)  # on the axis: no change
    assert np.nanmin(ratio) < 0.85  # towards the sample's corners, more than the edge's 0.8 x ... 1 / sqrt 2 beyond
    assert np.nanmin(ratio) >= 0.0


def test_stray_light_reaches_light_frames_only() -> None:
    spec = SimRigSpec(material=m.Lambert(0.5), seed=2, stray_light_counts_s=5000.0, camera=CameraSpec((16, 16)))
    with SimulatedRig(spec) as rig:
        cam = rig.camera
        assert cam is not None
        cam.set_exposure(0.1)
        base = cam.rate_counts_per_s().mean()
        black = rig.spec.noise.black_level_dn
        light = (cam.capture().data.astype(float) - black).mean() / 0.1
        dark = (cam.capture_dark().data.astype(float) - black).mean()
    assert light == pytest.approx(base + 5000.0, rel=0.01)
    assert abs(dark) < 5.0


def test_the_lamp_warms_up_on_rig_time() -> None:
    spec = SimRigSpec(material=m.Lambert(0.5), lamp_drift=0.03, lamp_warmup_s=300.0, camera=CameraSpec((16, 16)))
    with SimulatedRig(spec) as rig:
        assert isinstance(rig.clock, ManualClock)
        first = rig.radiance_now().mean()
        rig.clock.advance(300.0)
        assert rig.lamp_factor() == pytest.approx(1.0 + 0.03 * (1.0 - math.exp(-1.0)))
        assert rig.radiance_now().mean() == pytest.approx(first * rig.lamp_factor(), rel=1e-12)


def test_the_rig_file_names_every_imperfection_and_checks_it() -> None:
    table = {"light_zero_deg": 0.4, "sample_tilt_deg": 0.5, "sample_tilt_azimuth_deg": 20.0,
             "sample_offset_mm": [1.0, 2.0, -0.5], "light_size_mm": 5.0, "beam_falloff": 0.1, "stray_light": 200.0,
             "lamp_drift": 0.02, "lamp_warmup_s": 900.0, "joint_settle_ticks": 1.0}  # fmt: skip
    doc = {"simulation": {"misalignment": table}}
    spec = spec_from(rig_config(parse(doc, RigFile, "rig.toml"), "rig.toml"))
    assert spec.misalignment == Alignment(light_zero_deg=0.4, sample_tilt_deg=0.5, sample_tilt_azimuth_deg=20.0,
                                          sample_offset_mm=(1.0, 2.0, -0.5))  # fmt: skip
    assert spec.light.size_m == pytest.approx(0.005) and spec.light.falloff == 0.1
    assert (spec.stray_light_counts_s, spec.lamp_drift, spec.lamp_warmup_s) == (200.0, 0.02, 900.0)
    assert spec.settle_ticks == 1.0
    with SimulatedRig(dataclasses.replace(spec, camera=CameraSpec((8, 8)))) as rig:
        assert rig.bus is not None
        assert all(rig.bus.servo(int(a.address)).mechanics.settle_ticks == 1.0 for a in rig.axes)
    assert spec_from(rig_config(parse({}, RigFile, "rig.toml"), "rig.toml")).misalignment.is_zero
    with pytest.raises(ConfigError, match=r"simulation\.misalignment\.sample_tilt_deg = -1\.0: expected"):
        parse({"simulation": {"misalignment": {"sample_tilt_deg": -1.0}}}, RigFile, "rig.toml")
    with pytest.raises(ConfigError, match=r"simulation\.misalignment\.tilt_zero = 1\.0: unknown key; expected one of"):
        parse({"simulation": {"misalignment": {"tilt_zero": 1.0}}}, RigFile, "rig.toml")
