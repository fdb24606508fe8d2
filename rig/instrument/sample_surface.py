"""Where camera rays meet the sample's surface, and each hit's local BRDF angles and light distance.

STAND-IN (flat only) for the image-mode branch: the "sample shapes" work owns this module and replaces it
with flat, sphere and cylinder at merge. The names and signatures are the shared API's, exactly.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import _angles, _to_local
from rig.instrument.kinematics_types import RigPose

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class SampleShape:
    """The sample's surface: "flat" (the rig's sample square), or a "sphere" / "cylinder" of radius_m."""

    kind: Literal["flat", "sphere", "cylinder"] = "flat"
    radius_m: float = 0.0

    def __post_init__(self) -> None:
        if self.kind != "flat":
            raise ValueError(f"SampleShape.kind = {self.kind!r}: this stand-in knows only 'flat'")


@dataclass(frozen=True)
class SurfaceHits:
    """Ray hits: world points (N, 3) m, unit outward normals and tangents (N, 3), and whether each hit (N,)."""

    point_m: FloatArray
    normal: FloatArray
    tangent: FloatArray
    hit: BoolArray


@dataclass(frozen=True)
class LocalAngles:
    """Each hit's (theta_i, phi_i, theta_o, phi_o) in degrees and its distance to the light (m), (N,) each."""

    theta_i_deg: FloatArray
    phi_i_deg: FloatArray
    theta_o_deg: FloatArray
    phi_o_deg: FloatArray
    light_distance_m: FloatArray


def surface_hits(shape: SampleShape, geometry: RigGeometry, pose: RigPose,
                 origin_m: npt.ArrayLike, directions: npt.ArrayLike) -> SurfaceHits:  # fmt: skip
    """Where rays from origin_m (3,) along unit directions (N, 3) first meet the sample's surface."""
    origin = np.asarray(origin_m, dtype=np.float64)
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    centre = np.asarray(pose.sample_centre_m, dtype=np.float64)
    n = np.asarray(pose.sample_normal, dtype=np.float64)
    tx = np.asarray(pose.sample_tangent, dtype=np.float64)
    ty = np.asarray(pose.sample_bitangent, dtype=np.float64)
    denom = d @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((centre - origin) @ n) / denom
    point = origin + np.where(np.isfinite(t), t, 0.0)[:, None] * d
    q = point - centre
    inside = (np.abs(q @ tx) <= 0.5 * geometry.sample_width_m) & (np.abs(q @ ty) <= 0.5 * geometry.sample_height_m)
    # The lit side faces the origin: the ray runs against the normal.
    hit = np.isfinite(t) & (t > 0) & (denom < 0) & inside
    count = d.shape[0]
    return SurfaceHits(point, np.broadcast_to(n, (count, 3)).copy(), np.broadcast_to(tx, (count, 3)).copy(), hit)


def local_angles(hits: SurfaceHits, light_m: npt.ArrayLike, camera_m: npt.ArrayLike) -> LocalAngles:
    """Each hit's (theta_i, phi_i, theta_o, phi_o) in degrees and its distance to the light (m)."""
    p = hits.point_m
    z = hits.normal
    x = hits.tangent
    y = np.cross(z, x)
    to_light = np.asarray(light_m, dtype=np.float64) - p
    to_camera = np.asarray(camera_m, dtype=np.float64) - p
    dist = np.linalg.norm(to_light, axis=-1)
    wi = _to_local(to_light / dist[:, None], x, y, z)
    wo = _to_local(to_camera / np.linalg.norm(to_camera, axis=-1, keepdims=True), x, y, z)
    ti, pi = _angles(wi)
    to, po = _angles(wo)
    a = [np.atleast_1d(np.asarray(v, dtype=np.float64)) for v in (ti, pi, to, po)]
    return LocalAngles(a[0], a[1], a[2], a[3], dist)
