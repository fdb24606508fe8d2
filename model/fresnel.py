"""Fresnel reflectance: exact dielectric, exact conductor, Schlick's approximation, F0 from indices.

All functions take cos_i, the cosine between the incident direction and the (micro)surface normal,
and return unpolarised reflectance in [0, 1]. Indices are relative: eta = n_transmitted / n_incident,
and a conductor's index is eta + i k with k the extinction coefficient (both dimensionless).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.floating]


def f0_from_ior(eta: npt.ArrayLike, k: npt.ArrayLike = 0.0) -> Array:
    """Reflectance at normal incidence of an interface with relative index eta + i k."""
    e = np.asarray(eta, dtype=float)
    kk = np.asarray(k, dtype=float)
    return ((e - 1.0) ** 2 + kk * kk) / ((e + 1.0) ** 2 + kk * kk)


def ior_from_f0(f0: npt.ArrayLike) -> Array:
    """Real relative index eta > 1 of a dielectric whose normal-incidence reflectance is f0 (< 1)."""
    s = np.sqrt(np.clip(np.asarray(f0, dtype=float), 0.0, 1.0 - 1e-12))
    return (1.0 + s) / (1.0 - s)


def schlick_weight(cos_i: npt.ArrayLike) -> Array:
    """(1 - cos_i)^5 with cos_i clamped to [0, 1]: the part of Schlick's approximation that depends on no F0."""
    c = np.clip(np.asarray(cos_i), 0.0, 1.0)
    m = 1.0 - c
    m2 = m * m
    return np.asarray(m2 * m2 * m)


def schlick(cos_i: npt.ArrayLike, f0: npt.ArrayLike, *, weight: Array | None = None) -> Array:
    """Schlick's approximation F0 + (1 - F0)(1 - cos_i)^5; cos_i is clamped to [0, 1].

    ``weight``: :func:`schlick_weight` of cos_i where the caller keeps it (a Pair, over a fit's evaluations).
    """
    w: Any = schlick_weight(cos_i) if weight is None else weight
    return f0 + (1.0 - np.asarray(f0, dtype=w.dtype)) * w


def dielectric(cos_i: npt.ArrayLike, eta: npt.ArrayLike) -> Array:
    """Exact unpolarised reflectance of a dielectric interface, mean of |r_s|^2 and |r_p|^2.

    Handles eta < 1 (light leaving the denser medium): beyond the critical angle the result is
    exactly 1 (total internal reflection). eta = 1 gives 0 (no interface).
    """
    c = np.clip(np.abs(np.asarray(cos_i)), 0.0, 1.0)
    e = np.asarray(eta, dtype=c.dtype)
    sin2_t = (1.0 - c * c) / (e * e)
    cos_t = np.sqrt(np.maximum(0.0, 1.0 - sin2_t))
    # The sums are >= 0 and vanish only at grazing incidence with eta -> 0, which eta > 0 excludes;
    # the maximum guards the 0/0 of c = cos_t = 0 (grazing at exactly the critical angle).
    tiny = np.finfo(c.dtype).tiny
    rs = (c - e * cos_t) / np.maximum(c + e * cos_t, tiny)
    rp = (e * c - cos_t) / np.maximum(e * c + cos_t, tiny)
    f = 0.5 * (rs * rs + rp * rp)
    # Strictly beyond the critical angle only: at grazing with eta = 1 (no interface) F is 0, not 1.
    return np.where(sin2_t > 1.0, 1.0, np.minimum(f, 1.0)).astype(c.dtype)


def conductor(cos_i: npt.ArrayLike, eta: npt.ArrayLike, k: npt.ArrayLike) -> Array:
    """Exact unpolarised reflectance of an interface with complex relative index eta + i k.

    Real-arithmetic form of the complex Fresnel equations (as in PBRT and Mitsuba's fresnel_conductor),
    exact for any eta > 0, k >= 0; k = 0 reduces to the dielectric case without total internal
    reflection handling, so use :func:`dielectric` for eta < 1.
    """
    c = np.clip(np.abs(np.asarray(cos_i)), 0.0, 1.0)
    e = np.asarray(eta, dtype=c.dtype)
    kk = np.asarray(k, dtype=c.dtype)
    c2 = c * c
    s2 = 1.0 - c2
    e2, k2 = e * e, kk * kk
    t0 = e2 - k2 - s2
    a2pb2 = np.sqrt(t0 * t0 + 4.0 * e2 * k2)
    a = np.sqrt(np.maximum(0.0, 0.5 * (a2pb2 + t0)))
    t1 = a2pb2 + c2
    t2 = 2.0 * c * a
    rs = (t1 - t2) / np.maximum(t1 + t2, np.finfo(c.dtype).tiny)
    t3 = c2 * a2pb2 + s2 * s2
    t4 = t2 * s2
    rp = rs * (t3 - t4) / np.maximum(t3 + t4, np.finfo(c.dtype).tiny)
    return np.clip(0.5 * (rs + rp), 0.0, 1.0)


def conductor_complex(cos_i: npt.ArrayLike, eta: npt.ArrayLike, k: npt.ArrayLike) -> Array:
    """The same reflectance computed with complex arithmetic from the amplitude coefficients.

    Slower than :func:`conductor`; kept as an independent check of it and for teaching.
    """
    c = np.clip(np.abs(np.asarray(cos_i, dtype=float)), 0.0, 1.0)
    n = np.asarray(eta, dtype=float) + 1j * np.asarray(k, dtype=float)
    cos_t = np.sqrt(1.0 - (1.0 - c * c) / (n * n) + 0j)
    rs = (c - n * cos_t) / (c + n * cos_t)
    rp = (n * c - cos_t) / (n * c + cos_t)
    return np.asarray(0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2))
