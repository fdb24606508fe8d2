"""Compiled (numba) evaluation of a Cook-Torrance microfacet BRDF over arrays of direction pairs.

The kernel takes plain arrays and parameters (a distribution, masking and Fresnel name, the Fresnel
indices, rho_d, alpha, the form's scale): it knows no model class. ``CookTorrance.eval`` dispatches here
(:meth:`model.cook_torrance.CookTorrance.compiled_eval`), never the other way round.

The numpy code in :mod:`model.base`, :mod:`model.microfacet` and :mod:`model.fresnel` stays the
readable reference; :func:`microfacet` computes the same f_r in 1/sr in one pass per pair, without
temporaries, on all cores. It repeats the reference's arithmetic operation for operation (same clamps,
same association, same dtype), so float64 results agree to the last bit except where libm and scipy
round exp and erfc differently (Beckmann). That is deliberate: near the peak at alpha = 1e-4, D depends
on 1 - cos_h^2 and one ulp of cos_h moves D by ~1e-8 relative, so "close" arithmetic is not enough.

For the same reason ``fastmath`` is off: on the RGB GGX conductor "contract" (FMA) changed 22 % of the values
(by <= 1e-14) and every flag together 58 %, each for a few per cent of speed ("nsz" changed no value and gained
as little). Merging the conductor's two divisions into one gained as little: not worth a second formula either.

Each configuration (distribution, masking, Fresnel kind, channel count) is its own compiled loop: the
choices are closure constants, so their branches fold away and LLVM vectorises the straight-line body.
The first call of a configuration and dtype compiles it (seconds of CPU); ``cache=True`` keeps it on disk.

What is ISA-specific: numba compiles for the host CPU (the disk cache is keyed by it), so the vector
width and LLVM's inlining and vectorising decisions are the target's. Every GGX configuration vectorises on
AVX2 (4-wide float64, 8-wide float32 vsqrt/vdiv; read from ``inspect_asm`` with numba targeting znver3) and on
AVX-512 (zmm registers, 8-wide float64, 16-wide float32; LLVM 22's znver5 target), provided the per-channel values
reach the loop as tuples (see :func:`_params`): as arrays, the dielectric and Schlick loops stayed scalar on AVX2,
and on AVX-512 every loop reloaded them through masked gathers and stored through scatters, several times slower
(docs/benchmarks.md, model throughput). Beckmann stays scalar on any target (libm exp and erfc; numba would
vectorise them only through Intel's SVML). sqrt and division are correctly rounded in every width, so the values
do not depend on the ISA.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import numpy.typing as npt
from numba import prange

from model.base import DIVISOR_FLOOR
from model.geometry import float_dtype
from model.microfacet import clamp_alpha

Array = npt.NDArray[np.floating]
Consts = tuple[float, ...]

#: The configurations the kernel covers; anything else (blinn_phong, v_groove) uses the numpy path.
DISTRIBUTIONS: tuple[str, ...] = ("ggx", "beckmann")
MASKINGS: tuple[str, ...] = ("smith", "smith_correlated", "smith_schlick", "none")
FRESNELS: tuple[str, ...] = ("conductor", "dielectric", "schlick")

_JIT: dict[str, Any] = {"fastmath": False, "error_model": "numpy", "boundscheck": False, "cache": True}
_U1, _U2, _U3 = np.uint64(1), np.uint64(2), np.uint64(3)

# kc, the dtype's constants: zero, one, half, two, four, pi, sqrt(pi), tiny (the floor of microfacet's
# and fresnel's divisors), base.DIVISOR_FLOOR (Pair's and CookTorrance's), and the bounds of the
# Beckmann Lambda argument. mp, the model's: alpha^2, alpha (both clamped), Smith-Schlick k, 1 - k, scale.


@numba.njit(inline="always", **_JIT)
def _lambda(c: float, kc: Consts, mp: Consts, dist: int) -> float:
    # Smith Lambda of one direction: microfacet.ggx_lambda or microfacet.beckmann_lambda.
    zero, one, half, two, _, _, sqrt_pi, tiny, _, a_lo, a_hi = kc
    a2, alpha = mp[0], mp[1]
    if dist == 0:
        cc = c * c
        c2 = tiny if cc < tiny else cc
        s2 = one - c2
        return half * (math.sqrt(one + a2 * ((zero if s2 < zero else s2) / c2)) - one)
    s2 = one - c * c
    den = alpha * math.sqrt(zero if s2 < zero else s2)
    a = c / (tiny if den < tiny else den)
    a = a_lo if a < a_lo else (a_hi if a > a_hi else a)
    lam = -half * math.erfc(a) + math.exp(-a * a) / (two * a * sqrt_pi)
    return zero if lam < zero else lam


@numba.njit(**_JIT)
def _specular(ci: float, co: float, ch: float, kc: Consts, mp: Consts, dist: int, mask: int) -> float:
    # scale D G / (4 cos_i cos_o): CookTorrance.specular with microfacet.distribution_d and .masking.
    zero, one, _, _, four, pi, _, tiny, floor, _, _ = kc
    a2, _, ks, one_m_ks, scale = mp
    c2 = ch * ch
    s2 = one - c2
    s2 = zero if s2 < zero else s2
    if dist == 0:
        den = s2 + a2 * c2
        dd = den * den
        d = a2 / (pi * (tiny if dd < tiny else dd))
    else:
        c4 = c2 * c2
        ca = c2 * a2
        e = math.exp(-s2 / (tiny if ca < tiny else ca))
        # As model.microfacet.beckmann_d: where the exponential has underflowed the denominator may have too.
        d = e / (pi * a2 * (tiny if c4 < tiny else c4)) if e > zero else zero
    d = d if ch > zero else zero
    if mask == 0:
        g = one / (one + _lambda(ci, kc, mp, dist)) * (one / (one + _lambda(co, kc, mp, dist)))
    elif mask == 1:
        g = one / (one + (_lambda(ci, kc, mp, dist) + _lambda(co, kc, mp, dist)))
    elif mask == 2:
        gi = ci * one_m_ks + ks
        go = co * one_m_ks + ks
        g = ci / (tiny if gi < tiny else gi) * (co / (tiny if go < tiny else go))
    else:
        g = one
    den4 = four * ci * co
    return scale * d * g / (floor if den4 < floor else den4)


@numba.njit(inline="always", **_JIT)
def _fresnel(cd: float, cd2: float, s2: float, p: float, q: float, kc: Consts, fres: int) -> float:
    # One channel of fresnel.conductor (p = eta^2 - k^2, q = 4 eta^2 k^2), fresnel.dielectric
    # (p = eta, q = eta^2) or fresnel.schlick (p = f0, q = 1 - f0); cd is already in [0, 1].
    zero, one, half, two, _, _, _, tiny, _, _, _ = kc
    if fres == 0:
        t0 = p - s2
        a2pb2 = math.sqrt(t0 * t0 + q)
        x = half * (a2pb2 + t0)
        t1 = a2pb2 + cd2
        t2 = two * cd * math.sqrt(zero if x < zero else x)
        u = t1 + t2
        rs = (t1 - t2) / (tiny if u < tiny else u)
        t3 = cd2 * a2pb2 + s2 * s2
        t4 = t2 * s2
        v = t3 + t4
        f = half * (rs + rs * (t3 - t4) / (tiny if v < tiny else v))
        return zero if f < zero else (one if f > one else f)
    if fres == 1:
        sin2_t = s2 / q
        x = one - sin2_t
        cos_t = math.sqrt(zero if x < zero else x)
        u = cd + p * cos_t
        rs = (cd - p * cos_t) / (tiny if u < tiny else u)
        v = p * cd + cos_t
        rp = (p * cd - cos_t) / (tiny if v < tiny else v)
        f = half * (rs * rs + rp * rp)
        return one if sin2_t > one else (one if f > one else f)
    m = one - cd
    m2 = m * m
    return p + q * (m2 * m2 * m)


# Inlined into the parfor body as numba IR (so are _lambda and _fresnel), with unsigned indices and no
# load inside a conditional expression: a call that LLVM does not inline, the wraparound test of a
# signed index, or a conditional load (numba lowers `a[i] if c else 0` to a branch), each kept the whole
# loop scalar. Whether LLVM inlines a call is its target's cost model: on AVX2 (znver3), with the helpers
# left to LLVM, every sqrt and division stayed scalar (vsqrtsd, vdivsd). Inlining _lambda and _fresnel in
# numba was enough for the loop to vectorise; inlining _specular too vectorised the same but about tripled the
# compile time of a configuration.
@numba.njit(inline="always", **_JIT)
def _pair(
    j: int, o: int, wi: Array, wo: Array, out: Array, p: Consts, q: Consts, rho: Consts, kc: Consts, mp: Consts,
    dist: int, mask: int, fres: int, nc: int,
) -> None:
    # f_r of the pair at wi[j:j+3], wo[j:j+3] into out[o:o+nc]: Model.eval with CookTorrance._eval.
    zero, one, half, _, _, _, _, _, floor, _, _ = kc
    ix, iy, ci = wi[j], wi[j + _U1], wi[j + _U2]
    ox, oy, co = wo[j], wo[j + _U1], wo[j + _U2]
    sx, sy, sz = ix + ox, iy + oy, ci + co
    norm = math.sqrt(sx * sx + sy * sy + sz * sz)
    ch = sz / (floor if norm < floor else norm)
    ch = one if ch > one else ch  # as Pair.cos_h: h is not unit where norm underflowed
    cd = half * norm  # wi . h = |wi + wo| / 2, as Pair.cos_d
    cd = zero if cd < zero else (one if cd > one else cd)
    spec = _specular(ci, co, ch, kc, mp, dist, mask)
    valid = ci > zero and co > zero
    cd2 = cd * cd
    s2 = one - cd2
    for c in range(nc):
        f = _fresnel(cd, cd2, s2, p[c], q[c], kc, fres)
        v = rho[c] + spec * f  # outside the conditional: a load inside it made it a branch
        out[o + np.uint64(c)] = v if valid else zero


@functools.cache
def _compiled(dist: int, mask: int, fres: int, nc: int) -> Callable[..., None]:
    """The parallel loop for one configuration (indices into the tuples above, nc channels)."""
    # Closure variables are compile-time constants to numba (so the configuration's branches fold
    # and the channel loop unrolls) and part of the disk cache's key; keep them plain numbers.
    uc = np.uint64(nc)

    @numba.njit(parallel=True, **_JIT)
    def kernel(wi: Array, wo: Array, out: Array, p: Consts, q: Consts, rho: Consts, kc: Consts, mp: Consts) -> None:
        for i in prange(wi.size // 3):
            u = np.uint64(i)
            _pair(u * _U3, u * uc, wi, wo, out, p, q, rho, kc, mp, dist, mask, fres, nc)

    return kernel


def _config(distribution: str, masking: str, fresnel: str) -> tuple[int, int, int] | None:
    """Indices of the choices in the tuples above, or None when the kernel does not cover them."""
    if distribution not in DISTRIBUTIONS or masking not in MASKINGS or fresnel not in FRESNELS:
        return None
    return DISTRIBUTIONS.index(distribution), MASKINGS.index(masking), FRESNELS.index(fresnel)


def _directions(wi: npt.ArrayLike, wo: npt.ArrayLike) -> tuple[Array, Array, tuple[int, ...]] | None:
    """Both direction arrays as flat contiguous (3 N,) arrays of one dtype, and the batch shape."""
    dtype = float_dtype(wi, wo)
    a, b = np.asarray(wi, dtype=dtype), np.asarray(wo, dtype=dtype)
    if a.shape[-1:] != (3,) or b.shape[-1:] != (3,):
        return None  # the numpy path raises the documented error
    if a.shape != b.shape:
        try:
            shape = np.broadcast_shapes(a.shape, b.shape)
        except ValueError:
            return None
        # One fixed direction against many is common (a fixed light); other broadcasts stay numpy's.
        if min(a.size, b.size) != 3:
            return None
        a, b = np.broadcast_to(a, shape), np.broadcast_to(b, shape)
    return np.ascontiguousarray(a).reshape(-1), np.ascontiguousarray(b).reshape(-1), a.shape[:-1]


@dataclass(frozen=True)
class MicrofacetParams:
    """The numbers the kernel reads: the Fresnel term's indices, rho_d, alpha and the form's scale.

    ``eta`` and ``k`` (conductor), ``eta`` (dielectric) or ``f0`` (schlick) as a scalar or one value per
    channel; ``rho_d`` the Lambertian albedo (scalar or per channel); ``alpha`` the roughness before
    :func:`model.microfacet.clamp_alpha`; ``scale`` 1 for Walter's form, 4 for the 1982 form; ``channels``
    None for a scalar result, else the channel count of the (..., C) result.
    """

    fresnel: str
    eta: object = 1.5
    k: object = 0.0
    f0: object = 0.04
    rho_d: object = 0.0
    alpha: float = 0.1
    scale: float = 1.0
    channels: int | None = None


def _params(m: MicrofacetParams, dtype: np.dtype, nc: int) -> tuple[Consts, Consts, Consts, Consts, Consts]:
    """Per-channel values (p, q, rho_d / pi) and the constant tuples, computed as the numpy path does.

    All are tuples of the working dtype's scalars, which the kernel receives as values: given as arrays, LLVM
    cannot tell that the loop's stores to ``out`` leave them unchanged, so it loads them again in every
    iteration; on AVX-512 it did that with masked gathers, and wrote ``out`` with scatters, which made the loop
    several times slower for the same values.
    """
    t = dtype.type

    def per_channel(value: object) -> Array:
        return np.ascontiguousarray(np.broadcast_to(np.atleast_1d(np.asarray(value, dtype=dtype)), (nc,)))

    p: Array
    q: Array
    if m.fresnel == "conductor":
        e, k = per_channel(m.eta), per_channel(m.k)
        e2, k2 = e * e, k * k
        p, q = e2 - k2, 4.0 * e2 * k2
    elif m.fresnel == "dielectric":
        p = per_channel(m.eta)
        q = p * p
    else:
        p = per_channel(m.f0)
        q = 1.0 - p
    rho = per_channel(m.rho_d) / np.pi
    alpha = clamp_alpha(m.alpha)
    al, ks = t(alpha), t(0.5 * alpha)
    a2 = al**2  # as microfacet.ggx_d: the clamped alpha in the working dtype, squared there
    a_lo = 1e-150 if dtype == np.float64 else 1e-30
    kc = tuple(t(x) for x in (0.0, 1.0, 0.5, 2.0, 4.0, math.pi, math.sqrt(math.pi), np.finfo(dtype).tiny,
                              DIVISOR_FLOOR, a_lo, 40.0))
    mp = (a2, al, ks, t(1.0) - ks, t(m.scale))
    return tuple(p), tuple(q), tuple(rho), kc, mp


def microfacet(
    wi: npt.ArrayLike, wo: npt.ArrayLike, distribution: str, masking: str, params: MicrofacetParams
) -> Array | None:
    """f_r in 1/sr at unit directions wi, wo (..., 3), or None where the kernel does not apply.

    Same shapes, dtype and values as ``CookTorrance``'s numpy path (``Model.eval``); None for
    configurations outside :data:`DISTRIBUTIONS` x :data:`MASKINGS` x :data:`FRESNELS` and for broadcasts
    other than equal shapes or one single direction against many.
    """
    cfg = _config(distribution, masking, params.fresnel)
    dirs = None if cfg is None else _directions(wi, wo)
    if cfg is None or dirs is None:
        return None
    a, b, batch = dirs
    channels = params.channels
    nc = 1 if channels is None else channels
    p, q, rho, kc, mp = _params(params, a.dtype, nc)
    out = np.empty(a.size // 3 * nc, dtype=a.dtype)
    _compiled(*cfg, nc)(a, b, out, p, q, rho, kc, mp)
    return out.reshape(batch) if channels is None else out.reshape(*batch, nc)


def warm_up(
    distribution: str = "ggx", masking: str = "smith", fresnel: str = "conductor", channels: int | None = None
) -> None:
    """Compile (or load from the disk cache) the float64 kernel of one configuration (default: GGX conductor)."""
    z = np.array([[0.0, 0.0, 1.0]])
    microfacet(z, z, distribution, masking, MicrofacetParams(fresnel, channels=channels))
