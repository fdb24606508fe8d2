"""Helpers for tests that use Mitsuba 3: variant gating and evaluation of its BSDFs on numpy arrays.

Every function takes the variant to run under and restores the previous one. Inputs are rounded to
float32 here (Mitsuba's rgb variants compute in float32), so a caller comparing against float64 code
should round its own inputs with :func:`f32` first and feed the very same values to both sides.
In jit variants (llvm) one vectorised call evaluates all pairs; in scalar variants a Python loop does.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Mapping
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np
import numpy.typing as npt
import pytest

from model.mitsuba.variant import unavailable_reason, use_variant

#: The rgb variants the oracle tests run under, fastest first.
ORACLE_VARIANTS = ("llvm_ad_rgb", "scalar_rgb")
#: CI sets this to 1 (and installs libllvm19): then a missing llvm variant fails instead of skipping.
REQUIRE_LLVM_ENV = "GONIO_REQUIRE_LLVM"


def llvm_required() -> bool:
    return os.environ.get(REQUIRE_LLVM_ENV, "").strip() == "1"


def require_variant(name: str) -> None:
    """Skip the calling test when ``name`` does not load, or fail when it must load.

    scalar variants need nothing beyond the wheel, so they must always load; llvm variants may be
    missing (no libLLVM >= 16) unless GONIO_REQUIRE_LLVM=1 says this machine promises them.
    """
    reason = unavailable_reason(name)
    if reason is None:
        return
    if name.startswith("scalar") or (name.startswith("llvm") and llvm_required()):
        pytest.fail(f"{name} must load here but does not: {reason}")
    pytest.skip(f"{name} unavailable: {reason}")


def held_variant(name: str) -> Iterator[str]:
    """The body of a test module's ``variant`` fixture: ``name`` checked by require_variant and held for the test.

    Held for the whole test, the helpers' own use_variant finds it set and costs nothing; switched back and
    forth per call instead, every call would pay for a change of variant.
    """
    require_variant(name)
    with use_variant(name):
        yield name


def f32(a: npt.ArrayLike) -> np.ndarray:
    """The float32 rounding of ``a`` as float64: the values Mitsuba really sees, exact in float64."""
    return np.asarray(a, dtype=np.float32).astype(np.float64)


def _is_jit() -> bool:
    return bool(dr.is_jit_v(mi.Float))


def _vec(v: np.ndarray) -> Any:
    """(N, 3) numpy -> mi.Vector3f of N lanes (jit)."""
    return mi.Vector3f(np.ascontiguousarray(v.T, dtype=np.float32))


def _float(x: np.ndarray) -> Any:
    return mi.Float(np.ascontiguousarray(x, dtype=np.float32))


def _per_lane(fn: Callable[..., Any], *columns: np.ndarray) -> np.ndarray:
    """Scalar variants: call ``fn`` once per row of the columns, collecting float64 results."""
    out = [np.asarray(fn(*(c[i] for c in columns)), dtype=np.float64) for i in range(len(columns[0]))]
    return np.array(out)


def bsdf_eval_cos(variant: str, spec: Mapping[str, Any], wi: npt.ArrayLike, wo: npt.ArrayLike) -> np.ndarray:
    """Mitsuba's ``bsdf.eval`` (f_r times cos(theta_o)) for local directions (N, 3); returns (N, C)."""
    wi32 = np.asarray(wi, dtype=np.float32).reshape(-1, 3)
    wo32 = np.asarray(wo, dtype=np.float32).reshape(-1, 3)
    with use_variant(variant):
        bsdf = mi.load_dict(dict(spec))
        ctx = mi.BSDFContext()
        if _is_jit():
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wi = _vec(wi32)
            value = bsdf.eval(ctx, si, _vec(wo32))
            return np.array(value, dtype=np.float64).T

        def one(a: np.ndarray, b: np.ndarray) -> Any:
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wi = mi.Vector3f(*(float(x) for x in a))
            return bsdf.eval(ctx, si, mi.Vector3f(*(float(x) for x in b)))

        return _per_lane(one, wi32, wo32).reshape(len(wi32), -1)


def _distribution(kind: str) -> Any:
    return {"ggx": mi.MicrofacetType.GGX, "beckmann": mi.MicrofacetType.Beckmann}[kind]


def microfacet_d(variant: str, kind: str, alpha: npt.ArrayLike, m: npt.ArrayLike) -> np.ndarray:
    """Mitsuba's D(m) of distribution ``kind`` at per-lane roughness alpha (N,), normals m (N, 3)."""
    a32 = np.asarray(alpha, dtype=np.float32).reshape(-1)
    m32 = np.asarray(m, dtype=np.float32).reshape(-1, 3)
    with use_variant(variant):
        t = _distribution(kind)
        if _is_jit():
            return np.array(mi.MicrofacetDistribution(t, _float(a32)).eval(_vec(m32)), dtype=np.float64)
        return _per_lane(
            lambda a, v: mi.MicrofacetDistribution(t, float(a)).eval(mi.Vector3f(*(float(x) for x in v))),
            a32,
            m32,
        )


def microfacet_g1(variant: str, kind: str, alpha: npt.ArrayLike, v: npt.ArrayLike, m: npt.ArrayLike) -> np.ndarray:
    """Mitsuba's Smith G1(v, m) of distribution ``kind`` at per-lane alpha (N,); v, m (N, 3)."""
    a32 = np.asarray(alpha, dtype=np.float32).reshape(-1)
    v32 = np.asarray(v, dtype=np.float32).reshape(-1, 3)
    m32 = np.asarray(m, dtype=np.float32).reshape(-1, 3)
    with use_variant(variant):
        t = _distribution(kind)
        if _is_jit():
            d = mi.MicrofacetDistribution(t, _float(a32))
            return np.array(d.smith_g1(_vec(v32), _vec(m32)), dtype=np.float64)
        return _per_lane(
            lambda a, vv, mm: mi.MicrofacetDistribution(t, float(a)).smith_g1(
                mi.Vector3f(*(float(x) for x in vv)), mi.Vector3f(*(float(x) for x in mm))
            ),
            a32,
            v32,
            m32,
        )


def fresnel_dielectric(variant: str, cos_i: npt.ArrayLike, eta: npt.ArrayLike) -> np.ndarray:
    """Mitsuba's ``mi.fresnel(cos_i, eta)[0]`` (unpolarised dielectric reflectance), per lane."""
    c32 = np.asarray(cos_i, dtype=np.float32).reshape(-1)
    e32 = np.broadcast_to(np.asarray(eta, dtype=np.float32), c32.shape)
    with use_variant(variant):
        if _is_jit():
            return np.array(mi.fresnel(_float(c32), _float(e32))[0], dtype=np.float64)
        return _per_lane(lambda c, e: mi.fresnel(mi.Float(c), mi.Float(e))[0], c32, e32)


def fresnel_conductor(variant: str, cos_i: npt.ArrayLike, eta: npt.ArrayLike, k: npt.ArrayLike) -> np.ndarray:
    """Mitsuba's ``mi.fresnel_conductor(cos_i, eta + i k)`` (unpolarised reflectance), per lane."""
    c32 = np.asarray(cos_i, dtype=np.float32).reshape(-1)
    e32 = np.broadcast_to(np.asarray(eta, dtype=np.float32), c32.shape)
    k32 = np.broadcast_to(np.asarray(k, dtype=np.float32), c32.shape)
    with use_variant(variant):
        if _is_jit():
            eta_c = mi.Complex2f(_float(e32), _float(k32))
            return np.array(mi.fresnel_conductor(_float(c32), eta_c), dtype=np.float64)
        return _per_lane(
            lambda c, e, kk: mi.fresnel_conductor(mi.Float(c), mi.Complex2f(mi.Float(e), mi.Float(kk))),
            c32,
            e32,
            k32,
        )


def rgb(values: npt.ArrayLike) -> dict[str, Any]:
    """A Mitsuba ``rgb`` texture dict for a per-channel parameter (three floats)."""
    return {"type": "rgb", "value": [float(x) for x in np.asarray(values, dtype=np.float64).reshape(3)]}
