"""The simulated rig described by a rig file: its geometry, axes, camera, reference tile and material."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping

from acquisition.noise import SensorNoise
from rig.instrument.alignment import Alignment
from rig.run.config.files import ConfigError, RigConfig, material_from
from rig.run.config.schema import Misalignment
from simulator.camera.pixels import PixelResponse
from simulator.render.spec import CameraSpec, LightSpec
from simulator.rig import SimRigSpec, SimulatedRig


def spec_from(rig: RigConfig, *, camera: CameraSpec | None = None) -> SimRigSpec:
    """A SimRigSpec from a validated rig file (link kind 'simulated').

    ``camera`` stands in for the file's simulated camera: the rehearsal (:mod:`simulator.rehearsal`) serves a
    hardware rig file, whose ``[camera]`` describes a real camera, and with it any link kind is taken.
    """
    f = rig.file
    if f.link.kind != "simulated" and camera is None:
        raise ConfigError(f"{rig.path}: link.kind = {f.link.kind!r}: the simulated rig needs 'simulated'")
    cam = f.camera
    sim = f.simulation
    mis = sim.misalignment
    # The sensor as it is ([simulation.sensor]), each key it leaves out as the controller assumes ([camera.noise]).
    truth = {k: v for k, v in sim.sensor.model_dump().items()
             if k in SensorNoise.__dataclass_fields__ and v is not None}  # fmt: skip
    try:
        noise = SensorNoise(**{**cam.noise.model_dump(), **truth})
    except ValueError as exc:
        raise ConfigError(f"{rig.path}: simulation.sensor: {exc}") from None
    response = PixelResponse(vignetting=sim.sensor.vignetting, prnu_rms=sim.sensor.prnu_rms,
                             nonlinearity=sim.sensor.nonlinearity, seed=sim.seed)  # fmt: skip
    albedo = f.reference.albedo
    try:
        light = LightSpec(kind=sim.light_kind, intensity=sim.light_intensity_w_sr, size_m=mis.light_size_mm * 1e-3,
                          falloff=mis.beam_falloff)  # fmt: skip
    except ValueError as exc:
        raise ConfigError(f"{rig.path}: simulation.misalignment: {exc}") from None
    return SimRigSpec(
        geometry=rig.geometry,
        material=material_from(rig),
        light=light,
        camera=camera or CameraSpec(resolution=cam.resolution, roi=cam.roi, spp=cam.spp, variant=cam.variant),
        noise=noise,
        axes=rig.axes,
        baudrate=f.link.baudrate,
        fixed_pattern_dn=sim.fixed_pattern_dn,
        time_scale=sim.time_scale,
        seed=sim.seed,
        reference_albedo=albedo if isinstance(albedo, float) else (albedo[0], albedo[1], albedo[2]),
        misalignment=alignment_from(mis),
        stray_light_counts_s=mis.stray_light,
        lamp_drift=mis.lamp_drift,
        lamp_warmup_s=mis.lamp_warmup_s,
        settle_ticks=mis.joint_settle_ticks,
        backlash_deg=mis.backlash_deg,
        camera_output=sim.camera_output,
        response=response,
        sample_shape=rig.sample_shape,
    )


def alignment_from(table: Misalignment) -> Alignment:
    """The geometric part of ``[simulation.misalignment]`` as an Alignment (the simulated rig's truth)."""
    return Alignment(**table.model_dump(include={f.name for f in dataclasses.fields(Alignment)}))


def rig_from(
    rig: RigConfig, *, spec: SimRigSpec | None = None, start: Mapping[str, float] | None = None
) -> SimulatedRig:
    """The (unstarted) simulated rig of a rig file, on the link its ``[simulation] link`` names.

    ``spec`` replaces ``spec_from(rig)`` (a test's variation of it); ``start`` is where the axes stand (degrees).
    """
    cls: type[SimulatedRig] = SimulatedRig
    if rig.file.simulation.link == "grbl":
        from simulator.grbl_rig import SimulatedGrblRig  # here: a servo rig's run need not wait for GRBL's modules

        cls = SimulatedGrblRig
    return cls(spec if spec is not None else spec_from(rig), start=start)
