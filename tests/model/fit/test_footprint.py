"""A footprint's mean by sigma points (model/fit/footprint.py) and fits that predict it (fit_with_angular)."""

from __future__ import annotations

import numpy as np

import model as m
from model.fit.angular import fit_with_angular
from model.fit.footprint import MAX_AXES, footprint_average, sigma_points
from model.fit.samples import Samples
from model.fit.solve import fit
from model.fit.spec import ggx_conductor
from model.geometry import degrees_to_vector

PLASTIC = m.CookTorrance(rho_d=(0.5, 0.12, 0.08), alpha=0.08, distribution="ggx", fresnel="dielectric", eta=1.5)
GOLD = m.CookTorrance(alpha=0.08, eta=(0.18, 0.42, 1.37), k=(3.42, 2.35, 1.77))


def _tile_cov(n: int, std_rad: float, rng: np.random.Generator) -> np.ndarray:
    """Covariances (n, 4, 4) like a tile's: a two-dimensional patch (wi and wo both move with the surface point)
    of ``std_rad`` along each of its axes, plus a pose error a tenth as wide in every component."""
    out = np.empty((n, 4, 4))
    for k in range(n):
        a = rng.normal(size=(4, 2))
        a /= np.linalg.norm(a, axis=0)
        out[k] = std_rad**2 * a @ a.T + (0.1 * std_rad) ** 2 * np.eye(4)
    return out


def _lift(xy: np.ndarray) -> np.ndarray:
    return np.concatenate([xy, np.sqrt(1.0 - np.sum(xy**2, axis=-1, keepdims=True))], axis=-1)


def _monte_carlo(model: m.Model, wi: np.ndarray, wo: np.ndarray, cov: np.ndarray, draws: int, seed: int) -> np.ndarray:
    """The model's mean over N(centre, cov) in the tangent components, by antithetic Monte Carlo (N, C)."""
    rng = np.random.default_rng(seed)
    centre = np.concatenate([wi[:, :2], wo[:, :2]], axis=1)
    chol = np.linalg.cholesky(cov)
    half = draws // 2
    step = np.einsum("nij,knj->kni", chol, rng.normal(size=(half, *centre.shape)))
    d = np.concatenate([centre + step, centre - step]).reshape(-1, 4)
    f = np.asarray(model.eval(_lift(d[:, :2]), _lift(d[:, 2:])), dtype=np.float64)
    return np.asarray(f.reshape(2 * half, centre.shape[0], -1).mean(axis=0), dtype=np.float64)


def _across_the_lobe(n: int) -> tuple[np.ndarray, np.ndarray]:
    """n pairs with wi at 30 deg and wo across its mirror direction (the peak, the flanks, the tails)."""
    theta_o = np.linspace(20.0, 40.0, n)
    return degrees_to_vector(np.full(n, 30.0), np.zeros(n)), degrees_to_vector(theta_o, np.full(n, 180.0))


def test_the_sigma_point_mean_predicts_a_tile_on_a_narrow_lobe_far_better_than_the_centre() -> None:
    rng = np.random.default_rng(1)
    wi, wo = _across_the_lobe(21)
    cov = _tile_cov(21, np.radians(0.8), rng)
    tile = _monte_carlo(PLASTIC, wi, wo, cov, 40_000, seed=2)
    centre = np.asarray(PLASTIC.eval(wi, wo), dtype=np.float64)
    mean = footprint_average(PLASTIC, wi, wo, cov)
    off_centre = np.abs(centre - tile) / tile
    off_mean = np.abs(mean - tile) / tile
    assert off_centre.max() > 0.03  # the curvature is a bias of several percent at the peak
    assert off_mean.max() < 0.1 * off_centre.max()
    assert np.sqrt(np.mean(off_mean**2)) < 0.1 * np.sqrt(np.mean(off_centre**2))


def test_a_fit_to_footprint_means_recovers_alpha_where_the_centre_prediction_is_biased() -> None:
    rng = np.random.default_rng(5)
    n = 120
    theta_i = rng.uniform(10.0, 50.0, n)
    wi = np.asarray(degrees_to_vector(theta_i, np.zeros(n)), dtype=np.float64)
    # Around each mirror direction, within three lobe widths, where the curvature matters.
    wo = np.asarray(degrees_to_vector(theta_i + rng.uniform(-12.0, 12.0, n), 180.0 + rng.uniform(-8.0, 8.0, n)),
                    dtype=np.float64)  # fmt: skip
    cov = _tile_cov(n, np.radians(0.8), rng)
    truth = _monte_carlo(GOLD, wi, wo, cov, 4_000, seed=6)
    rel = 0.003
    value = truth * (1.0 + rel * rng.normal(size=truth.shape))
    s = Samples(wi, wo, value, rel * truth, direction_cov=cov)
    spec = ggx_conductor()
    # The prediction alone: the data's errors are their photometric noise, as synthesised.
    mean_fit = fit(spec, s, starts=2, footprint=True, warn=False)
    centre_fit = fit(spec, s, starts=2, warn=False)
    k = mean_fit.names.index("alpha")
    assert abs(mean_fit.values[k] - GOLD.alpha) < 3 * mean_fit.std_errors[k]
    assert mean_fit.reduced_chi2 < 1.5
    # The centre prediction widens the lobe to match the blurred peak: alpha biased up, by far more than the
    # data's precision, and the misfit shows in its chi2.
    assert centre_fit.values[k] - GOLD.alpha > 10 * mean_fit.std_errors[k]
    assert centre_fit.reduced_chi2 > 5
    # fit_with_angular predicts the mean by default; its first-order variance only widens the errors.
    default, _ = fit_with_angular(spec, s, starts=1)
    assert abs(default.values[k] - GOLD.alpha) < min(3 * default.std_errors[k], centre_fit.values[k] - GOLD.alpha)


def test_without_covariance_a_fit_is_the_old_one_exactly() -> None:
    wi, wo = _across_the_lobe(40)
    rng = np.random.default_rng(9)
    value = np.asarray(GOLD.eval(wi, wo)) * (1.0 + 0.01 * rng.normal(size=(40, 3)))
    zero = Samples(wi, wo, value, 0.01 * value, direction_cov=np.zeros((40, 4, 4)))
    none = Samples(wi, wo, value, 0.01 * value)
    spec = ggx_conductor()
    new = fit(spec, zero, footprint=True, starts=1, warn=False)
    old = fit(spec, none, starts=1, warn=False)
    np.testing.assert_array_equal(new.values, old.values)
    np.testing.assert_array_equal(new.residuals, old.residuals)
    averaged, _ = fit_with_angular(spec, zero, starts=1)
    centred, _ = fit_with_angular(spec, zero, starts=1, footprint=False)
    np.testing.assert_array_equal(averaged.values, centred.values)
    np.testing.assert_array_equal(footprint_average(GOLD, wi, wo, zero.direction_cov), GOLD.eval(wi, wo))
    assert sigma_points(wi, wo, zero.direction_cov).count == 0


def test_a_sigma_point_beyond_the_horizon_drops_its_axis_and_nothing_turns_nan() -> None:
    # wo at 85 deg with a wide spread along its radial (zenith) direction: that axis would cross the horizon.
    wi = degrees_to_vector(np.array([30.0, 30.0]), np.zeros(2))
    wo = degrees_to_vector(np.array([85.0, 30.0]), np.array([180.0, 180.0]))
    cov = np.zeros((2, 4, 4))
    cov[:, 2, 2] = np.radians(4.0) ** 2  # wo_x: radial for phi_o = 180 deg
    cov[:, 3, 3] = np.radians(0.5) ** 2  # wo_y: along the horizon, stays above it
    sp = sigma_points(wi, wo, cov)
    assert sp.count == 2
    # The grazing row keeps only its wo_y axis; the other both.
    np.testing.assert_allclose(sp.centre_weight, [1 - 1 / 3, 1 - 2 / 3])
    assert np.count_nonzero(sp.weight[0]) == 2 and np.count_nonzero(sp.weight[1]) == 4
    assert np.all(sp.wo[..., 2] > 0) and sp.wo.shape == (2, 2 * MAX_AXES, 3)
    for model in (GOLD, m.CookTorrance(alpha=1e-3, eta=(0.18, 0.42, 1.37), k=(3.42, 2.35, 1.77))):
        mean = footprint_average(model, wi, wo, cov)
        assert np.all(np.isfinite(mean)) and np.all(mean >= 0)


def test_a_near_mirror_lobe_is_averaged_without_nan_and_never_negative() -> None:
    # alpha 0.001: the lobe is far narrower than the footprint, so the sigma points see only its tails.
    mirror = m.CookTorrance(alpha=1e-3, eta=(0.18, 0.42, 1.37), k=(3.42, 2.35, 1.77))
    wi, wo = _across_the_lobe(41)
    cov = _tile_cov(41, np.radians(0.5), np.random.default_rng(3))
    mean = footprint_average(mirror, wi, wo, cov)
    assert np.all(np.isfinite(mean)) and np.all(mean >= 0)
