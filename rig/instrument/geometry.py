"""What a rig is made of: its layout, arm radii, sample, light beam, camera view and joint limits.

A ``RigGeometry`` is a frozen value: the kinematics (``rig.instrument.kinematics``) and the simulator read it, nothing
writes it. Lengths are metres and angles degrees, as in rig files. Every field is checked on
construction; a bad value raises ``GeometryError`` naming the field, the value and the range expected.

Layouts:

``"four_axis"``
    Light arm and camera arm turn about one vertical axis through the sample centre; the sample stage
    has tilt and roll. Joints: light, camera, tilt, roll.
``"in_plane"``
    The two arms only; the sample is mounted by hand, facing arm angle 0, with its local azimuth
    ``plane_azimuth_deg`` lying in the arm plane. Joints: light, camera.
``"fixed_camera"``
    The camera is fixed at arm angle ``camera_azimuth_deg``; the light arm moves and the stage has yaw
    (a turntable about the vertical axis), tilt and roll. Joints: light, yaw, tilt, roll.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Literal, get_args

from model.errors import InputError

Layout = Literal["four_axis", "in_plane", "fixed_camera"]
LAYOUTS: tuple[str, ...] = get_args(Layout)

#: Joint names per layout, in the order joint vectors and files list them.
JOINT_NAMES: dict[str, tuple[str, ...]] = {
    "four_axis": ("light", "camera", "tilt", "roll"),
    "in_plane": ("light", "camera"),
    "fixed_camera": ("light", "yaw", "tilt", "roll"),
}


class GeometryError(InputError, ValueError):
    """A rig geometry field is outside its valid range."""


def _finite(owner: str, name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise GeometryError(f"{owner}.{name} = {value!r}, expected a finite number")
    return float(value)


def _in_range(
    owner: str, name: str, value: float, lo: float, hi: float, *, lo_open: bool, hi_open: bool, unit: str
) -> None:
    v = _finite(owner, name, value)
    below = v < lo or (lo_open and v == lo)
    above = v > hi or (hi_open and v == hi)
    if below or above:
        left, right = ("(" if lo_open else "["), (")" if hi_open else "]")
        hi_text = "inf" if math.isinf(hi) else f"{hi:g}"
        raise GeometryError(f"{owner}.{name} = {value!r} {unit}, expected a value in {left}{lo:g}, {hi_text}{right}")


@dataclass(frozen=True)
class JointLimits:
    """Soft limits (min_deg, max_deg) per joint in degrees; a layout uses only its own joints."""

    light: tuple[float, float] = (-180.0, 180.0)
    camera: tuple[float, float] = (-180.0, 180.0)
    tilt: tuple[float, float] = (-90.0, 90.0)
    roll: tuple[float, float] = (-180.0, 180.0)
    yaw: tuple[float, float] = (-180.0, 180.0)

    def __post_init__(self) -> None:
        for f in fields(self):
            pair = getattr(self, f.name)
            where = f"JointLimits.{f.name}"
            if not isinstance(pair, tuple) or len(pair) != 2:
                raise GeometryError(f"{where} = {pair!r}, expected a pair (min_deg, max_deg)")
            lo = _finite("JointLimits", f"{f.name}[0]", pair[0])
            hi = _finite("JointLimits", f"{f.name}[1]", pair[1])
            if not lo < hi:
                raise GeometryError(f"{where} = {pair!r} deg, expected min_deg < max_deg")
            # Beyond two turns either way no rotary joint here is meaningful; it is almost surely a unit slip.
            if lo < -720.0 or hi > 720.0:
                raise GeometryError(f"{where} = {pair!r} deg, expected limits within [-720, 720] deg")

    def of(self, joint: str) -> tuple[float, float]:
        """The (min_deg, max_deg) limits of one joint, in degrees."""
        if joint not in {f.name for f in fields(self)}:
            raise KeyError(f"no joint named {joint!r}; joints are light, camera, tilt, roll, yaw")
        pair: tuple[float, float] = getattr(self, joint)
        return pair


@dataclass(frozen=True)
class RigGeometry:
    """A gonioreflectometer's geometry: layout, arm radii (m), sample size (m), beam, camera view, limits.

    Fields (lengths in metres, angles in degrees):

    layout:
        ``"four_axis"`` (default), ``"in_plane"`` or ``"fixed_camera"``; see the module docstring.
    light_radius_m, camera_radius_m:
        Distance from the sample centre (on the arm axis) to the light source and the camera's centre of
        projection. Both must clear the sample's half-diagonal.
    sample_width_m, sample_height_m:
        The sample's extent along its local x (tangent) and y (bitangent) axes, centred on the origin.
    min_separation_deg:
        Smallest angle between light and camera as seen from the sample centre, in [0, 180): closer,
        the arms collide or the camera shadows the light (near retroreflection).
    max_zenith_deg:
        Largest zenith angle of either direction, in (0, 90).
    camera_fov_deg:
        The camera's full field of view (the cone it sees around its axis), in (0, 180).
    beam_half_angle_deg:
        Half-angle of the light's cone, from a point source at ``light_radius_m``, in (0, 90). The
        spot at normal incidence has radius ``light_radius_m * tan(beam_half_angle)``.
    camera_azimuth_deg:
        ``fixed_camera`` only: the world arm angle at which the camera is fixed.
    plane_azimuth_deg:
        ``in_plane`` only: the sample-frame azimuth mounted in the arm plane (the light reaches
        phi = plane_azimuth and plane_azimuth + 180 only).
    limits:
        Joint soft limits in degrees (``JointLimits``).
    """

    layout: Layout = "four_axis"
    light_radius_m: float = 0.5
    camera_radius_m: float = 0.5
    sample_width_m: float = 0.05
    sample_height_m: float = 0.05
    min_separation_deg: float = 8.0
    max_zenith_deg: float = 85.0
    camera_fov_deg: float = 8.0
    beam_half_angle_deg: float = 0.25
    camera_azimuth_deg: float = 0.0
    plane_azimuth_deg: float = 0.0
    limits: JointLimits = field(default_factory=JointLimits)

    def __post_init__(self) -> None:
        owner = "RigGeometry"
        if self.layout not in LAYOUTS:
            raise GeometryError(
                f"{owner}.layout = {self.layout!r}, expected one of {', '.join(repr(x) for x in LAYOUTS)}"
            )
        inf = math.inf
        for name in ("sample_width_m", "sample_height_m", "light_radius_m", "camera_radius_m"):
            _in_range(owner, name, getattr(self, name), 0.0, inf, lo_open=True, hi_open=True, unit="m")
        half_diagonal = 0.5 * math.hypot(self.sample_width_m, self.sample_height_m)
        for name in ("light_radius_m", "camera_radius_m"):
            if getattr(self, name) <= half_diagonal:
                raise GeometryError(
                    f"{owner}.{name} = {getattr(self, name)!r} m, expected more than the sample's "
                    f"half-diagonal {half_diagonal:.6g} m (the arm would hit the sample)"
                )
        _in_range(owner, "min_separation_deg", self.min_separation_deg, 0, 180, lo_open=False, hi_open=True,
                  unit="deg")
        _in_range(owner, "max_zenith_deg", self.max_zenith_deg, 0, 90, lo_open=True, hi_open=True, unit="deg")
        _in_range(owner, "camera_fov_deg", self.camera_fov_deg, 0, 180, lo_open=True, hi_open=True, unit="deg")
        _in_range(owner, "beam_half_angle_deg", self.beam_half_angle_deg, 0, 90, lo_open=True, hi_open=True,
                  unit="deg")
        _finite(owner, "camera_azimuth_deg", self.camera_azimuth_deg)
        _finite(owner, "plane_azimuth_deg", self.plane_azimuth_deg)
        if not isinstance(self.limits, JointLimits):
            raise GeometryError(f"{owner}.limits = {self.limits!r}, expected a JointLimits")

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The layout's joints in order (names as in rig files and axes)."""
        return JOINT_NAMES[self.layout]

    @property
    def spot_radius_m(self) -> float:
        """Radius in metres of the illuminated spot at normal incidence."""
        return self.light_radius_m * math.tan(math.radians(self.beam_half_angle_deg))

    @property
    def view_radius_m(self) -> float:
        """Radius in metres of the camera's view, across its axis, at the sample centre."""
        return self.camera_radius_m * math.tan(math.radians(0.5 * self.camera_fov_deg))
