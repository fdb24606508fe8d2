"""Reachability measures behind ``rig.instrument.kinematics``: zeniths, arm separation, plane offset, the light's spot.

The illuminated spot: the light is a point source at ``light_radius_m`` emitting a circular cone of
half-angle beta around the direction to the sample centre. Its footprint on the sample plane is an exact
conic section: for theta_i + beta < 90 deg an ellipse with, along the incidence azimuth u (towards the
light) and across it w,

    k = cos^2(beta) - sin^2(theta_i)
    semi-axis along u   A = R sin(beta) cos(beta) cos(theta_i) / k      (grows like 1/cos^2 near grazing)
    semi-axis along w   B = R sin(beta) cos(theta_i) / sqrt(k)
    centre              x0 = -R sin(theta_i) sin^2(beta) / k  along u   (shifted away from the light)

so its near and far edges lie R sin(beta) / cos(theta_i -+ beta) from the sample centre. At
theta_i + beta >= 90 deg the footprint is unbounded.

Two criteria, both on this ellipse:

- the spot must stay on the sample: its extent along the sample's x and y axes (|centre| plus the
  ellipse's half-width along that axis) must not pass half the sample width and height; light beyond
  the edge would land on the stage, which the camera also sees;
- the camera must see the whole spot: projected orthographically along wo (the camera is far from the
  spot compared to its size), the spot's farthest reach from the view axis, bounded by |projected
  centre| + largest projected semi-axis (conservative by at most the small centre shift), must not
  pass the view radius ``camera_radius_m * tan(camera_fov_deg / 2)``.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from rig.instrument.geometry import RigGeometry

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class CheckDetails:
    """Per-point measures (arrays) the reachability checks compared: angles in degrees, reaches in metres."""

    theta_i: FloatArray
    theta_o: FloatArray
    phi_i: FloatArray
    phi_o: FloatArray
    separation: FloatArray
    off_plane_i: FloatArray
    off_plane_o: FloatArray
    spot_x: FloatArray
    spot_y: FloatArray
    spot_view: FloatArray
    failed_joint: npt.NDArray[np.int_]

    def replace(self, **changes: Any) -> CheckDetails:
        """A copy with some fields replaced."""
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class SpotEllipse:
    """The illuminated spot on the sample plane, in metres, along (u) and across (w) the incidence azimuth.

    ``centre_m`` is the centre's offset along u (negative: away from the light); all fields are inf when
    the beam reaches the horizon.
    """

    centre_m: FloatArray | float
    semi_along_m: FloatArray | float
    semi_across_m: FloatArray | float


def zenith_deg(w: FloatArray) -> FloatArray:
    """Zenith angle in degrees of local directions w (..., 3)."""
    out: FloatArray = np.degrees(np.arctan2(np.hypot(w[..., 0], w[..., 1]), w[..., 2]))
    return out


def separation_deg(u: FloatArray, v: FloatArray) -> FloatArray:
    """Angle in degrees between unit directions u and v (the angle between the arms)."""
    # atan2 of |u x v| and u . v stays accurate at small and near-180 angles where arccos does not.
    out: FloatArray = np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v), axis=-1), np.sum(u * v, axis=-1)))
    return out


def out_of_plane_deg(w: FloatArray, plane_azimuth_deg: float) -> FloatArray:
    """Angle in degrees between unit directions w and the vertical local plane at azimuth plane_azimuth_deg."""
    psi = math.radians(plane_azimuth_deg)
    across = -math.sin(psi) * w[..., 0] + math.cos(psi) * w[..., 1]
    out: FloatArray = np.degrees(np.arcsin(np.clip(np.abs(across), 0.0, 1.0)))
    return out


def _ellipse(geometry: RigGeometry, cos_t: FloatArray, sin_t: FloatArray) -> tuple[FloatArray, ...]:
    beta = math.radians(geometry.beam_half_angle_deg)
    r, sb, cb = geometry.light_radius_m, math.sin(beta), math.cos(beta)
    k = cb * cb - sin_t * sin_t
    bounded = k > 0
    ks = np.where(bounded, k, 1.0)
    inf = np.inf
    centre = np.where(bounded, -r * sin_t * sb * sb / ks, inf)
    along = np.where(bounded, r * sb * cb * cos_t / ks, inf)
    across = np.where(bounded, r * sb * cos_t / np.sqrt(ks), inf)
    return centre, along, across


def spot_ellipse(geometry: RigGeometry, theta_i_deg: npt.ArrayLike) -> SpotEllipse:
    """The illuminated spot's ellipse (metres) for incidence zenith angles in degrees."""
    t = np.radians(np.asarray(theta_i_deg, dtype=np.float64))
    centre, along, across = _ellipse(geometry, np.cos(t), np.abs(np.sin(t)))
    if centre.ndim == 0:
        return SpotEllipse(float(centre), float(along), float(across))
    return SpotEllipse(centre, along, across)


def _azimuth_axes(wi: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """sin(theta_i), cos(theta_i) and the unit incidence azimuth u (..., 2); u = x at the pole."""
    s = np.hypot(wi[..., 0], wi[..., 1])
    safe = np.where(s > 0, s, 1.0)
    u = np.stack([np.where(s > 0, wi[..., 0] / safe, 1.0), np.where(s > 0, wi[..., 1] / safe, 0.0)], axis=-1)
    return s, wi[..., 2], u


def spot_reach(geometry: RigGeometry, wi: FloatArray) -> tuple[FloatArray, FloatArray]:
    """How far (metres) the spot reaches from the sample centre along the sample's x and y axes."""
    s, c, u = _azimuth_axes(wi)
    centre, along, across = _ellipse(geometry, c, s)
    with np.errstate(invalid="ignore"):
        half_x = np.sqrt((along * u[..., 0]) ** 2 + (across * u[..., 1]) ** 2)
        half_y = np.sqrt((along * u[..., 1]) ** 2 + (across * u[..., 0]) ** 2)
        reach_x = np.where(np.isfinite(centre), np.abs(centre * u[..., 0]) + half_x, np.inf)
        reach_y = np.where(np.isfinite(centre), np.abs(centre * u[..., 1]) + half_y, np.inf)
    return reach_x, reach_y


def view_reach(geometry: RigGeometry, wi: FloatArray, wo: FloatArray) -> FloatArray:
    """Bound (metres) on the spot's farthest reach from the camera's view axis, orthographic along wo."""
    s, c, u2 = _azimuth_axes(wi)
    centre, along, across = _ellipse(geometry, c, s)
    zero = np.zeros_like(s)
    u = np.stack([u2[..., 0], u2[..., 1], zero], axis=-1)
    w = np.stack([-u2[..., 1], u2[..., 0], zero], axis=-1)
    pu = u - np.sum(u * wo, axis=-1, keepdims=True) * wo
    pw = w - np.sum(w * wo, axis=-1, keepdims=True) * wo
    with np.errstate(invalid="ignore"):
        g11 = along**2 * np.sum(pu * pu, -1)
        g22 = across**2 * np.sum(pw * pw, -1)
        g12 = along * across * np.sum(pu * pw, -1)
        largest = 0.5 * (g11 + g22) + np.sqrt(0.25 * (g11 - g22) ** 2 + g12**2)
        reach = np.abs(centre) * np.linalg.norm(pu, axis=-1) + np.sqrt(largest)
    out: FloatArray = np.where(np.isfinite(centre), reach, np.inf)
    return out


def _mm(metres: float) -> str:
    return "unbounded" if math.isinf(metres) else f"{metres * 1e3:.4g} mm"


def explain(
    geometry: RigGeometry,
    details: CheckDetails,
    code: str,
    index: int | tuple[int, ...],
    joints: dict[str, float],
) -> tuple[float | None, float | None, str | None, str]:
    """(value, limit, joint, message) for one unreachable point: what failed, by how much, and the field."""

    def at(a: npt.NDArray[Any]) -> float:
        return float(a[index])

    ti, to = at(details.theta_i), at(details.theta_o)
    # The direction named is the first that fails the check, the light's if both do.
    if code == "not_finite":
        return None, None, None, "directions must be finite, non-zero vectors (or finite angles in degrees)"
    if code == "below_horizon":
        side, theta = ("light", ti) if ti > 90.0 else ("camera", to)
        sub = "i" if side == "light" else "o"
        return theta, 90.0, None, (
            f"{side} direction is below the sample's horizon: theta_{sub} = {theta:.6g} deg > 90 deg"
        )
    if code == "max_zenith":
        side, theta = ("light", ti) if ti > geometry.max_zenith_deg else ("camera", to)
        sub = "i" if side == "light" else "o"
        return theta, geometry.max_zenith_deg, None, (
            f"{side} direction theta_{sub} = {theta:.6g} deg is beyond the rig's maximum zenith "
            f"{geometry.max_zenith_deg:g} deg (max_zenith_deg)"
        )
    if code == "out_of_plane":
        oi, oo = at(details.off_plane_i), at(details.off_plane_o)
        side, off, theta, phi = (
            ("light", oi, ti, at(details.phi_i)) if oi >= oo else ("camera", oo, to, at(details.phi_o))
        )
        psi = geometry.plane_azimuth_deg
        return off, 0.0, None, (
            f"{side} direction (theta {theta:.6g} deg, phi {phi:.6g} deg) lies {off:.6g} deg out of the in-plane "
            f"rig's measurement plane (phi = {psi:g} or {psi + 180.0:g} deg, plane_azimuth_deg): this rig "
            f"reaches only phi_o = phi_i or phi_i + 180 in that plane"
        )
    if code == "min_separation":
        sep = at(details.separation)
        return sep, geometry.min_separation_deg, None, (
            f"light and camera are {sep:.6g} deg apart, closer than the minimum arm separation "
            f"{geometry.min_separation_deg:g} deg (min_separation_deg): the arms would collide or the "
            f"camera would shadow the light"
        )
    if code == "spot_overfills_sample":
        rx, ry = at(details.spot_x), at(details.spot_y)
        hx, hy = 0.5 * geometry.sample_width_m, 0.5 * geometry.sample_height_m
        axis, reach, half, name = ("x", rx, hx, "width") if rx / hx >= ry / hy else ("y", ry, hy, "height")
        return reach, half, None, (
            f"the illuminated spot at theta_i = {ti:.6g} deg (beam half-angle {geometry.beam_half_angle_deg:g} "
            f"deg at {geometry.light_radius_m:g} m) reaches {_mm(reach)} from the sample centre along the "
            f"sample's {axis} axis, past its half-{name} {_mm(half)} (sample_{name}_m)"
        )
    if code == "spot_overfills_view":
        reach, view = at(details.spot_view), geometry.view_radius_m
        return reach, view, None, (
            f"seen from the camera at theta_o = {to:.6g} deg, the illuminated spot at theta_i = {ti:.6g} deg "
            f"reaches {_mm(reach)} from the view axis, past the camera's view radius {_mm(view)} "
            f"(camera_fov_deg {geometry.camera_fov_deg:g} at {geometry.camera_radius_m:g} m)"
        )
    if code == "joint_limit":
        name = geometry.joint_names[int(details.failed_joint[index])]
        value = joints[name]
        lo, hi = geometry.limits.of(name)
        bound = lo if value < lo else hi
        return value, bound, name, (
            f"joint {name!r} would need {value:.6g} deg (or a whole turn from it), outside its limits "
            f"[{lo:g}, {hi:g}] deg (limits.{name})"
        )
    raise ValueError(f"unknown reason code {code!r}")
