"""The microfacet terms a Pair keeps (sin^2 / cos^2 of h, GGX's tan^2, Schlick's weight, 4 cos_i cos_o) give the
very bits the terms computed from the directions at each evaluation gave: a fit reads them hundreds of times."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from model import CookTorrance, MetalRoughness, fresnel, microfacet
from model.base import Pair
from model.metal_roughness import F0_DIELECTRIC


def _pairs(dtype: type = np.float64) -> Pair:
    rng = np.random.default_rng(7)
    v = rng.normal(size=(2, 3000, 3))
    v[..., 2] = np.abs(v[..., 2])
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    return Pair(v[0].astype(dtype), v[1].astype(dtype))


def _reference(m: CookTorrance, p: Pair) -> np.ndarray:
    """CookTorrance._eval as it was written before the Pair kept any term."""
    d = microfacet.distribution_d(m.distribution, p.cos_h, m.alpha)
    g = microfacet.masking(m.masking, p.cos_i, p.cos_o, p.cos_h, p.cos_d, m.alpha, m.distribution)
    den = np.maximum(4.0 * p.cos_i * p.cos_o, p.tiny)
    spec = (4.0 if m.form == "cook_torrance_1982" else 1.0) * d * g / den
    if m.fresnel == "conductor":
        f = fresnel.conductor(p.cos_d, p.param(m.eta), p.param(m.k))
    elif m.fresnel == "dielectric":
        f = fresnel.dielectric(p.cos_d, p.param(m.eta))
    else:
        f = fresnel.schlick(p.cos_d, p.param(m.f0))
    return np.asarray(p.param(m.rho_d) / np.pi + spec * f)


@pytest.mark.parametrize(("distribution", "masking", "fresnel_kind"), list(itertools.product(
    ("ggx", "beckmann", "blinn_phong"), ("smith", "smith_correlated", "smith_schlick", "v_groove", "none"),
    ("schlick", "conductor", "dielectric"))))  # fmt: skip
def test_cook_torrance_on_a_pair_is_bit_identical_to_the_terms_computed_afresh(
    distribution: str, masking: str, fresnel_kind: str
) -> None:
    m = CookTorrance(alpha=0.27, distribution=distribution, masking=masking, fresnel=fresnel_kind,
                     eta=(0.2, 1.5, 1.1), k=(3.0, 0.0, 2.0), f0=(0.9, 0.5, 0.04), rho_d=(0.1, 0.0, 0.3))  # fmt: skip
    for dtype in (np.float64, np.float32):
        p = _pairs(dtype)
        want = _reference(m, _pairs(dtype))
        for _ in range(2):  # the second evaluation reads what the first kept
            got = m._eval(p)
            assert got.dtype == want.dtype and np.array_equal(got, want, equal_nan=True)


def test_metal_roughness_on_a_pair_is_bit_identical_to_the_terms_computed_afresh() -> None:
    m = MetalRoughness(base_color=(0.9, 0.6, 0.2), metallic=0.4, roughness=0.5)
    p, q = _pairs(), _pairs()
    a = m.alpha
    d = microfacet.ggx_d(q.cos_h, a)
    g = microfacet.masking("smith_correlated", q.cos_i, q.cos_o, q.cos_h, q.cos_d, a)
    spec = d * g / np.maximum(4.0 * q.cos_i * q.cos_o, q.tiny)
    f_d = fresnel.schlick(q.cos_d, F0_DIELECTRIC)
    base = q.param(m.base_color)
    want = 0.6 * ((1.0 - f_d) * base / np.pi + f_d * spec) + 0.4 * (fresnel.schlick(q.cos_d, base) * spec)
    assert np.array_equal(m._eval(p), want) and np.array_equal(m._eval(p), want)
