"""A rig as it is built, not as it is drawn: joint zero offsets, a tilted and off-centre sample.

``Alignment`` holds the geometric imperfections of one rig; the simulator renders with the true ones
(``[simulation.misalignment]``, hidden from the controller) and the controller corrects with the ones
``gonio calibrate geometry`` fitted (``geometry_calibration.json``). Both go through the functions here,
so the simulation and the correction share one definition of every quantity:

- ``light_zero_deg``, ``camera_zero_deg``, ``tilt_zero_deg``, ``roll_zero_deg`` (and ``yaw_zero_deg`` on a
  fixed-camera rig): how far a joint's true zero lies from its configured zero. A joint that reports the
  angle ``a`` (read back from its encoder, relative to the configured zero) physically stands at
  ``a - zero``. On a layout without the joint (the in-plane rig's fixed stage, the fixed camera) the
  offset applies to the fixed angle.
- ``sample_tilt_deg`` and ``sample_tilt_azimuth_deg``: the sample's normal is tipped from the stage's
  normal by ``sample_tilt_deg`` towards the stage-frame azimuth ``sample_tilt_azimuth_deg`` (measured from
  the stage's local x, the tangent, towards its local y), as a wedge under a badly seated sample does; the
  sample's tangent and bitangent turn with it (a rotation about the stage-frame axis perpendicular to
  that azimuth).
- ``sample_offset_mm`` (x, y, z): the sample's centre relative to the arms' rotation axis, in the stage's
  local frame (x tangent, y bitangent, z normal) in millimetres; it turns with the stage.

The camera and the light are mounted on their arms aimed at the arms' axis (the world origin), whatever
the sample does. A reading is what the camera's central ray sees: the point P where that ray meets the
sample's plane. The measured directions are those from P to the light and to the camera, in the
sample's own frame. With a zero ``Alignment`` all of this is ``rig.instrument.kinematics`` (P is the origin), and the
functions here return its results to the last bit.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import _angles, _arm, _sample_axes, _to_local, forward, solve, world_pose
from rig.instrument.kinematics_types import Directions, FloatArray, Joints, RigPose

#: Fields of Alignment that are joint zero offsets, by joint name.
ZERO_FIELDS = {"light": "light_zero_deg", "camera": "camera_zero_deg", "tilt": "tilt_zero_deg",
               "roll": "roll_zero_deg", "yaw": "yaw_zero_deg"}  # fmt: skip


@dataclass(frozen=True)
class Alignment:
    """Geometric imperfections of a rig (degrees, millimetres); all zero is the drawn rig. See the module."""

    light_zero_deg: float = 0.0
    camera_zero_deg: float = 0.0
    tilt_zero_deg: float = 0.0
    roll_zero_deg: float = 0.0
    yaw_zero_deg: float = 0.0
    sample_tilt_deg: float = 0.0
    sample_tilt_azimuth_deg: float = 0.0
    sample_offset_mm: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            values = value if isinstance(value, tuple) else (value,)
            if not all(np.isfinite(v) for v in values):
                raise ValueError(f"Alignment.{f.name} = {value!r}: expected finite numbers")
        if len(self.sample_offset_mm) != 3:
            raise ValueError(f"Alignment.sample_offset_mm = {self.sample_offset_mm!r}: expected (x, y, z) in mm")
        object.__setattr__(self, "sample_offset_mm", tuple(float(v) for v in self.sample_offset_mm))

    @property
    def is_zero(self) -> bool:
        """True for the drawn rig (no imperfection at all)."""
        return self == _DRAWN

    def zero_of(self, joint: str) -> float:
        """The zero offset of a joint in degrees."""
        return float(getattr(self, ZERO_FIELDS[joint]))

    def wedge(self) -> FloatArray:
        """The sample's local axes as columns, in the stage's local frame (3, 3): the wedge rotation."""
        tau, psi = np.radians(self.sample_tilt_deg), np.radians(self.sample_tilt_azimuth_deg)
        axis = np.array([-np.sin(psi), np.cos(psi), 0.0])
        k = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
        return np.eye(3) + np.sin(tau) * k + (1.0 - np.cos(tau)) * (k @ k)


# The parameterisation a geometry calibration fits (rig.alignment.model says why each layout fits these).
ZEROS = ("light_zero_deg", "camera_zero_deg", "tilt_zero_deg", "roll_zero_deg")
WEDGE = ("wedge_x_deg", "wedge_y_deg")
OFFSET = ("offset_x_mm", "offset_y_mm", "offset_z_mm")
PARAMETERS: dict[str, tuple[str, ...]] = {
    "four_axis": (*ZEROS, *WEDGE, *OFFSET),
    "in_plane": (*ZEROS, *OFFSET),
    "fixed_camera": ("light_zero_deg", "yaw_zero_deg", "tilt_zero_deg", "roll_zero_deg", *WEDGE, *OFFSET),
}


#: The drawn rig, built once: ``is_zero`` runs for every forward kinematics call.
_DRAWN = Alignment()


def alignment_of(names: Sequence[str], values: npt.ArrayLike) -> Alignment:
    """The Alignment a parameter vector stands for (names from PARAMETERS)."""
    v = dict(zip(names, np.asarray(values, dtype=np.float64).tolist(), strict=True))
    wx, wy = v.get("wedge_x_deg", 0.0), v.get("wedge_y_deg", 0.0)
    return Alignment(
        light_zero_deg=v.get("light_zero_deg", 0.0), camera_zero_deg=v.get("camera_zero_deg", 0.0),
        tilt_zero_deg=v.get("tilt_zero_deg", 0.0), roll_zero_deg=v.get("roll_zero_deg", 0.0),
        yaw_zero_deg=v.get("yaw_zero_deg", 0.0), sample_tilt_deg=math.hypot(wx, wy),
        sample_tilt_azimuth_deg=math.degrees(math.atan2(wy, wx)) if (wx or wy) else 0.0,
        sample_offset_mm=(v.get("offset_x_mm", 0.0), v.get("offset_y_mm", 0.0), v.get("offset_z_mm", 0.0)),
    )  # fmt: skip


def parameters_of(names: Sequence[str], alignment: Alignment) -> FloatArray:
    """The parameter vector of an Alignment (its inverse, for the parameters the layout fits)."""
    tau, psi = math.radians(alignment.sample_tilt_deg), math.radians(alignment.sample_tilt_azimuth_deg)
    values = {
        "light_zero_deg": alignment.light_zero_deg, "camera_zero_deg": alignment.camera_zero_deg,
        "tilt_zero_deg": alignment.tilt_zero_deg, "roll_zero_deg": alignment.roll_zero_deg,
        "yaw_zero_deg": alignment.yaw_zero_deg,
        "wedge_x_deg": math.degrees(tau) * math.cos(psi), "wedge_y_deg": math.degrees(tau) * math.sin(psi),
        "offset_x_mm": alignment.sample_offset_mm[0], "offset_y_mm": alignment.sample_offset_mm[1],
        "offset_z_mm": alignment.sample_offset_mm[2],
    }  # fmt: skip
    return np.array([values[n] for n in names])



def _physical(geometry: RigGeometry, joints: Joints, a: Alignment) -> tuple[FloatArray, ...]:
    """Physical light, camera, tilt, roll, yaw in radians for reported joints in degrees."""
    def of(name: str, fixed: float) -> FloatArray:
        value = getattr(joints, name, None)
        base = np.asarray(fixed if value is None else value, dtype=np.float64)
        return np.radians(base - a.zero_of(name))

    if geometry.layout == "in_plane":
        tilt, roll, yaw = of("tilt", 0.0), of("roll", -geometry.plane_azimuth_deg), of("yaw", 0.0)
        camera = of("camera", 0.0)
    elif geometry.layout == "fixed_camera":
        tilt, roll, yaw = of("tilt", 0.0), of("roll", 0.0), of("yaw", 0.0)
        camera = of("camera", geometry.camera_azimuth_deg)
    else:
        tilt, roll, yaw = of("tilt", 0.0), of("roll", 0.0), of("yaw", 0.0)
        camera = of("camera", 0.0)
    return of("light", 0.0), camera, tilt, roll, yaw


def _check_layout(geometry: RigGeometry, joints: Joints) -> None:
    present, expected = set(joints.as_dict()), set(geometry.joint_names)
    if present != expected:
        raise ValueError(
            f"a {geometry.layout} rig has joints {', '.join(geometry.joint_names)}; got {', '.join(sorted(present))}"
        )


def aligned_pose(geometry: RigGeometry, joints: Joints, alignment: Alignment) -> RigPose:
    """Where everything physically is (metres, unit vectors) for reported joints in degrees on a real rig."""
    if alignment.is_zero:
        return world_pose(geometry, joints)
    _check_layout(geometry, joints)
    light, camera, tilt, roll, yaw = _physical(geometry, joints, alignment)
    sx, sy, sz = _sample_axes(tilt, roll, yaw)
    shape = np.broadcast_shapes(sx.shape[:-1], light.shape, camera.shape)
    stage = np.stack([np.broadcast_to(v, (*shape, 3)) for v in (sx, sy, sz)], axis=-1)  # (..., 3, 3): columns
    local = stage @ alignment.wedge()
    centre = stage @ (np.asarray(alignment.sample_offset_mm) * 1e-3)
    return RigPose(
        sample_centre_m=centre,
        sample_normal=local[..., :, 2],
        sample_tangent=local[..., :, 0],
        sample_bitangent=local[..., :, 1],
        light_position_m=geometry.light_radius_m * np.broadcast_to(_arm(light), (*shape, 3)),
        camera_position_m=geometry.camera_radius_m * np.broadcast_to(_arm(camera), (*shape, 3)),
        aim_m=np.zeros((*shape, 3)),
    )


def viewed_point(pose: RigPose) -> FloatArray:
    """Where the camera's central ray (aimed at the arms' axis, the origin) meets the sample plane (m)."""
    c = np.asarray(pose.camera_position_m, dtype=np.float64)
    n = np.asarray(pose.sample_normal, dtype=np.float64)
    ray = -c / np.linalg.norm(c, axis=-1, keepdims=True)
    denom = np.sum(ray * n, axis=-1, keepdims=True)
    # A ray parallel to the plane (a grazing 90 deg view) meets it nowhere; the axis point is the limit.
    safe = np.where(np.abs(denom) > 1e-12, denom, 1.0)
    t = np.where(np.abs(denom) > 1e-12, np.sum((np.asarray(pose.sample_centre_m) - c) * n, -1, keepdims=True) / safe,
                 np.linalg.norm(c, axis=-1, keepdims=True))  # fmt: skip
    out: FloatArray = c + t * ray
    return out


def light_distance_m(geometry: RigGeometry, joints: Joints, alignment: Alignment) -> float:
    """Distance (m) from the light to the point the camera views, for reported joints in degrees on a real rig."""
    pose = aligned_pose(geometry, joints, alignment)
    return float(np.linalg.norm(np.asarray(pose.light_position_m) - viewed_point(pose)))


def pose_directions(pose: RigPose) -> Directions:
    """The BRDF directions (degrees, local unit vectors) measured at the viewed point of a pose."""
    p = viewed_point(pose)
    to_light = np.asarray(pose.light_position_m) - p
    to_camera = np.asarray(pose.camera_position_m) - p
    to_light = to_light / np.linalg.norm(to_light, axis=-1, keepdims=True)
    to_camera = to_camera / np.linalg.norm(to_camera, axis=-1, keepdims=True)
    axes = (pose.sample_tangent, pose.sample_bitangent, pose.sample_normal)
    x, y, z = (np.asarray(v, dtype=np.float64) for v in axes)
    wi, wo = _to_local(to_light, x, y, z), _to_local(to_camera, x, y, z)
    theta_i, phi_i = _angles(wi)
    theta_o, phi_o = _angles(wo)
    return Directions(theta_i, phi_i, theta_o, phi_o, wi, wo)


def aligned_forward(geometry: RigGeometry, joints: Joints, alignment: Alignment) -> Directions:
    """The directions a real rig measures for reported joints in degrees (``kinematics.forward`` when aligned)."""
    if alignment.is_zero:  # the same numbers, to the last bit, as every run before alignments existed
        return forward(geometry, joints)
    return pose_directions(aligned_pose(geometry, joints, alignment))


def _residual(geometry: RigGeometry, names: tuple[str, ...], q: FloatArray, alignment: Alignment,
              wi: FloatArray, wo: FloatArray) -> FloatArray:  # fmt: skip
    d = aligned_forward(geometry, Joints.from_dict({n: q[..., k] for k, n in enumerate(names)}), alignment)
    out: FloatArray = np.concatenate([d.wi - wi, d.wo - wo], axis=-1)
    return out


def aligned_inverse(
    geometry: RigGeometry,
    wi: npt.ArrayLike,
    wo: npt.ArrayLike,
    alignment: Alignment,
    start: Joints | None = None,
    *,
    iterations: int = 8,
    tol: float = 1e-10,
) -> tuple[Joints, FloatArray]:
    """Reported joints (degrees) that measure local unit directions wi, wo (..., 3) on a real rig.

    Gauss-Newton from ``start`` (default: the drawn rig's solution shifted by the zero offsets), over the
    layout's joints. Returns the joints and the remaining mismatch in degrees (the angle between wanted and
    measured direction, the larger of the two): 0 where the rig reaches the pair exactly, more where it
    cannot (an in-plane rig with a tilted sample cannot reach in-plane directions exactly).
    """
    a, b = np.broadcast_arrays(np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64))
    names = geometry.joint_names
    if start is None:
        nominal = solve(geometry, a, b).joints
        start = Joints.from_dict({n: np.asarray(getattr(nominal, n)) + alignment.zero_of(n) for n in names})
    q = np.stack([np.broadcast_to(np.asarray(getattr(start, n), dtype=np.float64), a.shape[:-1]) for n in names], -1)
    q = np.where(np.isfinite(q), q, 0.0)
    h = 1e-6
    for _ in range(iterations):
        r = _residual(geometry, names, q, alignment, a, b)
        jac = np.stack(
            [(_residual(geometry, names, q + h * np.eye(len(names))[k], alignment, a, b) - r) / h
             for k in range(len(names))], axis=-1,
        )  # fmt: skip
        jt = np.swapaxes(jac, -1, -2)
        step = np.linalg.solve(jt @ jac + 1e-18 * np.eye(len(names)), -(jt @ r[..., None]))[..., 0]
        q = q + step
        if np.all(np.abs(step) < tol):
            break
    d = aligned_forward(geometry, Joints.from_dict({n: q[..., k] for k, n in enumerate(names)}), alignment)
    miss = np.degrees(np.maximum(_angle(d.wi, a), _angle(d.wo, b)))
    return Joints.from_dict({n: (float(q[..., k]) if q.ndim == 1 else q[..., k]) for k, n in enumerate(names)}), miss


def _angle(u: FloatArray, v: FloatArray) -> FloatArray:
    out: FloatArray = np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.sum(u * v, axis=-1))
    return out
