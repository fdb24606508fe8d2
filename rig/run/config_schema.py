"""The schema of rig and sweep files (TOML): every table, key, type, unit and default, validated strictly.

Unknown keys are errors (``extra="forbid"``), types are not coerced (a string is never a number), and
numbers carry their bounds here, where they are defined. ``rig.run.config`` loads files against these models
and turns pydantic's errors into messages that name the file, the key, the value and what was expected.

Rig file tables: ``[geometry]`` (and ``[geometry.limits]``), ``[link]``, ``[axes.<joint>]``, ``[camera]``
(``[camera.noise]``), ``[reference]``, ``[simulation]`` (``[simulation.material]``). Sweep file tables:
``[sweep]`` and ``[capture]``. See examples/*.toml for annotated files.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator
from pydantic_core import PydanticCustomError

from acquisition.cameras import registry as cameras
from rig.run import registry

Pos = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]
Deg90 = Annotated[float, Field(ge=0, le=90, allow_inf_nan=False)]
Pair = tuple[Finite, Finite]
Channels = (
    Annotated[float, Field(gt=0, le=1)]
    | tuple[
        Annotated[float, Field(gt=0, le=1)], Annotated[float, Field(gt=0, le=1)], Annotated[float, Field(gt=0, le=1)]
    ]
)


def _tuples(value: Any) -> Any:
    return tuple(_tuples(v) for v in value) if isinstance(value, list) else value


class Strict(BaseModel):
    """Base of every table: unknown keys are errors, values are not coerced, models are frozen."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _arrays_as_tuples(cls, data: Any) -> Any:
        # TOML arrays arrive as lists; strict mode takes only tuples for the fixed-length and frozen fields.
        return {k: _tuples(v) for k, v in data.items()} if isinstance(data, dict) else data


class Limits(Strict):
    """``[geometry.limits]``: soft limits [min_deg, max_deg] per joint, in degrees."""

    light: Pair = (-180.0, 180.0)
    camera: Pair = (-180.0, 180.0)
    tilt: Pair = (-90.0, 90.0)
    roll: Pair = (-180.0, 180.0)
    yaw: Pair = (-180.0, 180.0)


class Geometry(Strict):
    """``[geometry]``: the rig's layout, arm radii and sample size in metres, angles in degrees."""

    layout: Literal["four_axis", "in_plane", "fixed_camera"] = "four_axis"
    light_radius_m: Pos = 0.5
    camera_radius_m: Pos = 0.5
    sample_width_m: Pos = 0.05
    sample_height_m: Pos = 0.05
    min_separation_deg: Annotated[float, Field(ge=0, lt=180)] = 8.0
    max_zenith_deg: Annotated[float, Field(gt=0, lt=90)] = 85.0
    camera_fov_deg: Annotated[float, Field(gt=0, lt=180)] = 8.0
    beam_half_angle_deg: Annotated[float, Field(gt=0, lt=90)] = 0.25
    camera_azimuth_deg: Finite = 0.0
    plane_azimuth_deg: Finite = 0.0
    limits: Limits = Limits()


def _one_of(value: str, known: tuple[str, ...]) -> str:
    # Worded as pydantic words a Literal, so the message reads like every other key's.
    if value not in known:
        raise PydanticCustomError("literal_error", "Input should be {expected}", {"expected": registry.listing(known)})
    return value


class Link(Strict):
    """``[link]``: how the controller reaches the servos, and what it does when it stops.

    ``kind`` names a registered rig backend (``gonio.backends``: simulated, dynamixel, grbl, or a lab's own).
    """

    kind: str = "simulated"
    port: str | None = None
    baudrate: Annotated[int, Field(gt=0)] = 1_000_000
    retries: Annotated[int, Field(ge=0, le=20)] = 2
    latency_timer_ms: Annotated[float, Field(ge=0, le=1000)] = 16.0
    poll_interval_s: Annotated[float, Field(gt=0, le=5)] = 0.02
    move_timeout_s: Annotated[float, Field(gt=0, le=3600)] = 60.0
    settle_s: Annotated[float, Field(ge=0, le=600)] = 0.0
    on_stop: Literal["torque_off", "hold"] = "torque_off"
    allow_reboot: bool = False

    @field_validator("kind")
    @classmethod
    def _registered(cls, value: str) -> str:
        return _one_of(value, registry.names())

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
    direction: Literal[1, -1] = 1
    zero_offset_deg: Annotated[float, Field(ge=-1e6, le=1e6, allow_inf_nan=False)] = -180.0
    min_deg: Annotated[float, Field(ge=-1e6, le=1e6, allow_inf_nan=False)] | None = None
    max_deg: Annotated[float, Field(ge=-1e6, le=1e6, allow_inf_nan=False)] | None = None
    max_speed_deg_s: Annotated[float, Field(gt=0, le=1e5, allow_inf_nan=False)] = 60.0
    max_accel_deg_s2: Annotated[float, Field(gt=0, le=1e7, allow_inf_nan=False)] = 120.0
    tolerance_deg: Pos = 0.2

    @model_validator(mode="after")
    def _one_address(self) -> AxisTable:
        if (self.id is None) == (self.letter is None):
            raise ValueError("give exactly one of id (a Dynamixel id) or letter (a GRBL axis)")
        return self


class Noise(Strict):
    """``[camera.noise]``: the sensor's gain (e-/DN), noise (e-), dark current (e-/s) and levels (DN)."""

    e_per_dn: Pos = 4.0
    read_noise_e: NonNeg = 3.0
    dark_current_e_per_s: NonNeg = 0.5
    black_level_dn: NonNeg = 512.0
    white_level_dn: Pos = 16383.0
    full_well_e: Pos = 60000.0


class Camera(Strict):
    """``[camera]``: the camera backend, its exposure range (s), image size and ROI (pixels).

    ``backend`` names a registered camera backend (``gonio.cameras``: folder, opencv, or a lab's own) or one
    that comes with the rig backend (the simulated rig's "simulated").
    """

    backend: str = "simulated"
    folder: str | None = None
    device: Annotated[int, Field(ge=0)] = 0
    min_exposure_s: Pos = 1e-5
    max_exposure_s: Pos = 30.0
    overhead_s: NonNeg = 0.0
    #: Wall seconds a capture may take beyond twice its exposure before the run stops on a camera fault.
    capture_timeout_s: Annotated[float, Field(gt=0, le=3600)] = 60.0
    resolution: tuple[Annotated[int, Field(ge=8, le=8192)], Annotated[int, Field(ge=8, le=8192)]] = (32, 32)
    roi: tuple[int, int, int, int] | None = None
    spp: Annotated[int, Field(ge=1, le=4096)] = 4
    variant: str | None = None
    noise: Noise = Noise()

    @field_validator("backend")
    @classmethod
    def _registered(cls, value: str) -> str:
        return _one_of(value, registry.provided_cameras() + cameras.names())

    @model_validator(mode="after")
    def _consistent(self) -> Camera:
        if self.min_exposure_s >= self.max_exposure_s:
            raise ValueError(f"min_exposure_s {self.min_exposure_s!r} must be below max_exposure_s")
        if self.backend == "folder" and not self.folder:
            raise ValueError("the folder backend needs folder (the directory the tethering software writes to)")
        return self


class Reference(Strict):
    """``[reference]``: the Lambertian reference target, where it is measured and how often."""

    kind: Literal["simulated", "manual", "none"] = "simulated"
    albedo: Channels = 0.99
    albedo_std_error: Annotated[float, Field(ge=0, lt=1)] = 0.005
    theta_i_deg: Annotated[float, Field(ge=0, lt=85)] = 0.0
    theta_o_deg: Annotated[float, Field(ge=0, lt=85)] = 30.0
    every: Annotated[int, Field(ge=0)] = 50
    drift_sigma: Pos = 4.0
    target_snr: Pos | None = None


class Material(Strict):
    """``[simulation.material]``: a model of the model module by class name, with its parameters."""

    model_config = ConfigDict(extra="allow", strict=True, frozen=True)

    model: str = "Lambert"

    def parameters(self) -> dict[str, Any]:
        """The model's keyword arguments (every key but ``model``), lists as tuples."""
        extra = dict(self.model_extra or {})
        return {k: tuple(v) if isinstance(v, list) else v for k, v in extra.items()}


class Simulation(Strict):
    """``[simulation]``: what the simulated rig stands in for: material, light (W/sr), time, seed."""

    material: Material = Material()
    light_intensity_w_sr: Pos = 1.0
    light_kind: Literal["point", "spot"] = "point"
    time_scale: Pos | None = None
    fixed_pattern_dn: NonNeg = 0.0
    seed: Annotated[int, Field(ge=0)] = 0


class RigFile(Strict):
    """A rig file: the hardware (or its simulation) a sweep runs on."""

    name: str = "rig"
    geometry: Geometry = Geometry()
    link: Link = Field(default_factory=Link)
    axes: dict[str, AxisTable] = Field(default_factory=dict)
    camera: Camera = Field(default_factory=Camera)
    reference: Reference = Reference()
    simulation: Simulation = Simulation()


class Sweep(Strict):
    """``[sweep]``: which BRDF directions to measure, in degrees."""

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
        return self


class Capture(Strict):
    """``[capture]``: how each point is exposed: target SNR, frames, darks, images kept."""

    target_snr: Annotated[float, Field(gt=0, le=1e5)] = 200.0
    exposures_s: tuple[Pos, ...] | None = None
    max_frames: Annotated[int, Field(ge=1, le=64)] = 5
    dark_frames: Annotated[int, Field(ge=0, le=16)] = 1
    first_exposure_s: Pos = 0.01
    save_images: bool = False
    include_cosine: bool = False


class SweepFile(Strict):
    """A sweep file: what to measure and how to capture it."""

    name: str = "sweep"
    sweep: Sweep
    capture: Capture = Capture()
