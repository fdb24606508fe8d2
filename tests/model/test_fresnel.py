import numpy as np
import pytest

from model import fresnel

cos = np.linspace(0.0, 1.0, 2001)


def test_conductor_real_form_equals_complex_amplitudes():
    for eta, k in [(0.2, 3.9), (1.5, 0.0), (2.9, 3.0), (0.05, 200.0), (1.0, 1.0)]:
        assert np.allclose(fresnel.conductor(cos, eta, k), fresnel.conductor_complex(cos, eta, k), atol=1e-12)


def test_normal_incidence_matches_f0():
    for eta, k in [(1.5, 0.0), (1.33, 0.0), (0.2, 3.9)]:
        assert fresnel.conductor(1.0, eta, k) == pytest.approx(fresnel.f0_from_ior(eta, k), rel=1e-12)
    assert fresnel.dielectric(1.0, 1.5) == pytest.approx(0.04, rel=1e-12)
    assert fresnel.ior_from_f0(0.04) == pytest.approx(1.5)


def test_dielectric_limits():
    assert np.all(fresnel.dielectric(cos, 1.0) < 1e-15)
    assert fresnel.dielectric(0.0, 1.5) == 1.0
    # Brewster's angle: the p amplitude vanishes, so F = |r_s|^2 / 2.
    theta_b = np.arctan(1.5)
    c = np.cos(theta_b)
    ct = np.sqrt(1 - (1 - c * c) / 2.25)
    rs = (c - 1.5 * ct) / (c + 1.5 * ct)
    assert fresnel.dielectric(c, 1.5) == pytest.approx(0.5 * rs * rs, rel=1e-12)


def test_total_internal_reflection_is_exactly_one():
    eta = 1 / 1.5
    crit = np.arcsin(eta)
    inside = np.cos(np.linspace(crit + 1e-9, np.pi / 2, 50))
    assert np.all(fresnel.dielectric(inside, eta) == 1.0)
    below = np.cos(np.linspace(0, crit - 1e-3, 50))
    assert np.all(fresnel.dielectric(below, eta) < 1.0)


def test_dielectric_matches_conductor_without_absorption():
    assert np.allclose(fresnel.dielectric(cos, 1.7), fresnel.conductor(cos, 1.7, 0.0), atol=1e-12)


def test_large_extinction_approaches_perfect_mirror_and_stays_bounded():
    f = fresnel.conductor(cos, 0.1, 1e3)
    assert np.all((f > 0.999) & (f <= 1.0))


def test_schlick_end_points_and_float32():
    assert fresnel.schlick(1.0, 0.04) == pytest.approx(0.04)
    assert fresnel.schlick(0.0, 0.04) == pytest.approx(1.0)
    f32 = fresnel.schlick(cos.astype(np.float32), np.float32(0.5))
    assert f32.dtype == np.float32
    assert np.all((f32 >= 0.5) & (f32 <= 1.0))


def test_fresnel_is_bounded_for_float32_and_extreme_indices():
    c = cos.astype(np.float32)
    for eta, k in [(1e-3, 0.0), (100.0, 0.0), (0.2, 1000.0)]:
        f = fresnel.conductor(c, np.float32(eta), np.float32(k))
        assert np.all(np.isfinite(f)) and np.all((f >= 0) & (f <= 1))
