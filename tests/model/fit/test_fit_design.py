"""The error measure, the first-order error prediction and the greedy choice of captures (model/fit/design.py)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from model import CookTorrance, Lambert
from model.fit.design import (
    brdf_error,
    choose_batch,
    covariance,
    error_pairs,
    error_weight,
    expected_error,
    fisher,
    pooled,
    sensitivities,
)
from model.fit.samples import FitError, Samples
from model.fit.solve import fit
from model.fit.spec import LAMBERT, lambert_ggx
from model.geometry import degrees_to_vector

PLASTIC = CookTorrance(rho_d=(0.5, 0.12, 0.08), alpha=0.08, distribution="ggx", fresnel="dielectric", eta=1.5)
REL = 0.02


def _pairs(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    th_i, th_o = rng.uniform(0, 70, n), rng.uniform(0, 70, n)
    return degrees_to_vector(th_i, np.zeros(n)), degrees_to_vector(th_o, rng.uniform(0, 180, n))


def _noisy(truth: CookTorrance, wi: np.ndarray, wo: np.ndarray, rng: np.random.Generator) -> Samples:
    f = np.asarray(truth.eval(wi, wo))
    return Samples(wi, wo, f * (1 + REL * rng.standard_normal(f.shape)), REL * f)


def test_error_pairs_are_cosine_distributed_within_the_zenith_limit() -> None:
    p = error_pairs(20000, max_theta_deg=70.0, seed=1)
    for w in (p.wi, p.wo):
        assert np.all(w[:, 2] >= np.cos(np.radians(70.0)) - 1e-12)
        # cos^2 uniform on [cos^2 70, 1]: its mean is the interval's midpoint.
        assert np.mean(w[:, 2] ** 2) == pytest.approx((1 + np.cos(np.radians(70)) ** 2) / 2, abs=0.01)
    np.testing.assert_allclose(p.wi[:, 1], 0.0, atol=1e-12)  # isotropic: phi_i = 0
    with pytest.raises(FitError, match="max_theta_deg"):
        error_pairs(10, max_theta_deg=0.0)


def test_brdf_error_is_zero_for_the_same_model_and_the_scale_error_for_a_scaled_one() -> None:
    p = error_pairs(500)
    assert brdf_error(PLASTIC, PLASTIC, p) == 0.0
    assert brdf_error(Lambert(rho_d=0.33), Lambert(rho_d=0.3), p) == pytest.approx(0.1, rel=1e-9)


def test_sensitivities_match_the_analytic_derivatives() -> None:
    rng = np.random.default_rng(0)
    wi, wo = _pairs(rng, 50)
    g = sensitivities(LAMBERT, np.array([0.2, 0.4, 0.6]), wi, wo, 3)
    np.testing.assert_allclose(g, np.broadcast_to(np.eye(3) / np.pi, (50, 3, 3)), rtol=1e-8, atol=1e-12)
    # alpha is fitted in log space: df/dlog(alpha) = alpha df/dalpha.
    spec = lambert_ggx("dielectric")
    x = np.array([0.5, 0.12, 0.08, 0.08, 1.5])
    g = sensitivities(spec, x, wi, wo, 3)
    h = 1e-7
    up, down = (PLASTIC.__class__(**{**_fields(PLASTIC), "alpha": 0.08 + s}) for s in (h, -h))
    dfda = (np.asarray(up.eval(wi, wo)) - np.asarray(down.eval(wi, wo))) / (2 * h)
    np.testing.assert_allclose(g[:, :, 3], 0.08 * dfda, rtol=1e-4, atol=1e-9)


def _fields(m: CookTorrance) -> dict[str, object]:
    return {k: getattr(m, k) for k in ("rho_d", "alpha", "distribution", "fresnel", "eta")}


def _mc_error(wi: np.ndarray, wo: np.ndarray, seeds: int) -> float:
    """RMS over noise realisations of the BRDF error of lambert_ggx fits at these pairs."""
    pairs = error_pairs(2000, max_theta_deg=70.0)
    errs = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for seed in range(seeds):
            res = fit(lambert_ggx("dielectric"), _noisy(PLASTIC, wi, wo, np.random.default_rng(100 + seed)),
                      starts=1, warn=False)  # fmt: skip
            errs.append(brdf_error(res.model, PLASTIC, pairs))
    return float(np.sqrt(np.mean(np.square(errs))))


def _predicted(wi: np.ndarray, wo: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    spec = lambert_ggx("dielectric")
    x = np.array([0.5, 0.12, 0.08, 0.08, 1.5])
    pairs = error_pairs(2000, max_theta_deg=70.0)
    f = np.asarray(PLASTIC.eval(wi, wo))
    cov = covariance(fisher(sensitivities(spec, x, wi, wo, 3), REL * f))
    a = error_weight(sensitivities(spec, x, pairs.wi, pairs.wo, 3), np.asarray(PLASTIC.eval(pairs.wi, pairs.wo)))
    return expected_error(a, cov), cov, a


def test_the_first_order_prediction_matches_the_error_of_repeated_fits() -> None:
    wi, wo = _pairs(np.random.default_rng(1), 120)
    predicted, _, _ = _predicted(wi, wo)
    measured = _mc_error(wi, wo, seeds=40)
    assert measured == pytest.approx(predicted, rel=0.3), (measured, predicted)


def test_greedy_captures_beat_random_ones_in_prediction_and_in_repeated_fits() -> None:
    rng = np.random.default_rng(2)
    wi0, wo0 = _pairs(rng, 20)
    _, cov, a = _predicted(wi0, wo0)
    # Candidates: half random, half close to the mirror direction, where the glossy lobe lives.
    wi_c, wo_c = _pairs(rng, 1000)
    th = rng.uniform(0, 70, 1000)
    wi_s = degrees_to_vector(th, np.zeros(1000))
    wo_s = degrees_to_vector(np.clip(th + rng.normal(0, 3, 1000), 0, 70), 180 + rng.normal(0, 3, 1000))
    wi_c, wo_c = np.concatenate([wi_c, wi_s]), np.concatenate([wo_c, wo_s])
    spec = lambert_ggx("dielectric")
    x = np.array([0.5, 0.12, 0.08, 0.08, 1.5])
    g = sensitivities(spec, x, wi_c, wo_c, 3)
    batch = choose_batch(cov, g, REL * np.asarray(PLASTIC.eval(wi_c, wo_c)), a, 20)
    assert len(set(batch.indices.tolist())) == 20
    assert np.all(np.diff(batch.error_after) <= 1e-15) and batch.error_after[-1] < batch.error_before
    pick = batch.indices
    rand = rng.choice(len(wi_c), 20, replace=False)
    p_greedy, _, _ = _predicted(np.concatenate([wi0, wi_c[pick]]), np.concatenate([wo0, wo_c[pick]]))
    p_random, _, _ = _predicted(np.concatenate([wi0, wi_c[rand]]), np.concatenate([wo0, wo_c[rand]]))
    assert p_greedy == pytest.approx(batch.error_after[-1], rel=1e-6)
    assert p_greedy < 0.9 * p_random
    m_greedy = _mc_error(np.concatenate([wi0, wi_c[pick]]), np.concatenate([wo0, wo_c[pick]]), seeds=25)
    m_random = _mc_error(np.concatenate([wi0, wi_c[rand]]), np.concatenate([wo0, wo_c[rand]]), seeds=25)
    assert m_greedy < m_random, (m_greedy, m_random)


def test_choose_batch_refuses_more_captures_than_candidates() -> None:
    with pytest.raises(FitError, match="asked for 5 captures from 3"):
        choose_batch(np.eye(2), np.zeros((3, 1, 2)), np.ones((3, 1)), np.eye(2), 5)


def test_the_scale_free_error_ignores_a_common_factor_per_channel_but_not_a_shape_change() -> None:
    p = error_pairs(500)
    scaled = CookTorrance(rho_d=(0.55, 0.12, 0.08), alpha=0.08, distribution="ggx", fresnel="dielectric", eta=1.5)
    assert brdf_error(Lambert(rho_d=(0.33, 0.2, 0.1)), Lambert(rho_d=(0.3, 0.25, 0.1)), p, scale_free=True) < 1e-12
    assert brdf_error(scaled, PLASTIC, p, scale_free=True) > 1e-3  # a diffuse change is not a scale


def test_pooled_readings_carry_each_capture_s_information_and_pick_as_all_its_readings_would() -> None:
    rng = np.random.default_rng(4)
    g = rng.normal(size=(12, 3, 2))  # 12 readings of 3 channels, 2 parameters
    sigma = rng.uniform(0.5, 2.0, size=(12, 3))
    owner = np.array([0, 0, 0, 0, 1, 2, 2, 2, 2, 2, 2, 3])
    g_pose, s_pose = pooled(g, sigma, owner, 4)
    assert g_pose.shape == (4, 2, 2) and np.all(s_pose == 1.0)
    for m in range(4):
        mine = owner == m
        assert fisher(g_pose[m : m + 1], s_pose[m : m + 1]) == pytest.approx(fisher(g[mine], sigma[mine]))
    # A capture of many readings outweighs one of a single reading of the same kind: its information is the sum.
    cov = covariance(np.zeros((2, 2)))
    a = np.eye(2)
    picked = choose_batch(cov, g_pose, s_pose, a, 1).indices
    one_by_one = [expected_error(a, np.linalg.inv(np.linalg.inv(cov) + fisher(g[owner == m], sigma[owner == m])))
                  for m in range(4)]  # fmt: skip
    assert picked[0] == int(np.argmin(one_by_one))
