"""Microfacet normal distributions and masking-shadowing terms.

Distributions D(h) are normalised so that the projected microfacet area is one:
integral of D(h) cos(theta_h) over the hemisphere of h = 1 (Walter et al. 2007). They take
cos_h = h.z of the unit half vector; slopes use sin^2 computed as 1 - cos^2 clamped at 0.

Roughness alpha is the slope-space width (GGX alpha, Beckmann RMS slope m). Values below
:data:`ALPHA_MIN` are clamped to it, the same clamp as Mitsuba 3, because D(h) of a perfect mirror is a
Dirac delta that no finite sample can represent (1/(pi alpha^2) = 3e7 at the clamp).

Masking: exact Smith (separable G1(wi) G1(wo), or height-correlated 1/(1 + L(wi) + L(wo))), the
Smith-Schlick approximation G1 = cos/(cos (1 - k) + k) with k = alpha/2 as in the PBR notes, the
Cook-Torrance V-groove term, or none.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
import numpy.typing as npt

Array = npt.NDArray[np.floating]

ALPHA_MIN = 1e-4
Distribution = Literal["ggx", "beckmann", "blinn_phong"]
Masking = Literal["smith", "smith_correlated", "smith_schlick", "v_groove", "none"]
DISTRIBUTIONS: tuple[str, ...] = ("ggx", "beckmann", "blinn_phong")
MASKINGS: tuple[str, ...] = ("smith", "smith_correlated", "smith_schlick", "v_groove", "none")


def clamp_alpha(alpha: npt.ArrayLike) -> Array:
    """Roughness clamped below at ALPHA_MIN (see the module docstring for why)."""
    return np.maximum(np.asarray(alpha), ALPHA_MIN)


def blinn_exponent_to_alpha(n: npt.ArrayLike) -> Array:
    """Beckmann-equivalent roughness of a Blinn-Phong exponent, alpha = sqrt(2 / (n + 2)) (Walter)."""
    return np.sqrt(2.0 / (np.asarray(n, dtype=float) + 2.0))


def alpha_to_blinn_exponent(alpha: npt.ArrayLike) -> Array:
    """Blinn-Phong exponent with the same Beckmann-equivalent roughness, n = 2 / alpha^2 - 2."""
    a = np.asarray(alpha, dtype=float)
    return 2.0 / (a * a) - 2.0


def _sin2_cos2(cos_h: Array) -> tuple[Array, Array]:
    c2 = cos_h * cos_h
    return np.maximum(0.0, 1.0 - c2), c2


def sin2_cos2(cos_h: npt.ArrayLike) -> tuple[Array, Array]:
    """(sin^2, cos^2) of a half vector's zenith cosine, as the distributions take them (dimensionless)."""
    return _sin2_cos2(np.asarray(cos_h))


def ggx_tan2(cos_v: npt.ArrayLike) -> Array:
    """tan^2 of a direction's zenith angle as :func:`ggx_lambda` takes it (cos^2 floored at the dtype's tiny)."""
    c = np.asarray(cos_v)
    c2 = np.maximum(c * c, np.finfo(c.dtype).tiny)
    return np.asarray(np.maximum(0.0, 1.0 - c2) / c2)


def ggx_d(cos_h: npt.ArrayLike, alpha: npt.ArrayLike, *, sin2_cos2: tuple[Array, Array] | None = None) -> Array:
    """GGX (Trowbridge-Reitz) normal distribution D(h) in 1/sr; zero for cos_h <= 0.

    ``sin2_cos2``: (sin^2, cos^2) of cos_h as :func:`sin2_cos2` makes them, where the caller keeps them (a Pair).
    """
    c = np.asarray(cos_h)
    a2 = clamp_alpha(alpha).astype(c.dtype) ** 2
    s2, c2 = _sin2_cos2(c) if sin2_cos2 is None else sin2_cos2
    # sin^2 + alpha^2 cos^2 instead of cos^2 (alpha^2 - 1) + 1: no cancellation when alpha -> 0.
    den = s2 + a2 * c2
    d = a2 / (math.pi * np.maximum(den * den, np.finfo(c.dtype).tiny))
    return np.where(c > 0, d, 0.0).astype(c.dtype)


def beckmann_d(
    cos_h: npt.ArrayLike, alpha: npt.ArrayLike, *, sin2_cos2: tuple[Array, Array] | None = None
) -> Array:
    """Beckmann normal distribution D(h) in 1/sr with RMS slope alpha; zero for cos_h <= 0 (``sin2_cos2``: ggx_d)."""
    c = np.asarray(cos_h)
    a2 = clamp_alpha(alpha).astype(c.dtype) ** 2
    s2, c2 = _sin2_cos2(c) if sin2_cos2 is None else sin2_cos2
    tiny = np.finfo(c.dtype).tiny
    c4 = np.maximum(c2 * c2, tiny)
    e = np.exp(-s2 / np.maximum(c2 * a2, tiny))
    # At grazing half vectors with a tiny alpha the denominator underflows (float32: alpha^2 cos^4 < 1e-45)
    # where the exponential already has: the density there is 0, not 0 / 0.
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(e > 0, e / (math.pi * a2 * c4), 0.0)
    return np.where(c > 0, d, 0.0).astype(c.dtype)


def blinn_phong_d(cos_h: npt.ArrayLike, exponent: npt.ArrayLike) -> Array:
    """Normalised Blinn-Phong distribution (n + 2)/(2 pi) cos_h^n in 1/sr; zero for cos_h <= 0."""
    c = np.asarray(cos_h)
    n = np.asarray(exponent, dtype=c.dtype)
    d = (n + 2.0) / (2.0 * math.pi) * np.power(np.maximum(c, 0.0), n)
    return np.where(c > 0, d, 0.0).astype(c.dtype)


def ggx_lambda(cos_v: npt.ArrayLike, alpha: npt.ArrayLike, *, tan2: Array | None = None) -> Array:
    """Smith Lambda of GGX for a direction with zenith cosine cos_v (> 0); ``tan2``: its :func:`ggx_tan2`, if kept."""
    c = np.asarray(cos_v)
    a2 = clamp_alpha(alpha).astype(c.dtype) ** 2
    tan2 = ggx_tan2(c) if tan2 is None else tan2
    return 0.5 * (np.sqrt(1.0 + a2 * tan2) - 1.0)


def beckmann_lambda(cos_v: npt.ArrayLike, alpha: npt.ArrayLike) -> Array:
    """Smith Lambda of Beckmann, exact: (erf(a) - 1)/2 + exp(-a^2)/(2 a sqrt(pi)), a = 1/(alpha tan)."""
    from scipy.special import erfc

    c = np.asarray(cos_v)
    al = clamp_alpha(alpha).astype(c.dtype)
    s = np.sqrt(np.maximum(0.0, 1.0 - c * c))
    # Beyond a = 40 both terms are below 1e-690 (Lambda is 0, no masking); below 1e-150 Lambda is
    # over 1e149 (G1 is 0 at grazing). Clipping keeps those limits without overflow warnings.
    a = np.clip(c / np.maximum(al * s, np.finfo(c.dtype).tiny), 1e-150 if c.dtype == np.float64 else 1e-30, 40.0)
    # -erfc(a)/2 is (erf(a) - 1)/2 without cancellation.
    lam = -0.5 * erfc(a) + np.exp(-a * a) / (2.0 * a * math.sqrt(math.pi))
    return np.maximum(lam, 0.0).astype(c.dtype)


def smith_g1(
    cos_v: npt.ArrayLike, alpha: npt.ArrayLike, distribution: str = "ggx", *, tan2: Array | None = None
) -> Array:
    """Exact Smith masking G1 = 1 / (1 + Lambda) of one direction; zero for cos_v <= 0 (``tan2``: ggx_lambda)."""
    c = np.asarray(cos_v)
    lam = _lambda(c, alpha, distribution, tan2)
    return np.where(c > 0, 1.0 / (1.0 + lam), 0.0).astype(c.dtype)


def _lambda(cos_v: Array, alpha: npt.ArrayLike, distribution: str, tan2: Array | None = None) -> Array:
    if distribution == "ggx":
        return ggx_lambda(cos_v, alpha, tan2=tan2)
    # Blinn-Phong has no closed-form Lambda; Walter et al. use Beckmann's at the equivalent alpha.
    return beckmann_lambda(cos_v, alpha)


def smith_schlick_g1(cos_v: npt.ArrayLike, k: npt.ArrayLike) -> Array:
    """Schlick's approximation of Smith G1 = cos / (cos (1 - k) + k); the notes use k = alpha/2."""
    c = np.asarray(cos_v)
    kk = np.asarray(k, dtype=c.dtype)
    g = c / np.maximum(c * (1.0 - kk) + kk, np.finfo(c.dtype).tiny)
    return np.where(c > 0, g, 0.0).astype(c.dtype)


def v_groove(cos_i: Array, cos_o: Array, cos_h: Array, cos_oh: Array) -> Array:
    """Cook-Torrance V-groove masking min(1, 2 cos_h cos_o / cos_oh, 2 cos_h cos_i / cos_oh)."""
    den = np.maximum(np.abs(cos_oh), np.finfo(cos_oh.dtype).tiny)
    g = np.minimum(1.0, np.minimum(2.0 * cos_h * cos_o / den, 2.0 * cos_h * cos_i / den))
    return np.clip(g, 0.0, 1.0)


def masking(
    kind: str,
    cos_i: Array,
    cos_o: Array,
    cos_h: Array,
    cos_oh: Array,
    alpha: npt.ArrayLike,
    distribution: str = "ggx",
    *,
    tan2: tuple[Array, Array] | None = None,
) -> Array:
    """Joint masking-shadowing G(wi, wo) of the named kind (see :data:`MASKINGS`).

    ``tan2``: the :func:`ggx_tan2` of cos_i and cos_o where the caller keeps them (a Pair); GGX's Smith uses them.
    """
    t_i, t_o = (None, None) if tan2 is None else tan2
    if kind == "smith":
        return smith_g1(cos_i, alpha, distribution, tan2=t_i) * smith_g1(cos_o, alpha, distribution, tan2=t_o)
    if kind == "smith_correlated":
        lam = _lambda(cos_i, alpha, distribution, t_i) + _lambda(cos_o, alpha, distribution, t_o)
        return np.where((cos_i > 0) & (cos_o > 0), 1.0 / (1.0 + lam), 0.0).astype(cos_i.dtype)
    if kind == "smith_schlick":
        k = 0.5 * clamp_alpha(alpha)
        return smith_schlick_g1(cos_i, k) * smith_schlick_g1(cos_o, k)
    if kind == "v_groove":
        return v_groove(cos_i, cos_o, cos_h, cos_oh)
    if kind == "none":
        return np.ones_like(cos_i)
    raise ValueError(f"unknown masking {kind!r}; expected one of {MASKINGS}")


def distribution_d(
    kind: str, cos_h: Array, alpha: npt.ArrayLike, *, sin2_cos2: tuple[Array, Array] | None = None
) -> Array:
    """Normal distribution D(h) of the named kind at roughness alpha (Blinn-Phong via its exponent; ``sin2_cos2``:
    see ggx_d)."""
    if kind == "ggx":
        return ggx_d(cos_h, alpha, sin2_cos2=sin2_cos2)
    if kind == "beckmann":
        return beckmann_d(cos_h, alpha, sin2_cos2=sin2_cos2)
    if kind == "blinn_phong":
        a = clamp_alpha(alpha)
        return blinn_phong_d(cos_h, alpha_to_blinn_exponent(a))
    raise ValueError(f"unknown distribution {kind!r}; expected one of {DISTRIBUTIONS}")


def half_vectors(kind: str, alpha: float, u1: Array, u2: Array) -> tuple[Array, Array]:
    """The half vectors h (N, 3) :func:`sample_half_vector` draws from u1, u2, and their cos(theta_h) (no pdf)."""
    a = max(float(alpha), ALPHA_MIN)
    if kind == "ggx":
        cos_t = 1.0 / np.sqrt(1.0 + a * a * u1 / np.maximum(1.0 - u1, 1e-300))
    elif kind == "beckmann":
        cos_t = 1.0 / np.sqrt(1.0 - a * a * np.log1p(-np.minimum(u1, 1.0 - 1e-16)))
    elif kind == "blinn_phong":
        # D cos = (n + 2)/(2 pi) cos^(n+1) has the CDF cos^(n+2) in cos(theta_h).
        cos_t = np.power(u1, 1.0 / (float(alpha_to_blinn_exponent(a)) + 2.0))
    else:
        raise ValueError(f"unknown distribution {kind!r}; expected one of {DISTRIBUTIONS}")
    sin_t = np.sqrt(np.maximum(0.0, 1.0 - cos_t * cos_t))
    phi = 2.0 * math.pi * u2
    return np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t], axis=-1), cos_t


def sample_half_vector(
    kind: str, alpha: float, u1: Array, u2: Array
) -> tuple[Array, Array]:
    """Sample h with density D(h) cos(theta_h) from uniform numbers u1, u2; returns (h, pdf_h in 1/sr)."""
    h, cos_t = half_vectors(kind, alpha, u1, u2)
    a = max(float(alpha), ALPHA_MIN)
    return h, distribution_d(kind, cos_t, a) * cos_t
