"""Closed-form identities: what each model's normalisation and each conversion promises."""

import numpy as np
import pytest

import model as m
from model.checks import random_hemisphere
from model.geometry import degrees_to_vector
from model.integrate import directional_albedo, integrate_hemisphere

NORMAL = np.array([0.0, 0.0, 1.0])


@pytest.mark.parametrize("method,n,tol", [("quadrature", 4096, 1e-12), ("mc", 200_000, 0.01)])
def test_cosine_integrates_to_pi(method, n, tol):
    est = integrate_hemisphere(lambda d: d[:, 2], n=n, method=method, rng=5)
    assert float(est.value) == pytest.approx(np.pi, rel=tol)


@pytest.mark.parametrize("theta", [0.0, 30.0, 60.0, 85.0])
def test_lambert_albedo_equals_rho(theta):
    est = directional_albedo(m.Lambert((0.2, 0.5, 0.9)), degrees_to_vector(theta, 0.0), n=4096)
    assert np.allclose(est.value, [0.2, 0.5, 0.9], rtol=1e-12)


@pytest.mark.parametrize("n_exp", [1.0, 10.0, 100.0, 1000.0])
def test_phong_lobe_albedo_is_rho_s_at_normal_incidence_and_less_elsewhere(n_exp):
    model = m.Phong(0.0, 0.7, n_exp)
    normal = directional_albedo(model, NORMAL, n=400_000)
    assert float(normal.value) == pytest.approx(0.7, rel=2e-3)
    oblique = directional_albedo(model, degrees_to_vector(70.0, 0.0), n=400_000)
    assert float(oblique.value) < 0.7


@pytest.mark.parametrize("n_exp", [0.0, 1.0, 10.0, 100.0, 1000.0])
def test_blinn_phong_exact_normalisation(n_exp):
    model = m.BlinnPhong(0.0, 0.6, n_exp)
    est = directional_albedo(model, NORMAL, n=400_000)
    assert float(est.value) == pytest.approx(0.6, rel=2e-3)


def test_blinn_phong_approximate_normalisation_overshoots_as_documented():
    ratios = [
        m.BlinnPhong(0.0, 1.0, n, normalization="approx").norm / m.BlinnPhong(0.0, 1.0, n).norm
        for n in np.linspace(0.0, 40.0, 81)
    ]
    assert 1.07 < max(ratios) < 1.076
    assert m.BlinnPhong(0, 1, 200, normalization="approx").norm / m.BlinnPhong(0, 1, 200).norm < 1.01


def test_cook_torrance_1982_form_is_four_times_walter():
    rng = np.random.default_rng(0)
    wi, wo = random_hemisphere(500, rng), random_hemisphere(500, rng)
    for dist in ("ggx", "beckmann"):
        walter = m.CookTorrance(alpha=0.3, distribution=dist)
        old = m.CookTorrance(alpha=0.3, distribution=dist, form="cook_torrance_1982")
        assert np.allclose(m.walter_from_1982(old.eval(wi, wo)), walter.eval(wi, wo), rtol=1e-12)


@pytest.mark.parametrize("alpha,anchor", [(0.1, 0.99), (0.5, 0.69), (1.0, 0.31)])
def test_white_furnace_matches_reference_anchors(alpha, anchor):
    model = m.CookTorrance(alpha=alpha, fresnel="schlick", f0=1.0)
    est = directional_albedo(model, NORMAL, n=1_000_000)
    assert float(est.value) == pytest.approx(anchor, abs=0.006)


def test_oren_nayar_with_smooth_facets_is_lambert():
    rng = np.random.default_rng(1)
    wi, wo = random_hemisphere(200, rng), random_hemisphere(200, rng)
    assert np.allclose(m.OrenNayar(0.6, 0.0).eval(wi, wo), m.Lambert(0.6).eval(wi, wo))


def test_oren_nayar_brightens_backscatter():
    on = m.OrenNayar(0.6, 0.5)
    wi = degrees_to_vector(60.0, 0.0)
    assert on.eval(wi, wi) > on.eval(wi, degrees_to_vector(60.0, 180.0))


def test_lafortune_mirror_lobe_is_an_unnormalised_phong_lobe():
    rng = np.random.default_rng(2)
    wi, wo = random_hemisphere(300, rng), random_hemisphere(300, rng)
    laf = m.Lafortune(0.0, (m.LafortuneLobe(-1.0, -1.0, 1.0, 20.0),))
    phong = m.Phong(0.0, 1.0, 20.0)
    scale = 22.0 / (2 * np.pi)
    assert np.allclose(laf.eval(wi, wo) * scale, phong.eval(wi, wo), rtol=1e-10, atol=1e-300)


def test_metal_roughness_metal_is_cook_torrance_with_schlick_and_correlated_smith():
    rng = np.random.default_rng(3)
    wi, wo = random_hemisphere(300, rng), random_hemisphere(300, rng)
    mr = m.MetalRoughness((0.9, 0.6, 0.3), metallic=1.0, roughness=0.5)
    ct = m.CookTorrance(alpha=0.25, masking="smith_correlated", fresnel="schlick", f0=(0.9, 0.6, 0.3))
    assert np.allclose(mr.eval(wi, wo), ct.eval(wi, wo), rtol=1e-12)


def test_metalness_mix_ends():
    rng = np.random.default_rng(4)
    wi, wo = random_hemisphere(300, rng), random_hemisphere(300, rng)
    metal = m.MetalnessMix(0.8, roughness=0.6, metalness=1.0)
    ct = m.CookTorrance(alpha=0.36, masking="smith_schlick", fresnel="schlick", f0=0.8)
    assert np.allclose(metal.eval(wi, wo), ct.eval(wi, wo), rtol=1e-12)
    plastic = m.MetalnessMix(0.8, roughness=0.6, metalness=0.0)
    assert np.all(plastic.eval(wi, wo) > 0)


def test_ward_variants_differ_only_in_normalisation():
    wi = degrees_to_vector(30.0, 0.0)
    wo = degrees_to_vector(30.0, 180.0)
    ward, duer = m.Ward(0, 1, 0.2, variant="ward"), m.Ward(0, 1, 0.2, variant="duer")
    c = np.cos(np.radians(30.0))
    assert float(duer.eval(wi, wo)) == pytest.approx(float(ward.eval(wi, wo)) / c, rel=1e-12)


def test_anisotropy_rotates_with_the_tangent():
    ward = m.Ward(0, 1, 0.05, 0.3)
    wi = degrees_to_vector(40.0, 0.0)
    along_x = ward.eval(wi, degrees_to_vector(40.0, 170.0))
    rot = m.Ward(0, 1, 0.3, 0.05)
    assert float(rot.eval(degrees_to_vector(40.0, 90.0), degrees_to_vector(40.0, 260.0))) == pytest.approx(
        float(along_x), rel=1e-9
    )
    ashikhmin = m.AshikhminShirley(0.0, 1.0, 10.0, 1000.0)
    assert ashikhmin.eval(wi, degrees_to_vector(40.0, 170.0)) != ashikhmin.eval(
        degrees_to_vector(40.0, 90.0), degrees_to_vector(40.0, 260.0)
    )


def test_kajiya_kay_peaks_on_the_fibre_cone():
    kk = m.KajiyaKay(0.0, 1.0, 200.0, 0.0)
    wi = degrees_to_vector(45.0, 0.0)
    # Mirror about the normal keeps T.wo = -T.wi: on the cone, value 1 * k_s.
    assert float(kk.eval(wi, degrees_to_vector(45.0, 180.0))) == pytest.approx(1.0, rel=1e-9)
    assert float(kk.eval(wi, degrees_to_vector(20.0, 180.0))) < 0.01


def test_float32_agrees_with_float64():
    rng = np.random.default_rng(5)
    wi, wo = random_hemisphere(2000, rng), random_hemisphere(2000, rng)
    ct = m.CookTorrance(alpha=0.3, eta=(0.2, 0.9, 1.1), k=(3.9, 2.4, 2.2))
    f64 = ct.eval(wi, wo)
    f32 = ct.eval(wi.astype(np.float32), wo.astype(np.float32))
    assert f32.dtype == np.float32
    assert np.allclose(f32, f64, rtol=1e-4, atol=1e-6)
