"""The schema of rig and sweep files (TOML): every table, key, type, unit and default, validated strictly.

Unknown keys are errors, types are not coerced (a string is never a number), and numbers carry their bounds
where they are defined (``rig.run.config.strict``: the base of every table, the bounded number types).
``rig.run.config.files`` loads files against these models and turns pydantic's errors into messages that name
the file, the key, the value and what was expected.

Rig file tables: ``[geometry]`` (and ``[geometry.limits]``), ``[link]``, ``[axes.<joint>]``, ``[camera]``
(``[camera.noise]``, ``[camera.options]``; in ``rig.run.config.camera``, which says where the keys each camera
backend reads are written), ``[reference]``, ``[simulation]`` (``[simulation.material]``,
``[simulation.sensor]``, ``[simulation.misalignment]``; the simulator reads them through this validation),
``[sample]`` (the sample's shape).
Sweep file tables: ``[sweep]`` and ``[capture]``. Both files may have ``[metadata]`` (``sample``, ``operator``,
``notes`` and free keys), which a run carries into its manifest, its tables and the report. See
examples/*.toml for annotated files.
"""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field, field_validator, model_validator

from rig.run import registry
from rig.run.config.camera import Camera
from rig.run.config.sample import Sample
from rig.run.config.strict import (
    Channels,
    Deg90,
    Finite,
    Levels,
    Metres,
    NonNeg,
    Pair,
    Pos,
    Seconds,
    Seed,
    Strict,
    one_of,
)


class Limits(Strict):
    """``[geometry.limits]``: soft limits [min_deg, max_deg] per joint, in degrees."""

    light: Pair = (-180.0, 180.0)
    camera: Pair = (-180.0, 180.0)
    tilt: Pair = (-90.0, 90.0)
    roll: Pair = (-180.0, 180.0)
    yaw: Pair = (-180.0, 180.0)


class Geometry(Strict):
    """``[geometry]``: the rig's layout, arm radii and sample size in metres, angles in degrees.

    ``calibration``: a ``geometry_calibration.json`` (``gonio calibrate geometry``; relative to the rig
    file) whose joint zeros, sample tilt and offset the kinematics correct for.
    """

    layout: Literal["four_axis", "in_plane", "fixed_camera"] = "four_axis"
    light_radius_m: Metres = 0.5
    camera_radius_m: Metres = 0.5
    sample_width_m: Metres = 0.05
    sample_height_m: Metres = 0.05
    min_separation_deg: Annotated[float, Field(ge=0, lt=180)] = 8.0
    max_zenith_deg: Annotated[float, Field(gt=0, lt=90)] = 85.0
    camera_fov_deg: Annotated[float, Field(gt=0, lt=180)] = 8.0
    beam_half_angle_deg: Annotated[float, Field(gt=0, lt=90)] = 0.25
    camera_azimuth_deg: Finite = 0.0
    plane_azimuth_deg: Finite = 0.0
    limits: Limits = Limits()
    calibration: str | None = None


class Link(Strict):
    """``[link]``: how the controller reaches the servos, and what it does when it stops.

    ``kind`` names a registered rig backend (``gonio.backends``: simulated, dynamixel, grbl, or a lab's own).
    """

    kind: str = "simulated"
    port: str | None = None
    baudrate: Annotated[int, Field(gt=0, le=20_000_000)] = 1_000_000  # the fastest serial adapters: 12 Mbaud
    retries: Annotated[int, Field(ge=0, le=20)] = 2
    latency_timer_ms: Annotated[float, Field(ge=0, le=1000)] = 16.0
    poll_interval_s: Annotated[float, Field(gt=0, le=5)] = 0.02
    move_timeout_s: Annotated[float, Field(gt=0, le=3600)] = 60.0
    settle_s: Annotated[float, Field(ge=0, le=600)] = 0.0
    on_stop: Literal["torque_off", "hold"] = "torque_off"
    allow_reboot: bool = False
    #: Known play of every joint's gears (deg of joint), unless its [axes.<joint>] table says otherwise.
    backlash_deg: Annotated[float, Field(ge=0, le=10, allow_inf_nan=False)] = 0.0
    #: Anti-backlash approach (deg of joint): every pose is reached by overshooting this far and coming back
    #: from one side, so the load rests against the same flank; 0 moves straight there.
    backlash_approach_deg: Annotated[float, Field(ge=0, le=20, allow_inf_nan=False)] = 0.0

    @field_validator("kind")
    @classmethod
    def _registered(cls, value: str) -> str:
        return one_of(value, registry.names())

    @model_validator(mode="after")
    def _port_for_hardware(self) -> Link:
        if registry.load(self.kind).needs_port and not self.port:
            without = [n for n in registry.names() if not registry.load(n).needs_port]
            raise ValueError(
                f"a {self.kind} link needs port (e.g. '/dev/ttyUSB0'); only {registry.listing(without)} has none"
            )
        return self


class AxisTable(Strict):
    """``[axes.<joint>]``: one servo or motor axis; lengths in degrees of the joint, times in seconds."""

    id: Annotated[int, Field(ge=0, le=252)] | None = None
    letter: Literal["X", "Y", "Z", "A", "B", "C"] | None = None
    # Upper bounds far beyond any joint: they keep move-time and path arithmetic finite.
    units_per_degree: Annotated[float, Field(gt=0, le=1e7, allow_inf_nan=False)] | None = None
    gear_ratio: Annotated[float, Field(gt=0, le=1e4, allow_inf_nan=False)] = 1.0
    # None = left out (1 and -180 deg, or a simulated GRBL's homing): a run's manifest writes every default out,
    # so "left out" must be a value that survives the dump, not a key missing from it.
    direction: Literal[1, -1] | None = None
    zero_offset_deg: Annotated[float, Field(ge=-1e6, le=1e6, allow_inf_nan=False)] | None = None
    min_deg: Annotated[float, Field(ge=-1e6, le=1e6, allow_inf_nan=False)] | None = None
    max_deg: Annotated[float, Field(ge=-1e6, le=1e6, allow_inf_nan=False)] | None = None
    max_speed_deg_s: Annotated[float, Field(gt=0, le=1e5, allow_inf_nan=False)] = 60.0
    max_accel_deg_s2: Annotated[float, Field(gt=0, le=1e7, allow_inf_nan=False)] = 120.0
    tolerance_deg: Annotated[float, Field(gt=0, le=90, allow_inf_nan=False)] = 0.2
    #: Known play between this joint's motor and its load (deg of joint); [link] backlash_deg if left out.
    backlash_deg: Annotated[float, Field(ge=0, le=10, allow_inf_nan=False)] | None = None

    @model_validator(mode="after")
    def _one_address(self) -> AxisTable:
        if (self.id is None) == (self.letter is None):
            raise ValueError("give exactly one of id (a Dynamixel id) or letter (a GRBL axis)")
        return self


class Reference(Strict):
    """``[reference]``: the Lambertian reference target, where it is measured and how often."""

    kind: Literal["simulated", "manual", "none"] = "simulated"
    albedo: Channels = 0.99
    albedo_std_error: Annotated[float, Field(ge=0, lt=1)] = 0.005
    theta_i_deg: Annotated[float, Field(ge=0, lt=85)] = 0.0
    theta_o_deg: Annotated[float, Field(ge=0, lt=85)] = 30.0
    every: Annotated[int, Field(ge=0, le=1_000_000)] = 50
    drift_sigma: Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)] = 4.0
    target_snr: Annotated[float, Field(gt=0, le=1e5, allow_inf_nan=False)] | None = None


class Material(Strict):
    """``[simulation.material]``: a model of the model module by class name, with its parameters."""

    model_config = ConfigDict(extra="allow", strict=True, frozen=True)

    model: str = "Lambert"

    def parameters(self) -> dict[str, Any]:
        """The model's keyword arguments (every key but ``model``), lists as tuples."""
        extra = dict(self.model_extra or {})
        return {k: tuple(v) if isinstance(v, list) else v for k, v in extra.items()}


ZeroOffset = Annotated[float, Field(ge=-45, le=45, allow_inf_nan=False)]
OffsetMm = Annotated[float, Field(ge=-50, le=50, allow_inf_nan=False)]


class Misalignment(Strict):
    """``[simulation.misalignment]``: how the simulated rig differs from the drawn one (hidden from the controller).

    Joint zeros (deg): a joint that reports angle a stands at a - zero. The sample's normal is tipped by
    ``sample_tilt_deg`` towards the stage-frame azimuth ``sample_tilt_azimuth_deg``; its centre sits
    ``sample_offset_mm`` (x tangent, y bitangent, z normal of the stage) off the arms' axis. The light is a
    disk of ``light_size_mm`` diameter (0: a point) whose irradiance falls by the fraction ``beam_falloff``
    at the edge of the lit spot; ``stray_light`` adds ambient counts per second to every pixel; the lamp
    warms up by the fraction ``lamp_drift`` with time constant ``lamp_warmup_s`` of rig time; each Dynamixel
    joint comes to rest anywhere within ``joint_settle_ticks`` encoder counts around what its encoder reads
    (1: a real servo, whose position loop cannot tell places within one count apart); every joint's gears have
    ``backlash_deg`` of play the encoder cannot see (the load lags the motor by half of it behind the direction
    it was last driven in), on either link.
    See ``rig.instrument.alignment`` for the exact definitions.
    """

    light_zero_deg: ZeroOffset = 0.0
    camera_zero_deg: ZeroOffset = 0.0
    tilt_zero_deg: ZeroOffset = 0.0
    roll_zero_deg: ZeroOffset = 0.0
    yaw_zero_deg: ZeroOffset = 0.0
    sample_tilt_deg: Annotated[float, Field(ge=0, le=20, allow_inf_nan=False)] = 0.0
    sample_tilt_azimuth_deg: Finite = 0.0
    sample_offset_mm: tuple[OffsetMm, OffsetMm, OffsetMm] = (0.0, 0.0, 0.0)
    light_size_mm: Annotated[float, Field(ge=0, le=200, allow_inf_nan=False)] = 0.0
    beam_falloff: Annotated[float, Field(ge=0, lt=1, allow_inf_nan=False)] = 0.0
    stray_light: NonNeg = 0.0
    lamp_drift: Annotated[float, Field(gt=-0.9, lt=10, allow_inf_nan=False)] = 0.0
    lamp_warmup_s: Pos = 600.0
    joint_settle_ticks: Annotated[float, Field(ge=0, le=10, allow_inf_nan=False)] = 0.0
    backlash_deg: Annotated[float, Field(ge=0, le=10, allow_inf_nan=False)] = 0.0


class SimulatedSensor(Strict):
    """``[simulation.sensor]``: the simulated sensor as it really is, hidden from the controller.

    Noise keys left out are those of ``[camera.noise]`` (what the controller assumes); ``vignetting`` is
    the fraction of light lost at the sensor's corner, ``prnu_rms`` the pixels' relative sensitivity RMS,
    ``nonlinearity`` the response's relative compression at full well (``simulator.camera.pixels``).
    """

    e_per_dn: Annotated[float, Field(ge=1e-3, le=1e5, allow_inf_nan=False)] | None = None
    read_noise_e: Annotated[float, Field(ge=0, le=1e6, allow_inf_nan=False)] | None = None
    dark_current_e_per_s: Annotated[float, Field(ge=0, le=1e9, allow_inf_nan=False)] | None = None
    black_level_dn: Levels | None = None
    white_level_dn: Annotated[float, Field(gt=0, le=2**32, allow_inf_nan=False)] | None = None
    full_well_e: Annotated[float, Field(gt=0, le=1e9, allow_inf_nan=False)] | None = None
    vignetting: Annotated[float, Field(ge=0, le=0.9)] = 0.0
    prnu_rms: Annotated[float, Field(ge=0, le=0.2)] = 0.0
    nonlinearity: Annotated[float, Field(ge=0, le=0.2)] = 0.0


class Simulation(Strict):
    """``[simulation]``: what the simulated rig stands in for: material, light, time, seed, sensor, imperfections.

    ``camera_output``: "linear" frames, "raw" CFA mosaics, or "dng": mosaics written as DNG files and read back
    through rawpy, the path of a real camera's RAW files.

    ``link``: what moves the simulated joints: "dynamixel" (virtual XM430 servos, ``[axes.*] id``) or "grbl" (a
    virtual GRBL 1.1 controller, ``[axes.*] letter``, coordinated moves, homed before a run moves).
    """

    material: Material = Material()
    camera_output: Literal["linear", "raw", "dng"] = "linear"
    sensor: SimulatedSensor = SimulatedSensor()
    misalignment: Misalignment = Misalignment()
    light_intensity_w_sr: Pos = 1.0
    light_kind: Literal["point", "spot"] = "point"
    time_scale: Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False)] | None = None
    fixed_pattern_dn: Levels = 0.0
    seed: Seed = 0
    link: Literal["dynamixel", "grbl"] = "dynamixel"


MetaValue = str | int | float | bool


class Metadata(Strict):
    """``[metadata]``: what the data are about, carried unchanged into the manifest, the tables and the report.

    ``sample``: what is measured; ``operator``: who measured it; ``notes``: free text; any other key is kept as
    given, if its value is a string, number, boolean, date or a list of those (a table is refused: metadata
    stays one level deep, so every key reads as one line). Dates become ISO 8601 strings.
    """

    model_config = ConfigDict(extra="allow", strict=True, frozen=True)

    sample: str | None = None
    operator: str | None = None
    notes: str | None = None

    @model_validator(mode="before")
    @classmethod
    def _plain_values(cls, data: Any) -> Any:
        if not isinstance(data, dict):
            return data
        out: dict[str, Any] = {}
        for key, value in data.items():
            if isinstance(value, list | tuple):
                out[key] = tuple(_meta_value(key, v) for v in value)
            else:
                out[key] = _meta_value(key, value)
        return out

    def as_dict(self) -> dict[str, Any]:
        """The keys that are set, lists as lists (plain JSON)."""
        keys = {"sample": self.sample, "operator": self.operator, "notes": self.notes, **(self.model_extra or {})}
        return {k: list(v) if isinstance(v, tuple) else v for k, v in keys.items() if v is not None}


def _meta_value(key: str, value: Any) -> MetaValue:
    if hasattr(value, "isoformat"):  # TOML dates and times
        return str(value.isoformat())
    if isinstance(value, float) and not math.isfinite(value):  # NaN and inf cannot travel through JSON
        raise ValueError(f"{key} = {value}: expected a finite number, a string or a boolean")
    if not isinstance(value, str | int | float | bool):
        raise ValueError(f"{key} = {repr(value)[:80]}: expected a string, number, boolean, date or a list of those "
                         "(metadata is one level deep: no tables)")  # fmt: skip
    return value


def run_metadata(rig: RigFile, sweep: SweepFile) -> dict[str, Any]:
    """A run's metadata: the rig file's ``[metadata]`` overlaid with the sweep file's (its keys win)."""
    return {**rig.metadata.as_dict(), **sweep.metadata.as_dict()}


class RigFile(Strict):
    """A rig file: the hardware (or its simulation) a sweep runs on."""

    name: str = "rig"
    metadata: Metadata = Metadata()
    geometry: Geometry = Geometry()
    link: Link = Field(default_factory=Link)
    axes: dict[str, AxisTable] = Field(default_factory=dict)
    camera: Camera = Field(default_factory=Camera)
    reference: Reference = Reference()
    simulation: Simulation = Simulation()
    sample: Sample = Sample()


#: The most points a sweep may expand to: far beyond any real sweep (a dense grid of 10^4 points runs for days),
#: short of what would exhaust memory generating and planning it.
MAX_SWEEP_POINTS = 1_000_000


class Sweep(Strict):
    """``[sweep]``: which BRDF directions to measure, in degrees (at most MAX_SWEEP_POINTS combinations)."""

    kind: Literal["grid", "in_plane", "rusinkiewicz", "list"]
    theta_i_deg: tuple[Finite, ...] | None = None
    theta_o_deg: tuple[Finite, ...] | None = None
    phi_i_deg: tuple[Finite, ...] | None = None
    phi_o_deg: tuple[Finite, ...] | None = None
    theta_h_deg: tuple[Deg90, ...] | None = None
    theta_d_deg: tuple[Deg90, ...] | None = None
    phi_d_deg: tuple[Finite, ...] | None = None
    phi_h_deg: tuple[Finite, ...] | None = None
    points: tuple[tuple[Finite, Finite, Finite, Finite], ...] | None = None
    isotropic: bool = False
    order: bool = True

    @model_validator(mode="after")
    def _keys_for_kind(self) -> Sweep:
        needed = {
            "grid": ("theta_i_deg", "theta_o_deg"),
            "in_plane": ("theta_i_deg", "theta_o_deg"),
            "rusinkiewicz": ("theta_h_deg", "theta_d_deg", "phi_d_deg"),
            "list": ("points",),
        }[self.kind]
        allowed = set(needed) | {"grid": {"phi_i_deg", "phi_o_deg"}, "rusinkiewicz": {"phi_h_deg"}}.get(
            self.kind, set()
        )
        missing = [k for k in needed if not getattr(self, k)]
        if missing:
            raise ValueError(f"a {self.kind!r} sweep needs {', '.join(missing)} (non-empty)")
        optional = {"theta_i_deg", "theta_o_deg", "phi_i_deg", "phi_o_deg", "theta_h_deg", "theta_d_deg", "phi_d_deg",
                    "phi_h_deg", "points"}  # fmt: skip
        stray = [k for k in optional - allowed if getattr(self, k) is not None]
        if stray:
            raise ValueError(f"{', '.join(sorted(stray))} has no meaning in a {self.kind!r} sweep")
        # Counted from the lists' lengths, before a point is generated: a product of long lists would need
        # gigabytes just to hold the combinations.
        keys = [k for k in (*needed, *sorted(allowed - set(needed))) if getattr(self, k) is not None]
        count = math.prod(len(getattr(self, k)) for k in keys)
        if count > MAX_SWEEP_POINTS:
            lengths = " x ".join(f"{k} ({len(getattr(self, k))})" for k in keys)
            raise ValueError(f"{lengths} = {count} points: expected at most {MAX_SWEEP_POINTS} points in a sweep "
                             "(shorten the lists, or split the sweep into several runs)")  # fmt: skip
        return self


class Capture(Strict):
    """``[capture]``: how each point is exposed: target SNR, frames, darks, images kept."""

    target_snr: Annotated[float, Field(gt=0, le=1e5)] = 200.0
    exposures_s: tuple[Seconds, ...] | None = None
    max_frames: Annotated[int, Field(ge=1, le=64)] = 5
    dark_frames: Annotated[int, Field(ge=0, le=16)] = 1
    first_exposure_s: Seconds = 0.01
    save_images: bool = False
    include_cosine: bool = False
    #: "point": each point one reading of the camera's ROI; "image": every tile_px x tile_px tile of the
    #: sample's whole footprint a sample of its own (rig.run.measuring.image_capture); "auto": image where the
    #: camera resolves the sample into enough tiles, else point (rig.run.measuring.mode_choice), decided when
    #: the run starts and written in its manifest.
    mode: Literal["point", "image", "auto"] = "point"
    #: Image mode's tile side in pixels (None: rig.run.measuring.tiles.DEFAULT_TILE_PX); also what "auto" counts in.
    tile_px: Annotated[int, Field(ge=1, le=512)] | None = None
    #: "stop": stop and go, every point measured at rest; "continuous": runs of points that differ in one joint are
    #: scanned at constant speed while the camera takes one frame per point (rig.run.measuring.scan); in image mode
    #: each frame's tiles are samples, each with the blur along its own directions.
    motion: Literal["stop", "continuous"] = "stop"
    #: The scanning joint's constant speed (deg/s of joint) in continuous motion, kept as given (up to the axis's
    #: max_speed_deg_s); left out: chosen per scan run, the fastest that the axis's max_speed_deg_s allows, that keeps
    #: each frame's blur (speed x exposure) within half the run's smallest step with room for the exposure to
    #: double, and that gives the camera time for each frame and its darks; a run that stopping at each point would
    #: measure sooner is then measured at rest (rig.run.planning.scans).
    scan_speed_deg_s: Annotated[float, Field(gt=0, le=30, allow_inf_nan=False)] | None = None
    #: A fitted model that predicts every point's level before it is measured, so its exposure is planned ahead:
    #: ``gonio analyze``'s fit.json or export/material.json (rig.run.measuring.exposure_sources). Exposures only.
    exposure_model: Annotated[str, Field(min_length=1)] | None = None
    #: An earlier run (its directory or its samples.csv) whose nearest measured direction pair predicts each
    #: point's level (a coarse first pass); with exposure_model too, the pass is asked first.
    exposure_from: Annotated[str, Field(min_length=1)] | None = None

    @model_validator(mode="after")
    def _tiles_in_image_mode(self) -> Capture:
        for key in ("exposure_model", "exposure_from"):
            if getattr(self, key) is not None and self.exposures_s is not None:
                raise ValueError(f"{key} = {getattr(self, key)!r} has no meaning with a fixed exposures_s "
                                 "(nothing is planned): leave out exposures_s to plan exposures ahead, or leave "
                                 f"out {key}")  # fmt: skip
        if self.tile_px is not None and self.mode == "point":
            raise ValueError(f"tile_px = {self.tile_px} has no meaning in point mode (each point reads the camera's "
                             'ROI): set mode = "image" to read the sample in tiles, or leave tile_px out')  # fmt: skip
        if self.scan_speed_deg_s is not None and self.motion != "continuous":
            raise ValueError(f"scan_speed_deg_s = {self.scan_speed_deg_s:g} has no meaning with motion = "
                             f'"{self.motion}" (every point is measured at rest): set motion = "continuous" or '
                             "leave scan_speed_deg_s out")  # fmt: skip
        return self


class SweepFile(Strict):
    """A sweep file: what to measure and how to capture it."""

    name: str = "sweep"
    metadata: Metadata = Metadata()
    sweep: Sweep
    capture: Capture = Capture()
