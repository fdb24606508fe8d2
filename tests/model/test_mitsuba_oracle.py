"""Mitsuba 3 as an independent oracle for the microfacet, Lambert and Fresnel code in model/.

Every test runs under each rgb variant that loads (llvm_ad_rgb, scalar_rgb); see
tests/mitsuba_helpers.py for the gating (GONIO_REQUIRE_LLVM=1 turns a missing llvm into a failure).

Mitsuba computes in float32, we compute in float64. Directions and parameters are rounded to float32
first and both sides see exactly those values, so what remains is Mitsuba's own float32 rounding.
Where float32 provably cannot deliver 1e-5 relative, the tolerance grows by a term computed per
sample from the cause, each measured and explained next to where it is used:

* Fresnel cosine ambiguity. float32-rounded directions are not unit length (|v| - 1 up to 6e-8).
  For unit vectors wi.h = wo.h = |wi + wo|/2, but here the three differ by about
  (|wi|^2 - |wo|^2) / |wi + wo|, which is large when wi and wo are nearly opposite (microfacet
  grazing, cos_d -> 0). Mitsuba uses wi.h, model.base uses |wi + wo|/2: neither is wrong, the
  input does not decide. Measured (GGX, 32k samples): up to 1.9e-4 relative in f at cos_d ~ 1e-3;
  at most 1.7e-6 wherever the spread of F over the three definitions is below 1e-7.
* Fresnel float32 floor. Mitsuba's conductor formula (the same as model.fresnel.conductor) has
  cancellations: an absolute error of ~eps32 when F is small (eta ~ 1, k ~ 0; measured 8.3e-8), and
  ~sqrt(eps32) = 2.4e-4 (measured 5.9e-4) for an index with eta < 1 and k -> 0, i.e. a lossless
  interface beyond its critical angle, where a^2 = (|t0| + t0)/2 cancels completely. That absolute
  error in F multiplies the rest of the BRDF.
* Beckmann's exp(-x), x = tan^2(theta_h)/alpha^2: float32 rounding of x gives a relative error of
  about x eps32 (measured at most 7.1 x 2^-24 x). Mitsuba also sets D to 0 where D cos(theta_h) <=
  1e-20 ("to prevent numerical issues", MicrofacetDistribution::eval), reached near x = 50.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from model import fresnel, microfacet
from model.cook_torrance import CookTorrance
from model.lambert import Lambert
from tests.mitsuba_helpers import (
    ORACLE_VARIANTS,
    bsdf_eval_cos,
    f32,
    fresnel_conductor,
    fresnel_dielectric,
    held_variant,
    microfacet_d,
    microfacet_g1,
    rgb,
)

pytestmark = pytest.mark.mitsuba

EPS32 = 2.0**-24  # float32 unit roundoff
REL = 1e-5  # the goal: relative agreement with Mitsuba
#: Absolute float32 error of Mitsuba's conductor F outside the lossless region (measured 8.3e-8).
F_FLOOR = 2e-7
#: Absolute error of Mitsuba's conductor F inside it (measured 5.9e-4, about 2.4 sqrt(eps32)).
F_FLOOR_LOSSLESS = 2e-3
#: Mitsuba's documented bound on its Beckmann G1 fit ("< 0.35 % relative error").
BECKMANN_G1_FIT = 3.5e-3
#: Mitsuba's MicrofacetDistribution::eval returns 0 where D cos(theta_h) <= this (1/sr).
D_CUTOFF = 1e-20


def d_cut(kind: str, cos_h: np.ndarray, alpha: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Masks (kept, zeroed) of Mitsuba's D cutoff, leaving out a +-0.1 % band where rounding decides."""
    dc = microfacet.distribution_d(kind, cos_h, alpha) * cos_h
    return dc > D_CUTOFF * (1.0 + 1e-3), dc < D_CUTOFF * (1.0 - 1e-3)


@pytest.fixture(params=ORACLE_VARIANTS)
def variant(request: pytest.FixtureRequest) -> Iterator[str]:
    yield from held_variant(request.param)


def n_sets(variant: str) -> tuple[int, int]:
    """(parameter sets, direction pairs per set): llvm evaluates thousands at once, scalar loops."""
    return (48, 256) if variant.startswith("llvm") else (12, 64)


# ---------------------------------------------------------------------------------------------
# Sampling


def hemisphere(rng: np.random.Generator, n: int) -> np.ndarray:
    """Upper-hemisphere directions: half with cos uniform, half log-uniform down to 1e-4 (grazing)."""
    cos = np.where(rng.uniform(size=n) < 0.5, rng.uniform(0.0, 1.0, n), np.exp(rng.uniform(np.log(1e-4), 0, n)))
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    sin = np.sqrt(1.0 - cos * cos)
    return np.stack([sin * np.cos(phi), sin * np.sin(phi), cos], axis=-1)


def direction_pairs(rng: np.random.Generator, n: int, kind: str, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """float32-rounded pairs: half independent, half wo mirrored about a lobe-sampled h (the peak)."""
    wi = hemisphere(rng, n)
    h, _ = microfacet.sample_half_vector(kind, alpha, rng.uniform(size=n // 2), rng.uniform(size=n // 2))
    mirrored = 2.0 * np.sum(wi[n // 2 :] * h, axis=-1, keepdims=True) * h - wi[n // 2 :]
    wo = np.concatenate([hemisphere(rng, n - n // 2), mirrored])
    keep = wo[:, 2] > 1e-4
    return f32(wi[keep]), f32(wo[keep])


def conductor_params(rng: np.random.Generator) -> tuple[float, np.ndarray, np.ndarray]:
    """alpha log-uniform in [0.01, 1], eta in [0.2, 3] and k in [0, 8] per RGB channel (float32)."""
    alpha = float(f32(np.exp(rng.uniform(np.log(0.01), 0.0))))
    return alpha, f32(rng.uniform(0.2, 3.0, 3)), f32(rng.uniform(0.0, 8.0, 3))


# ---------------------------------------------------------------------------------------------
# Tolerance terms (see the module docstring)


def lossless(eta: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Indices where Mitsuba's float32 conductor F cancels to sqrt(eps32) (errors measured only for
    eta < 1.004, k < 0.0124; the region is drawn wider for margin)."""
    return (eta < 1.01) & (k < 0.03)


def fresnel_floor(eta: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Absolute float32 error of Mitsuba's conductor F for each index (see the constants)."""
    return np.where(lossless(eta, k), F_FLOOR_LOSSLESS, F_FLOOR)


def cos_d_spread(wi: np.ndarray, wo: np.ndarray, eta: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Relative spread of F over wi.h, wo.h and |wi + wo|/2, (N, 3): what the input leaves open."""
    s = wi + wo
    norm = np.linalg.norm(s, axis=-1, keepdims=True)
    h = s / norm
    cands = [np.sum(wi * h, -1, keepdims=True), np.sum(wo * h, -1, keepdims=True), 0.5 * norm]
    f = np.stack([fresnel.conductor(np.clip(c, 0.0, 1.0), eta, k) for c in cands])
    return (f.max(axis=0) - f.min(axis=0)) / np.maximum(f.min(axis=0), 1e-300)


def conductor_tolerance(
    ours: np.ndarray, wi: np.ndarray, wo: np.ndarray, eta: np.ndarray, k: np.ndarray, rel: float = REL
) -> np.ndarray:
    """Per-sample absolute tolerance for f cos_o of a conductor: rel, cos_d ambiguity, F floor."""
    s = wi + wo
    cos_d = np.clip(0.5 * np.linalg.norm(s, axis=-1, keepdims=True), 0.0, 1.0)
    f = fresnel.conductor(cos_d, eta, k)
    rest = ours / np.maximum(f, 1e-300)  # the BRDF without its Fresnel factor
    # The two sides pick one of the cosines each, so they differ by at most the spread: 2x is margin.
    return ours * (rel + 2.0 * cos_d_spread(wi, wo, eta, k)) + rest * fresnel_floor(eta, k)


# ---------------------------------------------------------------------------------------------
# BRDFs


def compare_roughconductor(
    variant: str, distribution: str, seed: int
) -> tuple[list[np.ndarray], list[np.ndarray], list[tuple[np.ndarray, ...]]]:
    """(ours f cos_o, Mitsuba eval, (wi, wo, alpha, eta, k) per set) over random sets and pairs."""
    rng = np.random.default_rng(seed)
    sets, per_set = n_sets(variant)
    ours_all, theirs_all, inputs = [], [], []
    for _ in range(sets):
        alpha, eta, k = conductor_params(rng)
        wi, wo = direction_pairs(rng, per_set, distribution, alpha)
        spec = {"type": "roughconductor", "distribution": distribution, "alpha": alpha, "eta": rgb(eta), "k": rgb(k)}
        theirs = bsdf_eval_cos(variant, spec, wi, wo)
        model = CookTorrance(
            alpha=alpha, distribution=distribution, masking="smith", fresnel="conductor", eta=tuple(eta), k=tuple(k)
        )
        ours = model.eval(wi, wo) * wo[:, 2:3]
        ours_all.append(ours)
        theirs_all.append(theirs)
        inputs.append((wi, wo, np.float64(alpha), eta, k))
    return ours_all, theirs_all, inputs


def test_ggx_roughconductor_matches_mitsuba(variant: str) -> None:
    ours_l, theirs_l, inputs = compare_roughconductor(variant, "ggx", seed=11)
    n = sum(o.shape[0] for o in ours_l)
    assert n >= (2000 if variant.startswith("llvm") else 300)
    plain_misses = 0
    for ours, theirs, (wi, wo, alpha, eta, k) in zip(ours_l, theirs_l, inputs, strict=True):
        assert np.all(np.isfinite(theirs)) and np.all(ours > 0)
        tol = conductor_tolerance(ours, wi, wo, eta, k)
        err = np.abs(ours - theirs)
        worst = np.unravel_index(np.argmax(err / tol), err.shape)
        assert np.all(err <= tol), (
            f"alpha={alpha}, eta={eta}, k={k}, wi={wi[worst[0]]}, wo={wo[worst[0]]}: "
            f"ours {ours[worst]} mitsuba {theirs[worst]} (tolerance {tol[worst]})"
        )
        plain_misses += int(np.sum(err > REL * ours))
    # The per-sample terms must stay exceptions, or the check would be weaker than it reads:
    # measured 0.36 % of the samples miss 1e-5 relative plainly (llvm; grazing half angles).
    assert plain_misses <= 0.01 * 3 * n


def test_beckmann_roughconductor_matches_mitsuba_up_to_its_g1_fit(variant: str) -> None:
    ours_l, theirs_l, inputs = compare_roughconductor(variant, "beckmann", seed=12)
    worst_plain = 0.0
    for ours, theirs, (wi, wo, alpha, eta, k) in zip(ours_l, theirs_l, inputs, strict=True):
        # Substituting Mitsuba's own G1 (its rational fit) for our exact one must leave only
        # float32 rounding: this checks D, the 1/(4 cos) factors and F to 1e-5 as for GGX.
        h = (wi + wo) / np.linalg.norm(wi + wo, axis=-1, keepdims=True)
        al = np.full(len(wi), alpha)
        g_theirs = microfacet_g1(variant, "beckmann", al, wi, h) * microfacet_g1(variant, "beckmann", al, wo, h)
        g_ours = microfacet.smith_g1(wi[:, 2], alpha, "beckmann") * microfacet.smith_g1(wo[:, 2], alpha, "beckmann")
        swapped = ours * (g_theirs / g_ours)[:, None]
        # exp(-x) in float32: relative error ~ x eps32 (measured <= 7.1 x 2^-24 x), so 10 x 2^-24 x.
        cos_h = h[:, 2:3]
        x = (1.0 - cos_h**2) / (cos_h**2 * alpha**2)
        tol = conductor_tolerance(swapped, wi, wo, eta, k) + swapped * 10.0 * EPS32 * x
        kept, zeroed = (np.repeat(m, 3, axis=1) for m in d_cut("beckmann", cos_h, alpha))
        err = np.abs(swapped - theirs)
        assert np.all(err[kept] <= tol[kept])
        assert np.all(theirs[zeroed] == 0.0)
        # Plain comparison: the two G1 differ by at most 0.35 % each, so G by at most
        # (1.0035)^2 - 1 = 0.70 %; measured 0.62 % (both directions near the fit's worst point),
        # which is why a flat 0.5 % would fail.
        rel = np.abs(ours - theirs)[kept] / ours[kept]
        worst_plain = max(worst_plain, float(rel.max()))
    assert worst_plain <= (1.0 + BECKMANN_G1_FIT) ** 2 - 1.0
    # ... and the difference is really Mitsuba's fit: without it, the check above would be 1e-5.
    assert worst_plain > 1e-3


@pytest.mark.parametrize("below", ["wi", "wo", "both"])
def test_below_horizon_is_zero_in_both(variant: str, below: str) -> None:
    rng = np.random.default_rng(3)
    wi, wo = f32(hemisphere(rng, 64)), f32(hemisphere(rng, 64))
    if below in ("wi", "both"):
        wi[:, 2] *= -1.0
    if below in ("wo", "both"):
        wo[:, 2] *= -1.0
    spec = {"type": "roughconductor", "alpha": 0.3, "eta": rgb([0.2, 1.0, 1.5]), "k": rgb([3.0, 1.0, 2.0])}
    theirs = bsdf_eval_cos(variant, spec, wi, wo)
    ours = CookTorrance(alpha=0.3, eta=(0.2, 1.0, 1.5), k=(3.0, 1.0, 2.0)).eval(wi, wo)
    assert np.all(theirs == 0.0) and np.all(ours == 0.0)
    assert np.all(bsdf_eval_cos(variant, {"type": "diffuse"}, wi, wo) == 0.0)


def test_lambert_matches_mitsuba_diffuse(variant: str) -> None:
    rng = np.random.default_rng(4)
    rho = f32(rng.uniform(0.0, 1.0, 3))
    wi, wo = f32(hemisphere(rng, 500)), f32(hemisphere(rng, 500))
    theirs = bsdf_eval_cos(variant, {"type": "diffuse", "reflectance": rgb(rho)}, wi, wo)
    ours = Lambert(rho_d=tuple(rho)).eval(wi, wo) * wo[:, 2:3]
    # A product of three float32 roundings: measured 1.2e-7 relative.
    np.testing.assert_allclose(theirs, ours, rtol=1e-6, atol=0.0)


# ---------------------------------------------------------------------------------------------
# Microfacet terms alone


def lobe_normals(rng: np.random.Generator, kind: str, alpha: np.ndarray) -> np.ndarray:
    """float32-rounded microfacet normals, half from the lobe of each alpha, half from the hemisphere."""
    n = len(alpha)
    m = np.empty((n, 3))
    for i, a in enumerate(alpha[: n // 2]):
        m[i] = microfacet.sample_half_vector(kind, float(a), rng.uniform(size=1), rng.uniform(size=1))[0][0]
    m[n // 2 :] = hemisphere(rng, n - n // 2)
    return f32(m)


@pytest.mark.parametrize("kind", ["ggx", "beckmann"])
def test_distribution_d_matches_mitsuba(variant: str, kind: str) -> None:
    rng = np.random.default_rng(5)
    n = 20000 if variant.startswith("llvm") else 2000
    alpha = f32(np.exp(rng.uniform(np.log(0.01), 0.0, n)))
    m = lobe_normals(rng, kind, alpha)
    theirs = microfacet_d(variant, kind, alpha, m)
    # A float32 normal is not unit length; Mitsuba's D reads m.x/alpha, m.y/alpha and m.z, which
    # is insensitive to |m| (exactly so for Beckmann's exponent), while ours reads cos alone. So
    # ours gets the direction of m: cos_h = m.z/|m| in float64. (Feeding m.z raw costs up to 1e-3
    # at alpha ~ 0.01 near the peak, where 1 - cos^2 is only 1e-4.)
    cos_h = m[:, 2] / np.linalg.norm(m, axis=-1)
    ours = microfacet.distribution_d(kind, cos_h, alpha)
    x = (1.0 - cos_h**2) / (cos_h**2 * alpha**2)
    if kind == "ggx":
        # Measured 5.9e-7.
        np.testing.assert_allclose(theirs, ours, rtol=REL, atol=0.0)
        return
    kept, zeroed = d_cut(kind, cos_h, alpha)
    rel = np.abs(theirs - ours)[kept] / ours[kept]
    assert np.all(rel <= REL + 10.0 * EPS32 * x[kept])
    # Where x is small enough for 1e-5 (x < 20), it holds outright (measured 2.9e-6).
    small = kept & (x < 20.0)
    np.testing.assert_allclose(theirs[small], ours[small], rtol=REL, atol=0.0)
    assert np.all(theirs[zeroed] == 0.0) and np.any(zeroed)


def test_ggx_g1_matches_mitsuba(variant: str) -> None:
    rng = np.random.default_rng(6)
    n = 20000 if variant.startswith("llvm") else 2000
    alpha = f32(np.exp(rng.uniform(np.log(0.01), 0.0, n)))
    v = f32(hemisphere(rng, n))
    normal = np.tile([0.0, 0.0, 1.0], (n, 1))
    theirs = microfacet_g1(variant, "ggx", alpha, v, normal)
    ours = microfacet.smith_g1(v[:, 2] / np.linalg.norm(v, axis=-1), alpha, "ggx")
    # Both exact; measured 1.7e-7 relative down to cos = 1e-4.
    np.testing.assert_allclose(theirs, ours, rtol=REL, atol=0.0)


def test_beckmann_g1_differs_from_mitsuba_only_by_its_fit(variant: str) -> None:
    rng = np.random.default_rng(7)
    n = 20000 if variant.startswith("llvm") else 2000
    alpha = f32(np.exp(rng.uniform(np.log(0.01), 0.0, n)))
    v = f32(hemisphere(rng, n))
    theirs = microfacet_g1(variant, "beckmann", alpha, v, np.tile([0.0, 0.0, 1.0], (n, 1)))
    ours = microfacet.smith_g1(v[:, 2] / np.linalg.norm(v, axis=-1), alpha, "beckmann")
    rel = np.abs(theirs - ours) / ours
    # Mitsuba documents < 0.35 % for its rational fit; measured 0.313 %. More means a bug on one
    # side; much less would mean Mitsuba changed its G1 and this test's premise is stale.
    assert rel.max() <= BECKMANN_G1_FIT
    assert rel.max() > 2e-3


# ---------------------------------------------------------------------------------------------
# Fresnel


def test_dielectric_fresnel_matches_mitsuba(variant: str) -> None:
    rng = np.random.default_rng(8)
    n = 50000 if variant.startswith("llvm") else 5000
    cos = f32(rng.uniform(0.0, 1.0, n))
    eta = f32(rng.uniform(0.2, 3.0, n))  # eta < 1 includes total internal reflection
    theirs = fresnel_dielectric(variant, cos, eta)
    ours = fresnel.dielectric(cos, eta)
    # Two places are ill-conditioned for float32: near the critical angle of eta < 1, F has an
    # infinite slope (cos_t^2 = 1 - (1 - c^2)/eta^2 is off by a few eps32; measured up to 4.6e-5
    # absolute in F, about 13 eps32 / sqrt(|cos_t^2|)), and near eta = 1, F ~ (eta - 1)^2 is tiny
    # and cancels. Mitsuba's float32 result is the exact F of an index a few ulps away (backward
    # stability), so the tolerance adds the change of our F when eta moves by 4 float32 ulps.
    ulps = 4.0 * EPS32
    spread = np.abs(fresnel.dielectric(cos, eta * (1 + ulps)) - fresnel.dielectric(cos, eta * (1 - ulps)))
    err = np.abs(theirs - ours)
    assert np.all(err <= REL * ours + spread)
    # The extra term is needed by few samples: measured 0.26 % miss 1e-5 relative plainly.
    assert np.mean(err > REL * ours) < 0.01
    # Total internal reflection is exactly 1 in both.
    tir = (1.0 - cos**2) / eta**2 > 1.0 + 1e-6
    assert np.all(theirs[tir] == 1.0) and np.all(ours[tir] == 1.0)


def test_conductor_fresnel_matches_mitsuba(variant: str) -> None:
    rng = np.random.default_rng(9)
    n = 50000 if variant.startswith("llvm") else 5000
    cos = f32(rng.uniform(0.0, 1.0, n))
    eta = f32(rng.uniform(0.2, 3.0, n))
    # Half the k log-uniform down to 1e-6 so the lossless corner is actually visited.
    k = f32(
        np.where(rng.uniform(size=n) < 0.5, rng.uniform(0.0, 8.0, n), np.exp(rng.uniform(np.log(1e-6), np.log(8.0), n)))
    )
    theirs = fresnel_conductor(variant, cos, eta, k)
    ours = fresnel.conductor(cos, eta, k)
    err = np.abs(theirs - ours)
    assert np.all(err <= REL * ours + fresnel_floor(eta, k))
    # Outside the lossless corner the floor is the exception: measured 0.32 % miss 1e-5 plainly.
    assert np.mean((err > REL * ours)[~lossless(eta, k)]) < 0.02
    # Outside the lossless corner and above F = 0.02 that is 1e-5 relative outright.
    well = ~lossless(eta, k) & (ours > 0.02)
    np.testing.assert_allclose(theirs[well], ours[well], rtol=REL, atol=0.0)
