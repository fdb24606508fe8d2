"""Every model renders in Mitsuba 3: model.mitsuba.materials (the mapping) and model.mitsuba.plugin (the plugin).

Each model class of the model package gets at least one instance with RGB parameters. Its Mitsuba BSDF
(``to_mitsuba(model)`` through ``mi.load_dict``) is evaluated at fixed direction pairs, grazing ones
included, under scalar_rgb and llvm_ad_rgb, and eval / cos(theta_o) is compared with the model's own
``eval`` on the same float32-rounded directions:

* Python plugin: the model computes in float64 and the plugin rounds f cos once to float32, so the two
  agree to one float32 rounding (2^-24 relative; 5.8e-8 measured).
* Native GGX: within NATIVE_REL_TOL (1e-4); native Beckmann: within BECKMANN_REL_TOL (0.7 %, Mitsuba's
  G1 fit), where the model's D is above Mitsuba's cutoff (D cos(theta_h) <= 1e-20 gives 0 there).

Mitsuba's wo is the light direction when radiance is transported: the plugin evaluates
model.eval(wi=wo, wo=si.wi), which matters only for the non-reciprocal Kajiya-Kay.
"""

from __future__ import annotations

import inspect
from collections.abc import Iterator
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import model as model_pkg
from model import BlinnPhong, CookTorrance, Lambert, MerlTable, MetalnessMix, MetalRoughness, Phong, microfacet
from model.merl import SHAPE
from model.mitsuba import plugin as mitsuba_bsdf
from model.mitsuba.materials import BECKMANN_REL_TOL, NATIVE_REL_TOL, to_mitsuba
from model.mitsuba.variant import use_variant
from tests.mitsuba_helpers import ORACLE_VARIANTS, bsdf_eval_cos, f32, held_variant, require_variant
from tests.model import model_instances as shared

pytestmark = pytest.mark.mitsuba

#: One float32 rounding of the plugin's output, with a little margin.
PLUGIN_REL_TOL = 1.5 * 2.0**-24
#: Native GGX plugins at well-conditioned indices (see test_mitsuba_eval_matches_model).
GGX_REL_TOL = 1e-5
#: float32's smallest normal number: below it the output is subnormal and loses relative precision.
F32_TINY = float(np.finfo(np.float32).tiny)

# Gold-like and copper-like indices (F0 well above materials.F0_MIN_NATIVE in every channel).
GOLD = {"eta": (0.18, 0.42, 1.37), "k": (3.42, 2.35, 1.77)}
COPPER = {"eta": (0.27, 0.68, 1.22), "k": (3.61, 2.63, 2.29)}


def merl_table() -> MerlTable:
    """A synthetic MERL table: a smooth RGB falloff in theta_h with one bin range without data (NaN)."""
    th = ((np.arange(SHAPE[0]) + 0.5) / SHAPE[0]) ** 2 * (np.pi / 2)
    lobe = 0.05 + 3.0 * np.exp(-((th / 0.2) ** 2))
    values = np.broadcast_to(lobe[None, :, None, None] * np.array([1.0, 0.7, 0.4])[:, None, None, None], (3, *SHAPE))
    values = values.copy()
    values[:, :, 80:, :] = np.nan
    return MerlTable(values, source="synthetic")


#: name -> (model, expected plugin). Native exactly where model.mitsuba.materials documents it.
CASES: dict[str, tuple[Any, str]] = {
    "lambert": (shared.LAMBERT, "diffuse"),
    "ct_ggx_conductor": (CookTorrance(alpha=0.25, **GOLD), "roughconductor"),
    "ct_beckmann_conductor": (CookTorrance(alpha=0.3, distribution="beckmann", **COPPER), "roughconductor"),
    "ct_ggx_dielectric": (CookTorrance(alpha=0.2, fresnel="dielectric", eta=(1.45, 1.5, 1.55)), "roughconductor"),
    "ct_ggx_1982": (CookTorrance(alpha=0.3, form="cook_torrance_1982", **GOLD), "roughconductor"),
    "ct_ggx_with_diffuse": (CookTorrance(alpha=0.15, rho_d=(0.6, 0.3, 0.1), **COPPER), "blendbsdf"),
    "ct_dielectric_with_diffuse": (
        CookTorrance(alpha=0.3, fresnel="dielectric", eta=1.5, rho_d=(0.5, 0.4, 0.2)),
        "blendbsdf",
    ),
    "ct_smith_correlated": (CookTorrance(alpha=0.25, masking="smith_correlated", **GOLD), "gonio_model"),
    "ct_smith_schlick": (CookTorrance(alpha=0.25, masking="smith_schlick", **GOLD), "gonio_model"),
    "ct_v_groove": (CookTorrance(alpha=0.25, distribution="beckmann", masking="v_groove", **GOLD), "gonio_model"),
    "ct_schlick_fresnel": (shared.CT_SCHLICK, "gonio_model"),
    "ct_blinn_phong": (CookTorrance(alpha=0.3, distribution="blinn_phong", **GOLD), "gonio_model"),
    "ct_index_matched": (CookTorrance(alpha=0.25, fresnel="dielectric", eta=(1.01, 1.5, 1.5)), "gonio_model"),
    "ct_rho_d_one": (CookTorrance(alpha=0.25, rho_d=(1.0, 0.5, 0.2), **GOLD), "gonio_model"),
    "phong": (shared.PHONG, "gonio_model"),
    "blinn_phong": (BlinnPhong(rho_d=(0.3, 0.2, 0.1), rho_s=(0.5, 0.5, 0.4), n=80.0), "gonio_model"),
    "ward_anisotropic": (shared.WARD, "gonio_model"),
    "ashikhmin_shirley": (shared.ASHIKHMIN_SHIRLEY, "gonio_model"),
    "oren_nayar": (shared.OREN_NAYAR, "gonio_model"),
    "lafortune": (shared.LAFORTUNE, "gonio_model"),
    "kajiya_kay": (shared.KAJIYA_KAY, "gonio_model"),
    "metal_roughness_dielectric": (MetalRoughness(base_color=(0.8, 0.5, 0.2), metallic=0.0, roughness=0.5),
                                   "gonio_model"),
    "metal_roughness_metal": (shared.METAL, "gonio_model"),
    "metalness_mix": (MetalnessMix(base_color=(0.8, 0.5, 0.2), roughness=0.5, metalness=0.3), "gonio_model"),
    "merl_table": (merl_table(), "gonio_model"),
}


@pytest.fixture(params=ORACLE_VARIANTS)
def variant(request: pytest.FixtureRequest) -> Iterator[str]:
    yield from held_variant(request.param)


def sph(theta_deg: float, phi_deg: float) -> np.ndarray:
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def direction_pairs() -> tuple[np.ndarray, np.ndarray]:
    """float32-rounded (si.wi, wo) pairs: a grid down to 89.7 deg, mirror pairs, and a few below the horizon."""
    thetas = (0.0, 25.0, 50.0, 75.0, 88.0, 89.7)
    wis = [sph(t, p) for t in thetas for p in (0.0, 135.0)]
    wos = [sph(t, p) for t in thetas for p in (0.0, 70.0, 180.0, 250.0)]
    pairs = [(a, b) for a in wis for b in wos]
    pairs += [(a, np.array([-a[0], -a[1], a[2]])) for a in wis]  # the mirror direction: lobe peaks
    pairs += [(a, sph(t, 200.0)) for a in wis for t in (4.0, 12.0)]  # near the peak at normal incidence
    below = [(sph(40.0, 0.0) * [1, 1, -1], sph(40.0, 180.0)), (sph(40.0, 0.0), sph(60.0, 90.0) * [1, 1, -1])]
    pairs += below
    wi, wo = (f32(np.array(x)) for x in zip(*pairs, strict=True))
    return wi, wo


def light_view(wi: np.ndarray, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Model (wi, wo) for Mitsuba's (si.wi, wo) in radiance mode: the light is at Mitsuba's wo."""
    return wo, wi


def model_eval_cos(m: Any, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """The model's f_r times cos(theta of Mitsuba's wo), as (N, 3)."""
    f = np.asarray(m.eval(*light_view(wi, wo)), dtype=np.float64).reshape(len(wi), -1)
    return np.broadcast_to(f, (len(wi), 3)) * np.maximum(wo[:, 2:3], 0.0)


def test_every_model_class_has_a_case() -> None:
    classes = {
        obj
        for name in model_pkg.__all__
        if inspect.isclass(obj := getattr(model_pkg, name))
        and callable(getattr(obj, "eval", None))
        and not inspect.isabstract(obj)
        and obj is not model_pkg.BRDF
    }
    covered = {type(m) for m, _ in CASES.values()}
    assert classes - covered == set(), f"models without a Mitsuba case: {sorted(c.__name__ for c in classes - covered)}"


@pytest.mark.parametrize("name", sorted(CASES))
def test_native_exactly_where_documented(name: str) -> None:
    m, plugin = CASES[name]
    mat = to_mitsuba(m)
    assert mat.plugin == plugin, mat.note
    assert mat.native == (plugin != mitsuba_bsdf.PLUGIN)
    assert mat.needs_evaluated_calls == (not mat.native)
    assert mat.to_dict()["type"] == plugin and mat.note
    forced = to_mitsuba(m, allow_native=False)
    assert not forced.native and forced.plugin == mitsuba_bsdf.PLUGIN


@pytest.mark.parametrize("name", sorted(CASES))
def test_mitsuba_eval_matches_model(variant: str, name: str) -> None:
    m, _ = CASES[name]
    mat = to_mitsuba(m)
    wi, wo = direction_pairs()
    theirs = bsdf_eval_cos(variant, mat.to_dict(), wi, wo)
    ours = model_eval_cos(m, wi, wo)
    assert theirs.shape == ours.shape and np.all(np.isfinite(theirs))
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    assert np.all(theirs[~above] == 0.0)
    if not mat.native:
        np.testing.assert_allclose(theirs, ours, rtol=PLUGIN_REL_TOL, atol=F32_TINY)
        return
    if isinstance(m, CookTorrance) and m.distribution == "beckmann":
        s = wi + wo
        cos_h = s[:, 2] / np.linalg.norm(s, axis=-1)
        kept = microfacet.distribution_d("beckmann", cos_h, m.alpha) * cos_h > 1e-20 * (1 + 1e-3)
        rel = np.abs(theirs - ours)[kept & above] / ours[kept & above]
        assert rel.max() <= BECKMANN_REL_TOL
        return
    # NATIVE_REL_TOL bounds every index the mapping admits (down to F0 = 2e-3); these indices have F0 >= 0.04,
    # where Mitsuba's float32 Fresnel is good to 2e-6 (measured 2.3e-6 worst over all native GGX cases here).
    assert NATIVE_REL_TOL >= GGX_REL_TOL
    np.testing.assert_allclose(theirs, ours, rtol=GGX_REL_TOL, atol=F32_TINY)


def test_kajiya_kay_follows_the_transport_mode() -> None:
    require_variant("llvm_ad_rgb")
    m = CASES["kajiya_kay"][0]
    wi, wo = direction_pairs()
    with use_variant("llvm_ad_rgb"):
        bsdf = mi.load_dict(to_mitsuba(m).to_dict())
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wi = mi.Vector3f(np.ascontiguousarray(wi.T, dtype=np.float32))
        ctx = mi.BSDFContext(mi.TransportMode.Importance)
        theirs = np.array(bsdf.eval(ctx, si, mi.Vector3f(np.ascontiguousarray(wo.T, dtype=np.float32)))).T
    # Light paths: si.wi is the light direction, so the model's arguments come in Mitsuba's order.
    ours = np.asarray(m.eval(wi, wo)) * np.maximum(wo[:, 2:3], 0.0)
    np.testing.assert_allclose(theirs, ours, rtol=PLUGIN_REL_TOL, atol=F32_TINY)
    assert not np.allclose(ours, model_eval_cos(m, wi, wo))  # the swap is visible for this model


def sample_bsdf(
    variant: str, bsdf: Any, wi: np.ndarray, u: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(wo, pdf, weight, eval at wo) of bsdf.sample for pairs of si.wi (N, 3) and uniforms u (N, 3)."""
    ctx = mi.BSDFContext()
    if dr.is_jit_v(mi.Float):
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wi = mi.Vector3f(np.ascontiguousarray(wi.T, dtype=np.float32))
        bs, weight = bsdf.sample(ctx, si, mi.Float(u[:, 0].astype(np.float32)),
                                 mi.Point2f(np.ascontiguousarray(u[:, 1:].T, dtype=np.float32)))
        value = bsdf.eval(ctx, si, bs.wo)
        return (np.array(bs.wo, dtype=np.float64).T, np.array(bs.pdf, dtype=np.float64),
                np.array(weight, dtype=np.float64).T, np.array(value, dtype=np.float64).T)
    rows = []
    for a, b in zip(wi, u, strict=True):
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wi = mi.Vector3f(*(float(x) for x in a))
        bs, weight = bsdf.sample(ctx, si, float(b[0]), mi.Point2f(float(b[1]), float(b[2])))
        value = bsdf.eval(ctx, si, bs.wo)
        rows.append((list(bs.wo), float(bs.pdf), list(weight), list(value)))
    return tuple(np.array([r[i] for r in rows], dtype=np.float64) for i in range(4))  # type: ignore[return-value]


@pytest.mark.parametrize("name", ["phong", "kajiya_kay", "merl_table", "ct_smith_correlated"])
def test_sampling_is_cosine_weighted_with_weight_eval_over_pdf(variant: str, name: str) -> None:
    m = CASES[name][0]
    rng = np.random.default_rng(21)
    n = 2000 if variant.startswith("llvm") else 100
    wi = f32(np.array([sph(t, p) for t, p in zip(rng.uniform(0, 89.5, n), rng.uniform(0, 360, n), strict=True)]))
    wi[: n // 10, 2] *= -1.0  # a tenth from below the horizon: nothing may come back
    u = rng.uniform(size=(n, 3))
    with use_variant(variant):
        bsdf = mi.load_dict(to_mitsuba(m).to_dict())
        wo, pdf, weight, value = sample_bsdf(variant, bsdf, wi, u)
    below, up = wi[:, 2] <= 0, wi[:, 2] > 0
    assert np.all(pdf[below] == 0.0) and np.all(weight[below] == 0.0)
    assert np.all(wo[up, 2] > 0.0)
    np.testing.assert_allclose(np.linalg.norm(wo[up], axis=-1), 1.0, rtol=1e-6)
    np.testing.assert_allclose(pdf[up], wo[up, 2] / np.pi, rtol=1e-6)
    # weight = eval / pdf, both float32: one more rounding of the quotient.
    np.testing.assert_allclose(weight[up], value[up] / pdf[up, None], rtol=3e-7, atol=F32_TINY)
    np.testing.assert_allclose(value[up], model_eval_cos(m, wi[up], wo[up]), rtol=PLUGIN_REL_TOL, atol=F32_TINY)


def scene(bsdf: dict[str, Any], seed: int = 0, integrator: dict[str, Any] | None = None) -> Any:
    """A 16x16 view of a 2 x 2 rectangle (the sample) under one point light, direct illumination by default."""
    return mi.load_dict({
        "type": "scene",
        "integrator": integrator or {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
        "sensor": {
            "type": "perspective",
            "fov": 20.0,
            "to_world": mi.ScalarTransform4f().look_at(origin=[0.0, -2.0, 3.0], target=[0.0, 0.0, 0.0], up=[0, 0, 1]),
            "film": {"type": "hdrfilm", "width": 16, "height": 16, "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": 4, "seed": seed},
        },
        "sample": {"type": "rectangle", "bsdf": bsdf},
        "light": {"type": "point", "position": [0.3, 1.5, 2.0], "intensity": {"type": "rgb", "value": [10.0] * 3}},
    })


def render(variant: str, bsdf: dict[str, Any]) -> np.ndarray:
    with use_variant(variant), mitsuba_bsdf.evaluated_calls():
        return np.array(mi.render(scene(bsdf), spp=4), dtype=np.float64)


@pytest.mark.parametrize("name", ["phong", "ward_anisotropic", "merl_table"])
def test_python_plugin_renders(variant: str, name: str) -> None:
    img = render(variant, to_mitsuba(CASES[name][0]).to_dict())
    assert img.shape == (16, 16, 3) and np.all(np.isfinite(img)) and np.all(img >= 0.0)
    assert np.mean(img > 0.0) > 0.9  # the rectangle fills the view and the light reaches all of it


def test_path_integrator_renders_with_evaluated_calls(variant: str) -> None:
    # The path integrator's bounce loop is a dr.while_loop: under llvm it needs SymbolicLoops off as well,
    # and it samples the plugin (BSDF sampling with multiple importance) besides evaluating it.
    s = scene(to_mitsuba(CASES["oren_nayar"][0]).to_dict(), integrator={"type": "path", "max_depth": 3})
    with mitsuba_bsdf.evaluated_calls():
        img = np.array(mi.render(s, spp=2), dtype=np.float64)
    assert np.all(np.isfinite(img)) and np.all(img >= 0.0) and np.mean(img > 0.0) > 0.9


def test_scalar_and_llvm_renders_agree() -> None:
    for v in ORACLE_VARIANTS:
        require_variant(v)
    bsdf = to_mitsuba(CASES["ward_anisotropic"][0]).to_dict()
    means = [float(render(v, bsdf).mean()) for v in ORACLE_VARIANTS]
    # Different random streams per variant, same scene: the means agree to the pixel jitter noise.
    assert max(means) / min(means) < 1.02  # measured 1.003


def test_native_and_plugin_render_the_same_image() -> None:
    require_variant("llvm_ad_rgb")
    m = CASES["ct_ggx_with_diffuse"][0]
    with use_variant("llvm_ad_rgb"):
        native = render("llvm_ad_rgb", to_mitsuba(m).to_dict())
        plugin = render("llvm_ad_rgb", to_mitsuba(m, allow_native=False).to_dict())
    # Emitter sampling only and the same seed: the same paths, so only the BSDF values differ.
    assert float(native.max()) > 0.0
    np.testing.assert_allclose(plugin, native, rtol=GGX_REL_TOL, atol=1e-6 * float(native.max()))  # 4.6e-7


def test_llvm_render_needs_evaluated_calls() -> None:
    require_variant("llvm_ad_rgb")
    with use_variant("llvm_ad_rgb"):
        s = scene(to_mitsuba(CASES["phong"][0]).to_dict())
        with dr.scoped_set_flag(dr.JitFlag.SymbolicCalls, True), pytest.raises(RuntimeError) as info:
            mi.render(s, spp=1)
    # drjit wraps the plugin's own message; it travels as the cause and names the remedy.
    messages, exc = [], info.value
    while exc is not None:
        messages.append(str(exc))
        exc = exc.__cause__ or exc.__context__
    assert any("evaluated_calls" in m for m in messages), messages


def test_registration_is_per_variant_and_idempotent() -> None:
    for v in ORACLE_VARIANTS:
        require_variant(v)
        with use_variant(v):
            assert mitsuba_bsdf.ensure_registered() == v
            assert mitsuba_bsdf.ensure_registered() == v
            assert mi.load_dict(to_mitsuba(Phong()).to_dict()) is not None
            with pytest.raises(Exception, match="no model registered"):
                mi.load_dict({"type": mitsuba_bsdf.PLUGIN, mitsuba_bsdf.MODEL_KEY: "missing"})
    with use_variant("scalar_spectral"), pytest.raises(ValueError, match="not an rgb variant"):
        mitsuba_bsdf.ensure_registered()


def test_same_model_same_key_and_channels_checked() -> None:
    m = Phong()
    assert mitsuba_bsdf.register_model(m) == mitsuba_bsdf.register_model(m)
    assert mitsuba_bsdf.register_model(m) != mitsuba_bsdf.register_model(Phong())
    with pytest.raises(ValueError, match="1 or 3"):
        to_mitsuba(Lambert(rho_d=(0.1, 0.2)))
    with pytest.raises(TypeError, match="eval"):
        mitsuba_bsdf.register_model(object())  # type: ignore[arg-type]


def test_eval_cos_broadcasts_scalar_models_to_rgb() -> None:
    m = Phong(rho_d=0.2, rho_s=0.3, n=10.0)
    wi, wo = np.array([sph(30.0, 0.0), sph(60.0, 10.0)]), sph(30.0, 180.0)
    out = mitsuba_bsdf.eval_cos(m, wi, wo)
    assert out.shape == (2, 3) and np.all(out[:, 0:1] == out)
    np.testing.assert_allclose(out[:, 0], m.eval(wo, wi) * wo[2])
