"""The sample's surface: where rays meet it, its normals and shading tangents, and each hit's BRDF angles.

A sample is flat (the rig's sample square), a sphere or a cylinder of known radius. Placement, in the
frame of one ``RigPose`` (from ``rig.instrument.alignment.aligned_pose`` or ``kinematics.world_pose``),
with c = ``sample_centre_m``, n = ``sample_normal``, T = ``sample_tangent``, B = ``sample_bitangent``:

- ``"flat"``: the plane through c with normal n, limited to the rig's sample square (``sample_width_m``
  along T, ``sample_height_m`` along B), as the simulator's Mitsuba ``rectangle`` is. Tangent T.
- ``"sphere"``: centre c - R n, so its top touches where the flat sample's centre is (normal n there).
- ``"cylinder"``: axis along B through c - R n, length ``sample_height_m``, open at both ends; its top
  line passes through c with normal n. It curves along T, so at the rest pose its normals sweep the arms'
  plane, as the classic cylinder method wants.

Curved shapes' shading tangent: normalize(B x N) at a hit of normal N (the direction of increasing
longitude about the B axis). It equals T at the top (the flat sample's frame), lies along the cylinder's
circumference, and is exactly the ``s`` axis Mitsuba's ``sphere`` (pole on B) and ``cylinder`` (axis along
B) give their BSDFs, so an anisotropic material renders in the frame these angles are measured in. On
the sphere it agrees with T projected onto the tangent plane along the two great circles through the top
(the T-n and B-n planes), and differs from it only to second order near the top; at the sphere's two
points N = +-B, where B x N vanishes, T (then in the tangent plane) serves.

The local frame of a hit is (tangent, normal x tangent, normal), the kinematics' (x, y, z); angles follow
the project's conventions (both directions point away from the surface, phi from the local x axis, in
degrees) through ``rig.instrument.kinematics``'s own conversions. A ray that misses (or meets only the
inner side of the open cylinder, or the flat sample's back) has ``hit`` False and finite filler values:
the sample centre, n and T.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np
import numpy.typing as npt

from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import _angles, _to_local
from rig.instrument.kinematics_types import FloatArray, RigPose

BoolArray = npt.NDArray[np.bool_]
ShapeKind = Literal["flat", "sphere", "cylinder"]
SHAPE_KINDS: tuple[str, ...] = get_args(ShapeKind)

#: Relative slack at the flat square's edge: a ray aimed exactly at an edge counts as a hit despite rounding.
_EDGE_SLACK = 1e-12


@dataclass(frozen=True)
class SampleShape:
    """The sample's surface: "flat" (the rig's sample square), or a "sphere" / "cylinder" of radius_m."""

    kind: ShapeKind = "flat"
    radius_m: float = 0.0  # > 0 for sphere and cylinder, 0 for flat

    def __post_init__(self) -> None:
        if self.kind not in SHAPE_KINDS:
            raise ValueError(f"SampleShape.kind = {self.kind!r}, expected one of {', '.join(map(repr, SHAPE_KINDS))}")
        r = self.radius_m
        if isinstance(r, bool) or not isinstance(r, int | float) or not math.isfinite(r):
            raise ValueError(f"SampleShape.radius_m = {r!r}, expected a finite number of metres")
        if self.kind == "flat" and r != 0.0:
            raise ValueError(f"SampleShape.radius_m = {r!r} m for a flat sample, expected 0 (a flat sample has none)")
        if self.kind != "flat" and not r > 0.0:
            raise ValueError(f"SampleShape.radius_m = {r!r} m for a {self.kind}, expected a radius > 0")
        object.__setattr__(self, "radius_m", float(r))


#: The flat sample, every rig's default.
FLAT = SampleShape()


@dataclass(frozen=True)
class SurfaceHits:
    """Where rays meet the sample: world points (m), unit outward normals and shading tangents, and which hit."""

    point_m: FloatArray  # (N, 3) world points (metres)
    normal: FloatArray  # (N, 3) unit outward normals (world)
    tangent: FloatArray  # (N, 3) unit tangents: the local x axis of the shading frame (phi = 0)
    hit: BoolArray  # (N,) whether the ray meets the sample's surface on its lit (outer) side


@dataclass(frozen=True)
class LocalAngles:
    """Each hit's BRDF angles in degrees (theta_i, phi_i, theta_o, phi_o) and its distance to the light (m)."""

    theta_i_deg: FloatArray
    phi_i_deg: FloatArray
    theta_o_deg: FloatArray
    phi_o_deg: FloatArray
    light_distance_m: FloatArray


def _vec3(name: str, value: npt.ArrayLike) -> FloatArray:
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} = {value!r}, expected one finite 3-vector (metres or a unit vector)")
    return a


def _unit_rows(v: FloatArray) -> FloatArray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    out: FloatArray = v / np.where(n > 0, n, 1.0)
    return out


def _directions(directions: npt.ArrayLike) -> FloatArray:
    d = np.asarray(directions, dtype=np.float64)
    if d.ndim != 2 or d.shape[1] != 3:
        raise ValueError(f"directions have shape {d.shape}, expected (N, 3) unit vectors")
    norm = np.linalg.norm(d, axis=-1)
    if not np.all(np.isfinite(d)) or np.any(norm == 0):
        raise ValueError("directions must be finite, non-zero 3-vectors")
    out: FloatArray = d / norm[:, None]
    return out


def _flat(geometry: RigGeometry, c: FloatArray, n: FloatArray, t_axis: FloatArray, b_axis: FloatArray,
          o: FloatArray, d: FloatArray) -> tuple[FloatArray, BoolArray]:  # fmt: skip
    """Distance along each ray to the sample square's front (m) and whether it is met there."""
    denom = d @ n
    front = denom < 0.0  # the ray travels against the normal: it comes from the lit side
    t = np.where(front, ((c - o) @ n) / np.where(front, denom, -1.0), 0.0)
    q = o + t[:, None] * d - c
    hw, hh = 0.5 * geometry.sample_width_m, 0.5 * geometry.sample_height_m
    inside = (np.abs(q @ t_axis) <= hw * (1 + _EDGE_SLACK)) & (np.abs(q @ b_axis) <= hh * (1 + _EDGE_SLACK))
    return t, front & (t > 0.0) & inside


def _near_root(oc: FloatArray, d: FloatArray, radius: float) -> tuple[FloatArray, BoolArray]:
    """Nearest positive distance from outside to a circle/sphere of ``radius`` about the origin of ``oc``.

    ``oc`` and ``d`` are the origin and direction with any axial part removed (d need not be unit). The
    discriminant comes from the ray's closest approach, (R - |l|)(R + |l|), and the near root from
    c / (-b + sqrt(a disc)), so grazing rays and far origins keep their digits.
    """
    a = np.sum(d * d, axis=-1)
    ok = a > 0.0
    a_safe = np.where(ok, a, 1.0)
    b = np.sum(oc * d, axis=-1)
    closest = np.linalg.norm(oc - (b / a_safe)[:, None] * d, axis=-1)
    disc = (radius - closest) * (radius + closest)
    outside = np.sum(oc * oc, axis=-1) - radius * radius
    met = ok & (disc >= 0.0) & (b < 0.0) & (outside > 0.0)
    q = -b + np.sqrt(np.where(met, a_safe * disc, 0.0))
    t = np.where(met, outside / np.where(met, q, 1.0), 0.0)
    return t, met


def _curved_tangent(normal: FloatArray, t_axis: FloatArray, b_axis: FloatArray) -> FloatArray:
    """normalize(B x N), or T projected onto the tangent plane where N is along B (see the module)."""
    along = np.cross(b_axis, normal)
    size = np.linalg.norm(along, axis=-1, keepdims=True)
    projected = t_axis - (normal @ t_axis)[:, None] * normal
    fallback = _unit_rows(projected)
    out: FloatArray = np.where(size > 1e-12, along / np.where(size > 1e-12, size, 1.0), fallback)
    return out


def surface_hits(shape: SampleShape, geometry: RigGeometry, pose: RigPose,
                 origin_m: npt.ArrayLike, directions: npt.ArrayLike) -> SurfaceHits:  # fmt: skip
    """Where rays from origin_m (3,) along unit directions (N, 3) first meet the sample's surface."""
    c = _vec3("pose.sample_centre_m", pose.sample_centre_m)
    n = _unit_rows(_vec3("pose.sample_normal", pose.sample_normal))
    t_axis = _unit_rows(_vec3("pose.sample_tangent", pose.sample_tangent))
    b_axis = _unit_rows(_vec3("pose.sample_bitangent", pose.sample_bitangent))
    o = _vec3("origin_m", origin_m)
    d = _directions(directions)
    count = d.shape[0]
    if shape.kind == "flat":
        dist, hit = _flat(geometry, c, n, t_axis, b_axis, o, d)
        point = o + dist[:, None] * d
        normal = np.broadcast_to(n, (count, 3)).copy()
        tangent = np.broadcast_to(t_axis, (count, 3)).copy()
    else:
        r = shape.radius_m
        centre = c - r * n
        oc = o - centre
        if shape.kind == "sphere":
            dist, hit = _near_root(np.broadcast_to(oc, (count, 3)), d, r)
            point = o + dist[:, None] * d
            radial = point - centre
        else:
            # The circle problem in the plane across the axis; the axial part only decides the open ends.
            oc_across = oc - (oc @ b_axis) * b_axis
            d_across = d - (d @ b_axis)[:, None] * b_axis
            dist, hit = _near_root(np.broadcast_to(oc_across, (count, 3)), d_across, r)
            point = o + dist[:, None] * d
            axial = (point - centre) @ b_axis
            hit &= np.abs(axial) <= 0.5 * geometry.sample_height_m
            radial = point - centre - axial[:, None] * b_axis
        normal = _unit_rows(np.where(hit[:, None], radial, n))
        tangent = _curved_tangent(normal, t_axis, b_axis)
    # Misses carry the sample centre's values: finite, and never where the light or camera stands.
    point = np.where(hit[:, None], point, c)
    normal = np.where(hit[:, None], normal, n)
    tangent = np.where(hit[:, None], tangent, t_axis)
    return SurfaceHits(point_m=point, normal=normal, tangent=tangent, hit=hit)


def local_angles(hits: SurfaceHits, light_m: npt.ArrayLike, camera_m: npt.ArrayLike) -> LocalAngles:
    """Each hit's (theta_i, phi_i, theta_o, phi_o) in degrees and its distance to the light (m)."""
    light = _vec3("light_m", light_m)
    camera = _vec3("camera_m", camera_m)
    p = np.asarray(hits.point_m, dtype=np.float64)
    z = np.asarray(hits.normal, dtype=np.float64)
    x = np.asarray(hits.tangent, dtype=np.float64)
    y = np.cross(z, x)
    to_light = light - p
    distance = np.linalg.norm(to_light, axis=-1)
    to_camera = _unit_rows(camera - p)
    wi = _to_local(_unit_rows(to_light), x, y, z)
    wo = _to_local(to_camera, x, y, z)
    theta_i, phi_i = _angles(wi)
    theta_o, phi_o = _angles(wo)
    def deg(v: object) -> FloatArray:
        return np.atleast_1d(np.asarray(v, dtype=np.float64))

    return LocalAngles(deg(theta_i), deg(phi_i), deg(theta_o), deg(phi_o), light_distance_m=distance)
