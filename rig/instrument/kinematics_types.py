"""Values exchanged with ``rig.instrument.kinematics``: joints, directions, poses, reasons and batch solutions.

Angles in degrees, lengths in metres; fields may be floats or broadcastable numpy arrays. The frame and
solution conventions are documented in ``rig.instrument.kinematics``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from enum import StrEnum
from typing import Literal

import numpy as np
import numpy.typing as npt

from model.errors import InputError
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics_checks import CheckDetails, explain

FloatArray = npt.NDArray[np.float64]
Angle = float | FloatArray
Branch = Literal["camera_ccw", "camera_cw"]
BRANCHES: tuple[str, ...] = ("camera_ccw", "camera_cw")


class Reason(StrEnum):
    """Machine-readable reason a pair of directions cannot be measured on a rig."""

    NOT_FINITE = "not_finite"
    BELOW_HORIZON = "below_horizon"
    MAX_ZENITH = "max_zenith"
    OUT_OF_PLANE = "out_of_plane"
    MIN_SEPARATION = "min_separation"
    SPOT_OVERFILLS_SAMPLE = "spot_overfills_sample"
    SPOT_OVERFILLS_VIEW = "spot_overfills_view"
    JOINT_LIMIT = "joint_limit"


@dataclass(frozen=True)
class Joints:
    """Joint angles in degrees (floats or broadcastable arrays); joints a layout lacks are None."""

    light: Angle
    camera: Angle | None = None
    tilt: Angle | None = None
    roll: Angle | None = None
    yaw: Angle | None = None

    def as_dict(self) -> dict[str, Angle]:
        """The present joints as {name: degrees}, in field order."""
        return {name: v for name in _JOINT_FIELDS if (v := getattr(self, name)) is not None}

    @classmethod
    def from_dict(cls, angles_deg: Mapping[str, Angle]) -> Joints:
        """Joints from {name: degrees}; unknown names raise ValueError."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(angles_deg) - known)
        if unknown:
            raise ValueError(f"unknown joint name(s) {unknown}; joints are {sorted(known)}")
        if "light" not in angles_deg:
            raise ValueError("joints need a 'light' angle (degrees)")
        return cls(**dict(angles_deg))


#: Joints' field names in order (a subclass's own fields are not joints).
_JOINT_FIELDS = tuple(f.name for f in fields(Joints))


@dataclass(frozen=True)
class Directions:
    """BRDF directions: zenith/azimuth in degrees and the local unit vectors wi, wo (..., 3)."""

    theta_i: Angle
    phi_i: Angle
    theta_o: Angle
    phi_o: Angle
    wi: FloatArray
    wo: FloatArray


@dataclass(frozen=True)
class RigPose:
    """World placement (metres, unit vectors) of the sample, light and camera for one set of joints.

    The sample centre is the world origin on the drawn rig; tangent, bitangent and normal are the world
    images of the sample's local x, y and z axes. Arrays have shape (..., 3). ``aim_m`` is the point the
    camera and the light are aimed at (the arms' axis, the origin); None means the sample centre, which is
    the same point on the drawn rig (``rig.instrument.alignment`` moves the sample off it).
    """

    sample_centre_m: FloatArray
    sample_normal: FloatArray
    sample_tangent: FloatArray
    sample_bitangent: FloatArray
    light_position_m: FloatArray
    camera_position_m: FloatArray
    aim_m: FloatArray | None = None

    def aim(self) -> FloatArray:
        """Where the camera and the light point (m): ``aim_m``, or the sample centre."""
        return np.asarray(self.sample_centre_m if self.aim_m is None else self.aim_m, dtype=np.float64)


@dataclass(frozen=True)
class Unreachable:
    """Why directions cannot be measured: a ``Reason`` code, a message, and the numbers behind it.

    ``value`` and ``limit`` are in the unit the reason concerns: degrees for angles (zenith,
    separation, out-of-plane angle, joint angle), metres for spot sizes. ``joints`` holds the pose
    that would be needed when the solution exists but breaks a joint limit.
    """

    reason: Reason
    message: str
    value: float | None = None
    limit: float | None = None
    joint: str | None = None
    joints: Joints | None = None


class UnreachableError(InputError, ValueError):
    """Raised by ``require`` for an unreachable point; carries the ``Unreachable`` in ``.unreachable``."""

    def __init__(self, unreachable: Unreachable) -> None:
        super().__init__(f"{unreachable.reason.value}: {unreachable.message}")
        self.unreachable = unreachable


def require(result: Joints | Unreachable) -> Joints:
    """The joints (degrees) of a result, or raise ``UnreachableError`` with its reason."""
    if isinstance(result, Unreachable):
        raise UnreachableError(result)
    return result


@dataclass(frozen=True)
class Solution:
    """Inverse kinematics over arrays of directions: joints in degrees and a reason code per point.

    ``joints`` holds the solution wherever it is defined, reachable or not (joint values outside their
    limits are reported at their canonical angle in (-180, 180]); ``reason`` is ``""`` where the point is
    reachable, else a ``Reason`` value. ``at(index)`` gives one point as ``Joints`` or ``Unreachable``
    with its message.
    """

    geometry: RigGeometry
    wi: FloatArray
    wo: FloatArray
    joints: Joints
    reason: npt.NDArray[np.str_]
    details: CheckDetails = field(repr=False)

    @property
    def reachable(self) -> npt.NDArray[np.bool_]:
        """Boolean mask of reachable points."""
        return self.reason == ""

    @property
    def shape(self) -> tuple[int, ...]:
        """Shape of the batch of points."""
        return tuple(self.reason.shape)

    def at(self, index: int | tuple[int, ...] = ()) -> Joints | Unreachable:
        """One point's result: its Joints (degrees), or Unreachable with reason and message."""
        joints = Joints.from_dict({k: float(np.asarray(v)[index]) for k, v in self.joints.as_dict().items()})
        code = str(self.reason[index])
        if not code:
            return joints
        angles = {k: float(v) for k, v in joints.as_dict().items()}
        value, limit, joint, message = explain(self.geometry, self.details, code, index, angles)
        needed = joints if code == Reason.JOINT_LIMIT else None
        return Unreachable(Reason(code), message, value, limit, joint, needed)
