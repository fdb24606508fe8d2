"""Directions in the local shading frame: z is the sample normal, both directions point away.

Angles are radians here; degrees live only at the user boundary (files, CLI, tables). Arrays of
directions have shape (..., 3) and broadcast. Half and difference angles follow Rusinkiewicz (1998).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.floating]

#: Smallest norm treated as a real direction; guards normalisation of near-zero vectors.
TINY = 1e-300


def float_dtype(*arrays: npt.ArrayLike) -> np.dtype:
    """The floating dtype for a computation: float32 if every input is float32, else float64."""
    dts = [np.asarray(a).dtype for a in arrays]
    if dts and all(d == np.float32 for d in dts):
        return np.dtype(np.float32)
    return np.dtype(np.float64)


def tiny(dtype: np.dtype) -> float:
    """The smallest positive normal number of a floating dtype, used as a safe divisor."""
    return float(np.finfo(dtype).tiny)


def normalize(v: npt.ArrayLike) -> Array:
    """Unit vectors along v (..., 3); a zero vector stays zero instead of becoming NaN."""
    a = np.asarray(v)
    if not np.issubdtype(a.dtype, np.floating):
        a = a.astype(np.float64)
    n = np.sqrt(np.sum(a * a, axis=-1, keepdims=True))
    return np.where(n > 0, a / np.maximum(n, tiny(a.dtype)), 0.0).astype(a.dtype)


def dot(a: Array, b: Array) -> Array:
    """Dot product over the last axis, keeping it (shape (..., 1))."""
    return np.sum(a * b, axis=-1, keepdims=True)


def spherical_to_vector(theta: npt.ArrayLike, phi: npt.ArrayLike) -> Array:
    """Unit vector from zenith theta and azimuth phi (radians); shape broadcast(theta, phi) + (3,)."""
    t = np.asarray(theta, dtype=float_dtype(theta, phi))
    p = np.asarray(phi, dtype=t.dtype)
    st = np.sin(t)
    return np.stack(np.broadcast_arrays(st * np.cos(p), st * np.sin(p), np.cos(t)), axis=-1)


def vector_to_spherical(v: npt.ArrayLike) -> tuple[Array, Array]:
    """Zenith theta in [0, pi] and azimuth phi in (-pi, pi] (radians) of directions v (..., 3)."""
    a = np.asarray(v, dtype=float_dtype(v))
    x, y, z = a[..., 0], a[..., 1], a[..., 2]
    # atan2 of the in-plane length keeps theta accurate near the pole, where arccos(z) loses digits.
    theta = np.arctan2(np.hypot(x, y), z)
    return theta, np.arctan2(y, x)


def degrees_to_vector(theta_deg: npt.ArrayLike, phi_deg: npt.ArrayLike) -> Array:
    """Unit vector from zenith and azimuth in degrees (the user-facing convention)."""
    return spherical_to_vector(np.radians(theta_deg), np.radians(phi_deg))


def cos_theta(v: Array) -> Array:
    """Cosine of the zenith angle (the z component), shape (..., 1)."""
    return v[..., 2:3]


def reflect(v: npt.ArrayLike, n: npt.ArrayLike = (0.0, 0.0, 1.0)) -> Array:
    """Mirror direction of v about the normal n; both point away from the surface."""
    a = np.asarray(v, dtype=float_dtype(v))
    nn = np.asarray(n, dtype=a.dtype)
    return 2.0 * dot(a, nn) * nn - a


def refract(
    v: npt.ArrayLike, eta: npt.ArrayLike, n: npt.ArrayLike = (0.0, 0.0, 1.0)
) -> tuple[Array, Array]:
    """Refracted direction of v (pointing away, on the side of n) into a medium of relative index eta.

    eta = n_transmitted / n_incident. Returns (direction, tir) where tir is True under total internal
    reflection; there the direction is the mirror direction, so callers never see NaN.
    """
    a = np.asarray(v, dtype=float_dtype(v))
    nn = np.asarray(n, dtype=a.dtype)
    e = np.asarray(eta, dtype=a.dtype)[..., None]
    c = dot(a, nn)
    sin2_t = (1.0 - c * c) / (e * e)
    tir = sin2_t > 1.0
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - sin2_t))
    t = -a / e + (c / e - cos_t) * nn
    return np.where(tir, reflect(a, nn), t), tir[..., 0]


def critical_angle(eta: npt.ArrayLike) -> Array:
    """Critical angle (radians) for light leaving a medium into one eta times less dense; pi/2 if none.

    eta = n_outside / n_inside; total internal reflection exists only for eta < 1.
    """
    e = np.asarray(eta, dtype=float)
    return np.where(e < 1.0, np.arcsin(np.clip(e, 0.0, 1.0)), np.pi / 2)


def half_vector(wi: Array, wo: Array) -> Array:
    """Normalised half vector of two directions; zero where they are exactly opposite."""
    return normalize(wi + wo)


def _rotate_z(v: Array, angle: Array) -> Array:
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1], v[..., 2]], axis=-1)


def _rotate_y(v: Array, angle: Array) -> Array:
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * v[..., 0] + s * v[..., 2], v[..., 1], -s * v[..., 0] + c * v[..., 2]], axis=-1)


def to_half_diff(wi: npt.ArrayLike, wo: npt.ArrayLike) -> tuple[Array, Array, Array, Array]:
    """Rusinkiewicz coordinates (theta_h, phi_h, theta_d, phi_d) in radians of a direction pair."""
    a = np.asarray(wi, dtype=float_dtype(wi, wo))
    b = np.asarray(wo, dtype=a.dtype)
    h = half_vector(a, b)
    theta_h, phi_h = vector_to_spherical(h)
    d = _rotate_y(_rotate_z(a, -phi_h), -theta_h)
    theta_d, phi_d = vector_to_spherical(d)
    return theta_h, phi_h, theta_d, phi_d


def from_half_diff(
    theta_h: npt.ArrayLike, phi_h: npt.ArrayLike, theta_d: npt.ArrayLike, phi_d: npt.ArrayLike
) -> tuple[Array, Array]:
    """Direction pair (wi, wo) from Rusinkiewicz half/difference angles in radians."""
    th, ph, td, pd = (np.asarray(x, dtype=float_dtype(theta_h, phi_h, theta_d, phi_d))
                      for x in (theta_h, phi_h, theta_d, phi_d))
    d = spherical_to_vector(td, pd)
    th_b, ph_b = np.broadcast_arrays(th, ph)
    wi = _rotate_z(_rotate_y(d, th_b), ph_b)
    h = spherical_to_vector(th_b, ph_b)
    return wi, reflect(wi, h)


def build_frame(n: npt.ArrayLike) -> tuple[Array, Array, Array]:
    """Orthonormal frame (s, t, n) around unit normals n (..., 3), continuous away from n = -z.

    Uses the branchless construction of Duff et al. (2017).
    """
    nn = normalize(n)
    x, y, z = nn[..., 0], nn[..., 1], nn[..., 2]
    sign = np.where(z >= 0, 1.0, -1.0)
    a = -1.0 / (sign + z)
    b = x * y * a
    s = np.stack([1.0 + sign * x * x * a, sign * b, -sign * x], axis=-1)
    t = np.stack([b, sign + y * y * a, -y], axis=-1)
    return s, t, nn


def to_local(v: npt.ArrayLike, n: npt.ArrayLike) -> Array:
    """Express world directions v in the local frame whose z axis is the normal n."""
    s, t, nn = build_frame(n)
    a = np.asarray(v, dtype=float)
    return np.concatenate([dot(a, s), dot(a, t), dot(a, nn)], axis=-1)
