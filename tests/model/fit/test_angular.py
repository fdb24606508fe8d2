"""Angular uncertainty in a fit (model/fit/angular.py): the gradient, the effective variance, the iteration."""

from __future__ import annotations

import numpy as np
import pytest

import model as m
from model.fit.angular import angular_share, angular_variance, fit_with_angular, gradient, with_angular
from model.fit.samples import FitError, Samples
from model.fit.spec import ggx_conductor
from model.geometry import degrees_to_vector

GOLD = m.CookTorrance(alpha=0.08, eta=(0.18, 0.42, 1.37), k=(3.42, 2.35, 1.77))


def _in_plane(theta_o: np.ndarray, cov_rad2: float, model: m.Model = GOLD, rel: float = 0.01) -> Samples:
    wi = degrees_to_vector(np.full(len(theta_o), 30.0), np.zeros(len(theta_o)))
    wo = degrees_to_vector(np.abs(theta_o), np.where(theta_o < 0, 0.0, 180.0))
    f = np.asarray(model.eval(wi, wo))
    cov = np.broadcast_to(np.eye(4) * cov_rad2, (len(theta_o), 4, 4)).copy()
    return Samples(wi, wo, f, rel * f, direction_cov=cov)


def test_the_gradient_is_the_models_slope_along_the_tangent_components() -> None:
    s = _in_plane(np.linspace(-60, 60, 13), 1e-8)
    g = gradient(GOLD, s)
    assert g.shape == (13, 3, 4)
    # Moving wo_x by h moves the value by g h: checked against a direct evaluation with a larger step.
    h = 1e-4
    wo = s.wo.copy()
    wo[:, 0] += h
    wo[:, 2] = np.sqrt(1 - wo[:, 0] ** 2 - wo[:, 1] ** 2)
    direct = (np.asarray(GOLD.eval(s.wi, wo)) - s.value) / h
    np.testing.assert_allclose(g[..., 2], direct, rtol=2e-2, atol=1e-6)
    flat = gradient(m.Lambert(0.5), _in_plane(np.linspace(-60, 60, 13), 1e-8, m.Lambert(0.5)))
    np.testing.assert_allclose(flat, 0.0, atol=1e-6)


def test_the_angular_term_is_large_on_a_lobes_flank_and_nil_at_its_peak_and_on_a_matte_sample() -> None:
    theta_o = np.array([30.0, 36.0, 50.0])  # the mirror, the flank, the tail
    s = _in_plane(theta_o, np.radians(0.05) ** 2)
    share = angular_share(s.std_error, angular_variance(GOLD, s))[:, 1]
    assert share[0] < 0.05 and share[1] > 0.5 and share[2] < share[1]
    matte = _in_plane(theta_o, np.radians(0.05) ** 2, m.Lambert(0.5))
    assert np.all(angular_variance(m.Lambert(0.5), matte) < 1e-12)
    assert angular_variance(GOLD, Samples(s.wi, s.wo, s.value, s.std_error)).max() == 0.0  # no covariance


def test_fitting_with_angular_errors_widens_the_flanks_and_keeps_the_answer() -> None:
    rng = np.random.default_rng(3)
    theta_o = np.linspace(-70, 70, 57)
    clean = _in_plane(theta_o, np.radians(0.1) ** 2)
    # Jitter the measured directions by their covariance, as a real rig's would be.
    jitter = rng.normal(0, np.radians(0.1), (clean.n, 2))
    wo = clean.wo.copy()
    wo[:, :2] += jitter
    wo[:, 2] = np.sqrt(1 - np.sum(wo[:, :2] ** 2, axis=1))
    value = np.asarray(GOLD.eval(clean.wi, wo)) * (1 + rng.normal(0, 0.01, clean.value.shape))
    noisy = Samples(clean.wi, clean.wo, value, 0.01 * value, direction_cov=clean.direction_cov)
    spec = ggx_conductor()
    result, variance = fit_with_angular(spec, noisy)
    plain, _ = fit_with_angular(spec, Samples(noisy.wi, noisy.wo, noisy.value, noisy.std_error))
    assert variance.max() > 0 and np.argmax(variance[:, 1]) not in (0, clean.n - 1)
    assert result.reduced_chi2 < plain.reduced_chi2  # the jitter is explained by the errors, not by the model
    assert abs(result.model.alpha - 0.08) < 4 * result.std_errors[result.names.index("alpha")]
    widened = with_angular(noisy, noisy.std_error, variance)
    assert np.all(widened.std_error >= noisy.std_error)


def test_a_bad_direction_covariance_is_named() -> None:
    s = _in_plane(np.linspace(-10, 10, 3), 1e-8)
    with pytest.raises(FitError, match=r"direction_cov must have shape \(3, 4, 4\)"):
        Samples(s.wi, s.wo, s.value, s.std_error, direction_cov=np.zeros((2, 4, 4)))
    bad = s.direction_cov.copy()
    bad[1, 0, 0] = np.nan
    with pytest.raises(FitError, match="sample 1: direction_cov is not finite"):
        Samples(s.wi, s.wo, s.value, s.std_error, direction_cov=bad)
    rows = [{"theta_i_deg": 30, "phi_i_deg": 0, "theta_o_deg": 20, "phi_o_deg": 180, "brdf_r": 1, "brdf_se_r": 0.1,
             "direction_cov": "[[1, 2]]"}]  # fmt: skip
    with pytest.raises(FitError, match="direction_cov: expected a 4 x 4 matrix per row"):
        Samples.from_table_rows(rows)
