"""Joint angles from BRDF directions (inverse) and back (forward), and where everything sits in the world.

Directions: the sample's local frame (z = sample normal, x = tangent, y = bitangent), both directions
pointing away from the surface; angles in degrees at this boundary (theta_i, phi_i, theta_o, phi_o),
unit vectors and radians inside. The light gives the incident direction wi, the camera the outgoing wo.

World frame (metres; the sample centre is the origin):

- z points up and is the axis both arms turn about; the arms sweep the horizontal x-y plane.
- An arm (or the fixed camera) at angle a points from the origin along (cos a, sin a, 0); positive
  angles turn counter-clockwise seen from above (right-handed about +z). Light at
  ``light_radius_m * (cos a, sin a, 0)``, camera likewise at ``camera_radius_m``.
- Stage at rest (all stage joints 0): the sample stands upright facing +x (arm angle 0): normal = +x,
  tangent (local x) = +y, bitangent (local y) = +z. Seen from the rest pose, in-plane directions with
  the light at a > 0 have phi = 0 and a < 0 phi = 180, theta = |a|.
- Stage joints compose outermost first: yaw (``fixed_camera`` only) turns the whole stage about +z;
  tilt t turns about the world -y axis (right-handed), so positive tilt lifts the normal to
  (cos t, 0, sin t); roll r turns the sample about its own normal (right-handed), which makes the arm
  plane appear at local azimuth -r.

Four-axis inverse: the world's vertical, seen in the sample frame, must be perpendicular to both wi and
wo, so it is +-m with m = wi x wo / |wi x wo|; then tilt = asin(m_z), roll = atan2(m_x, m_y), and the arm
angles follow. The two signs are the two solutions, (tilt, roll) and (-tilt, roll + 180) with the arms
mirrored. We choose by *arm order*: branch ``"camera_cw"`` (default) puts the camera clockwise of the
light seen from above, by the angle between the two directions (less than 180 deg), so the arms never
swap sides; the usual forward-scattering plane (phi_i = 0, phi_o = 180) then sits at tilt 0, roll 0 with
the light at +theta_i and the camera at -theta_o. ``"camera_ccw"`` is the mirrored solution. The choice is
deterministic and continuous everywhere except at wi = wo (excluded by any positive
``min_separation_deg``; there tilt is 0) and at wrap-arounds, which joint limits and ``near`` settle:
each rotary joint takes the 360-deg equivalent inside its limits closest to ``near`` (the previous pose
in a sweep) or, without ``near``, closest to 0 (the canonical angle in (-180, 180] on a tie).

In-plane rig: the sample is fixed at tilt 0 and roll -plane_azimuth_deg, so the arm plane is the local
plane at phi = plane_azimuth_deg (light arm angle > 0) or plane_azimuth_deg + 180 (< 0); the arm angle
is the signed zenith, a = atan2(w . p, w_z) with p the in-plane azimuth direction.

Fixed-camera rig: the four-axis solution turned about +z by yaw = camera_azimuth - camera so the camera
lands on its fixed direction; the light arm becomes light + yaw. A fixed camera takes away one arm, and
the stage needs its third axis (yaw) to keep all four BRDF dimensions.

phi is undefined at theta = 0: ``forward`` reports phi = 0 there (when sin(theta) < 1e-12); compare
direction vectors (``Directions.wi``/``wo``) rather than raw azimuths near the pole.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from model.geometry import degrees_to_vector
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics_checks import (
    CheckDetails,
    SpotEllipse,
    out_of_plane_deg,
    separation_deg,
    spot_ellipse,
    spot_reach,
    view_reach,
    zenith_deg,
)
from rig.instrument.kinematics_scalar import forward_one
from rig.instrument.kinematics_types import (
    BRANCHES,
    Angle,
    Branch,
    Directions,
    FloatArray,
    Joints,
    Reason,
    RigPose,
    Solution,
    Unreachable,
    UnreachableError,
    require,
)

__all__ = [
    "BRANCHES",
    "PLANE_TOLERANCE_DEG",
    "Angle",
    "Branch",
    "Directions",
    "Joints",
    "Reason",
    "RigPose",
    "Solution",
    "SpotEllipse",
    "Unreachable",
    "UnreachableError",
    "forward",
    "inverse",
    "require",
    "solve",
    "solve_degrees",
    "spot_ellipse",
    "world_pose",
]

#: How far (degrees) a direction may lie off the in-plane rig's measurement plane and still count as in it.
PLANE_TOLERANCE_DEG = 1e-7


# ----------------------------------------------------------------------------------------------------------
# Rotations


def _wrap180(deg: FloatArray) -> FloatArray:
    """Angles in degrees wrapped into (-180, 180]."""
    out: FloatArray = 180.0 - np.mod(180.0 - deg, 360.0)
    return out


def _sample_axes(tilt: FloatArray, roll: FloatArray, yaw: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """World images of the sample's local x, y, z axes for stage angles in radians; each (..., 3)."""
    ct, st = np.cos(tilt), np.sin(tilt)
    cr, sr = np.cos(roll), np.sin(roll)
    cy, sy = np.cos(yaw), np.sin(yaw)
    zero = np.zeros_like(ct * cr * cy)
    # At tilt t, roll 0: x0 = (0, 1, 0), y0 = (-sin t, 0, cos t), z0 = (cos t, 0, sin t); roll mixes x0, y0.
    axes = []
    for vx, vy, vz in (
        (-sr * st, cr + zero, sr * ct),
        (-cr * st, -sr + zero, cr * ct),
        (ct + zero, zero, st + zero),
    ):
        axes.append(np.stack([cy * vx - sy * vy, sy * vx + cy * vy, vz + zero], axis=-1))
    return axes[0], axes[1], axes[2]


def _arm(angle_rad: FloatArray) -> FloatArray:
    """Unit vector of an arm at an angle (radians) in the horizontal plane."""
    a = np.asarray(angle_rad, dtype=np.float64)
    return np.stack([np.cos(a), np.sin(a), np.zeros_like(a)], axis=-1)


def _to_local(d: FloatArray, x: FloatArray, y: FloatArray, z: FloatArray) -> FloatArray:
    """World direction d expressed in the frame (x, y, z)."""
    return np.stack([np.sum(d * x, -1), np.sum(d * y, -1), np.sum(d * z, -1)], axis=-1)


def _angle_of(d: FloatArray) -> FloatArray:
    """Arm angle in radians of a (horizontal) world direction."""
    out: FloatArray = np.arctan2(d[..., 1], d[..., 0])
    return out


# ----------------------------------------------------------------------------------------------------------
# Inverse


def _four_axis(wi: FloatArray, wo: FloatArray, branch: str) -> dict[str, FloatArray]:
    """Light, camera, tilt, roll (radians) of the four-axis rig for unit directions wi, wo."""
    # wi x (wo - wi) equals wi x wo but keeps its relative accuracy when the two are nearly parallel.
    c = np.cross(wi, wo - wi)
    n = np.linalg.norm(c, axis=-1, keepdims=True)
    # wi parallel to wo: any vertical perpendicular to wi works; taking it horizontal in the sample frame
    # gives tilt 0, and the pole itself falls back to the rest pose's vertical (0, 1, 0).
    g = np.stack([wi[..., 1], -wi[..., 0], np.zeros_like(wi[..., 0])], axis=-1)
    gn = np.linalg.norm(g, axis=-1, keepdims=True)
    fallback = np.where(gn > 0, g / np.where(gn > 0, gn, 1.0), np.array([0.0, 1.0, 0.0]))
    m = np.where(n > 0, c / np.where(n > 0, n, 1.0), fallback)
    if branch == "camera_cw":
        m = -m
    tilt = np.arctan2(m[..., 2], np.hypot(m[..., 0], m[..., 1]))
    roll = np.arctan2(m[..., 0], m[..., 1])
    x, y, z = _sample_axes(tilt, roll, np.zeros_like(tilt))
    light = _angle_of(wi[..., 0:1] * x + wi[..., 1:2] * y + wi[..., 2:3] * z)
    camera = _angle_of(wo[..., 0:1] * x + wo[..., 1:2] * y + wo[..., 2:3] * z)
    return {"light": light, "camera": camera, "tilt": tilt, "roll": roll}


def _raw_solution(geometry: RigGeometry, wi: FloatArray, wo: FloatArray, branch: str) -> dict[str, FloatArray]:
    """Unwrapped joint angles in degrees for the geometry's layout."""
    if geometry.layout == "in_plane":
        psi = np.radians(geometry.plane_azimuth_deg)
        p = np.array([np.cos(psi), np.sin(psi), 0.0])
        return {
            "light": np.degrees(np.arctan2(np.sum(wi * p, -1), wi[..., 2])),
            "camera": np.degrees(np.arctan2(np.sum(wo * p, -1), wo[..., 2])),
        }
    sol = {k: np.degrees(v) for k, v in _four_axis(wi, wo, branch).items()}
    if geometry.layout == "fixed_camera":
        yaw = geometry.camera_azimuth_deg - sol.pop("camera")
        return {"light": sol["light"] + yaw, "yaw": yaw, "tilt": sol["tilt"], "roll": sol["roll"]}
    return sol


#: Multiples of 360 deg tried for each rotary joint, in order of preference on a tie (k = 0 first).
_TURNS = np.array([0.0, -1.0, 1.0, -2.0, 2.0])


def _place(
    deg: FloatArray, limits: tuple[float, float], near: Angle | None
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """The 360-deg equivalent of each angle inside the limits, nearest ``near`` (or 0); and the inside mask."""
    c = _wrap180(deg)
    cand = c[..., None] + 360.0 * _TURNS
    inside = (cand >= limits[0]) & (cand <= limits[1])
    ref = np.zeros(()) if near is None else np.asarray(near, dtype=np.float64)[..., None]
    ref = np.where(np.isfinite(ref), ref, 0.0)
    score = np.where(inside, np.abs(cand - ref), np.inf)
    best = np.take_along_axis(cand, np.argmin(score, axis=-1)[..., None], axis=-1)[..., 0]
    ok: npt.NDArray[np.bool_] = np.asarray(inside.any(axis=-1))
    return np.where(ok, best, c), ok


def solve(
    geometry: RigGeometry,
    wi: npt.ArrayLike,
    wo: npt.ArrayLike,
    *,
    branch: Branch = "camera_cw",
    near: Joints | None = None,
) -> Solution:
    """Joint angles in degrees and reachability for local unit directions wi, wo (..., 3), vectorised."""
    if branch not in BRANCHES:
        raise ValueError(f"branch = {branch!r}, expected one of {', '.join(map(repr, BRANCHES))}")
    a, b = np.broadcast_arrays(np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64))
    if a.shape[-1:] != (3,):
        raise ValueError(f"directions must have shape (..., 3), got {a.shape}")
    shape = a.shape[:-1]
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        na = np.linalg.norm(a, axis=-1, keepdims=True)
        nb = np.linalg.norm(b, axis=-1, keepdims=True)
        valid = (np.isfinite(na) & np.isfinite(nb) & (na > 0) & (nb > 0))[..., 0]
        # Invalid points compute on a harmless stand-in so nothing below produces warnings or NaN.
        safe = np.array([0.0, 0.0, 1.0])
        u = np.where(valid[..., None], a / np.where(valid[..., None], na, 1.0), safe)
        v = np.where(valid[..., None], b / np.where(valid[..., None], nb, 1.0), safe)
        spot_x, spot_y = spot_reach(geometry, u)
        details = CheckDetails(
            theta_i=zenith_deg(u),
            theta_o=zenith_deg(v),
            phi_i=np.degrees(np.arctan2(u[..., 1], u[..., 0])),
            phi_o=np.degrees(np.arctan2(v[..., 1], v[..., 0])),
            separation=separation_deg(u, v),
            off_plane_i=out_of_plane_deg(u, geometry.plane_azimuth_deg),
            off_plane_o=out_of_plane_deg(v, geometry.plane_azimuth_deg),
            spot_x=spot_x,
            spot_y=spot_y,
            spot_view=view_reach(geometry, u, v),
            failed_joint=np.full(shape, -1),
        )
        raw = _raw_solution(geometry, u, v, branch)

    reason = np.full(shape, "", dtype="<U24")

    def mark(mask: npt.NDArray[np.bool_], code: Reason) -> None:
        reason[(reason == "") & mask] = code.value

    mark(~valid, Reason.NOT_FINITE)
    mark((details.theta_i > 90.0) | (details.theta_o > 90.0), Reason.BELOW_HORIZON)
    mark(np.maximum(details.theta_i, details.theta_o) > geometry.max_zenith_deg, Reason.MAX_ZENITH)
    if geometry.layout == "in_plane":
        mark(np.maximum(details.off_plane_i, details.off_plane_o) > PLANE_TOLERANCE_DEG, Reason.OUT_OF_PLANE)
    mark(details.separation < geometry.min_separation_deg, Reason.MIN_SEPARATION)
    mark(
        (details.spot_x > 0.5 * geometry.sample_width_m) | (details.spot_y > 0.5 * geometry.sample_height_m),
        Reason.SPOT_OVERFILLS_SAMPLE,
    )
    mark(details.spot_view > geometry.view_radius_m, Reason.SPOT_OVERFILLS_VIEW)

    placed: dict[str, FloatArray] = {}
    failed = np.full(shape, -1)
    for j, name in enumerate(geometry.joint_names):
        prev = None if near is None else getattr(near, name)
        placed[name], ok = _place(raw[name], geometry.limits.of(name), prev)
        failed = np.where((failed < 0) & ~ok, j, failed)
    mark(failed >= 0, Reason.JOINT_LIMIT)
    if not valid.all():
        placed = {k: np.where(valid, val, np.nan) for k, val in placed.items()}
    return Solution(geometry, u, v, Joints.from_dict(placed), reason, details.replace(failed_joint=failed))


def solve_degrees(
    geometry: RigGeometry,
    theta_i: npt.ArrayLike,
    phi_i: npt.ArrayLike,
    theta_o: npt.ArrayLike,
    phi_o: npt.ArrayLike,
    *,
    branch: Branch = "camera_cw",
    near: Joints | None = None,
) -> Solution:
    """Vectorised inverse kinematics for BRDF angles in degrees (arrays broadcast); see ``solve``."""
    return solve(geometry, degrees_to_vector(theta_i, phi_i), degrees_to_vector(theta_o, phi_o),
                 branch=branch, near=near)


def inverse(
    geometry: RigGeometry,
    theta_i: float,
    phi_i: float,
    theta_o: float,
    phi_o: float,
    *,
    branch: Branch = "camera_cw",
    near: Joints | None = None,
) -> Joints | Unreachable:
    """Joint angles in degrees for one pair of BRDF directions in degrees, or why it is unreachable."""
    return solve_degrees(geometry, theta_i, phi_i, theta_o, phi_o, branch=branch, near=near).at(())


# ----------------------------------------------------------------------------------------------------------
# Forward


def _joint(joints: Joints, name: str) -> FloatArray:
    value = getattr(joints, name)
    return np.radians(np.asarray(value, dtype=np.float64))


def _stage_and_arms(geometry: RigGeometry, joints: Joints) -> tuple[FloatArray, ...]:
    """Sample axes x, y, z and unit light/camera directions in the world for joints in degrees."""
    present = set(joints.as_dict())
    expected = set(geometry.joint_names)
    if present != expected:
        raise ValueError(
            f"a {geometry.layout} rig has joints {', '.join(geometry.joint_names)}; "
            f"got {', '.join(sorted(present))}"
        )
    light = _joint(joints, "light")
    if geometry.layout == "in_plane":
        zero = np.zeros(())
        tilt, roll, yaw = zero, np.radians(np.asarray(-geometry.plane_azimuth_deg)), zero
        camera = _joint(joints, "camera")
    elif geometry.layout == "fixed_camera":
        tilt, roll, yaw = _joint(joints, "tilt"), _joint(joints, "roll"), _joint(joints, "yaw")
        camera = np.radians(np.asarray(geometry.camera_azimuth_deg, dtype=np.float64))
    else:
        tilt, roll, yaw = _joint(joints, "tilt"), _joint(joints, "roll"), np.zeros(())
        camera = _joint(joints, "camera")
    x, y, z = _sample_axes(tilt, roll, yaw)
    shape = np.broadcast_shapes(x.shape[:-1], light.shape, camera.shape)
    x, y, z = (np.broadcast_to(v, (*shape, 3)) for v in (x, y, z))
    d_light = np.broadcast_to(_arm(light), (*shape, 3))
    d_camera = np.broadcast_to(_arm(camera), (*shape, 3))
    return x, y, z, d_light, d_camera


def _out(a: FloatArray) -> Angle:
    return float(a) if np.ndim(a) == 0 else a


def _angles(w: FloatArray) -> tuple[Angle, Angle]:
    """Zenith and azimuth in degrees; azimuth 0 where sin(theta) < 1e-12 (phi undefined at the pole)."""
    s = np.hypot(w[..., 0], w[..., 1])
    theta = np.degrees(np.arctan2(s, w[..., 2]))
    phi = np.where(s < 1e-12, 0.0, np.degrees(np.arctan2(w[..., 1], w[..., 0])))
    return _out(theta), _out(phi)


def forward(geometry: RigGeometry, joints: Joints) -> Directions:
    """The BRDF directions (degrees and local unit vectors) a set of joint angles in degrees measures."""
    one = forward_one(geometry, joints)  # one pose of floats (the runner's read-backs): the same bits, faster
    if one is not None:
        return one
    x, y, z, d_light, d_camera = _stage_and_arms(geometry, joints)
    wi = _to_local(d_light, x, y, z)
    wo = _to_local(d_camera, x, y, z)
    theta_i, phi_i = _angles(wi)
    theta_o, phi_o = _angles(wo)
    return Directions(theta_i, phi_i, theta_o, phi_o, wi, wo)


def world_pose(geometry: RigGeometry, joints: Joints) -> RigPose:
    """World positions (metres) of sample centre, light and camera, and the sample's axes, for joints in degrees."""
    x, y, z, d_light, d_camera = _stage_and_arms(geometry, joints)
    return RigPose(
        sample_centre_m=np.zeros_like(z),
        sample_normal=np.array(z),
        sample_tangent=np.array(x),
        sample_bitangent=np.array(y),
        light_position_m=geometry.light_radius_m * d_light,
        camera_position_m=geometry.camera_radius_m * d_camera,
    )
