"""The simulated rig end to end: servos on a pty, the link, the rendered camera, the merge and the model."""

from __future__ import annotations

import numpy as np
import pytest

import model as m
from acquisition.hdr.merge import merge_linear
from acquisition.roi import reduce_roi
from rig.instrument.kinematics import Joints, forward, inverse, require
from simulator.rig import SimRigSpec, SimulatedRig, SimulatedRigError

pytestmark = pytest.mark.mitsuba


def predicted_counts(rig: SimulatedRig, joints: Joints) -> np.ndarray:
    """The model's reading in counts/s at the directions the joints give (the ROI centre, point light)."""
    d = forward(rig.spec.geometry, joints)
    light = m.PointLight(intensity=rig.spec.light.rgb()[0], distance=rig.spec.geometry.light_radius_m)
    radiance = m.predict_radiance(rig.spec.material, d.wi, d.wo, light)
    assert rig.camera is not None
    return np.asarray(radiance) * rig.camera.optics.counts_per_radiance(rig.spec.noise)


def measure(rig: SimulatedRig, exposures: tuple[float, ...]) -> np.ndarray:
    assert rig.camera is not None
    frames = []
    for t in exposures:
        rig.camera.set_exposure(t)
        frames.append(rig.camera.capture())
    hdr = merge_linear(frames, rig.spec.noise)
    h, w = hdr.radiance.shape[:2]
    reading = reduce_roi(hdr.radiance, hdr.variance, (0, 0, w, h), flags=hdr.saturated)
    return np.asarray(reading.mean)


@pytest.mark.parametrize(("theta_i", "theta_o"), [(0.0, 30.0), (30.0, 45.0), (50.0, 20.0)])
def test_readings_match_the_model_at_the_pose_the_servos_hold(theta_i: float, theta_o: float) -> None:
    with SimulatedRig(SimRigSpec(seed=2)) as rig, rig.open_link() as link:
        target = require(inverse(rig.spec.geometry, theta_i, 0.0, theta_o, 180.0))
        link.move_to(target.as_dict())
        actual = Joints.from_dict(link.wait_in_position(timeout_s=30.0))
        reading = measure(rig, (0.02, 0.02))
        expected = predicted_counts(rig, actual)
        # Point light on a finite ROI: the law curves across it by well under 1 %; shot noise is ~0.1 %.
        np.testing.assert_allclose(reading, expected, rtol=0.01)
        assert rig.renders == 2  # one radiance lookup per capture; the second one hits the render cache
        assert rig.renderer.stats.hits >= 1


def test_servo_errors_reach_the_images() -> None:
    with SimulatedRig(SimRigSpec(seed=3)) as rig, rig.open_link() as link:
        assert rig.bus is not None
        target = require(inverse(rig.spec.geometry, 45.0, 0.0, 30.0, 180.0))
        link.move_to(target.as_dict())
        link.wait_in_position(timeout_s=30.0)
        nominal = measure(rig, (0.02,))
        # 120 ticks of play: the encoder (and the link) see the goal, the light arm is 5.3 deg off.
        rig.bus.servo(1).mechanics.backlash_ticks = 120.0
        link.move_to({"light": 50.0})
        link.wait_in_position(timeout_s=30.0)
        link.move_to(target.as_dict())
        held = link.wait_in_position(timeout_s=30.0)
        assert held["light"] == pytest.approx(target.light, abs=0.2)
        shifted = measure(rig, (0.02,))
        physical = rig.joints_now()
        assert abs(physical.light - target.light) == pytest.approx(60.0 / (4096 / 360), abs=0.1)
        np.testing.assert_allclose(shifted, predicted_counts(rig, physical), rtol=0.01)
        assert not np.allclose(shifted, nominal, rtol=0.01)


def test_only_one_simulated_rig_per_process() -> None:
    with SimulatedRig() as rig:
        with pytest.raises(SimulatedRigError, match=r"already running in this process \(bus on /dev/pts/"):
            SimulatedRig().start()
        assert rig.port.startswith("/dev/pts/")
    with SimulatedRig():  # closed rigs release the slot
        pass


def test_a_rig_not_started_says_so() -> None:
    with pytest.raises(SimulatedRigError, match="not running"):
        _ = SimulatedRig().port
