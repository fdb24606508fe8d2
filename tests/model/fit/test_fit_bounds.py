"""Saturated samples as one-sided constraints (model.fit, lower_bounds="constrain") against excluding them."""

import numpy as np
import pytest

from model import CookTorrance, Lambert
from model.base import Model
from model.fit.solve import LAMBERT, FitError, Samples, fit, lambert_ggx
from model.geometry import degrees_to_vector
from tests.model.fit.test_fit import Array, noisy

# A narrow GGX peak (Schlick f0) over a Lambertian base, measured by in-plane sweeps in 5 degree steps at
# near-normal incidence. Off the mirror direction the samples see only the lobe's tail, which fixes about
# alpha^2 f0 but hardly alpha and f0 apart; the peak itself, f0 / alpha^2, is seen only at the three mirror
# samples, and those saturate: the camera clips them at a ceiling 20 % below the lowest true peak.
GLOSSY = CookTorrance(alpha=0.02, fresnel="schlick", f0=0.04, rho_d=(0.2, 0.3, 0.4))
THETA_I = np.array([5.0, 15.0, 25.0])
REL = 0.05


def _sweep() -> tuple[Array, Array]:
    ti, to = np.meshgrid(THETA_I, np.arange(-85.0, 86.0, 5.0), indexing="ij")
    wi = degrees_to_vector(ti.ravel(), 0.0)
    wo = degrees_to_vector(np.abs(to.ravel()), np.where(to.ravel() < 0, 180.0, 0.0))
    return wi, wo


def _peaks(model: Model) -> Array:
    """The model's green value at the three mirror directions, 1/sr."""
    return model.eval(degrees_to_vector(THETA_I, 0.0), degrees_to_vector(THETA_I, 180.0))[:, 1]


def _clipped(seed: int) -> tuple[Samples, float]:
    """Noisy samples of GLOSSY, flagged and clipped where the reading reaches the ceiling (as a camera does)."""
    wi, wo = _sweep()
    f: Array = GLOSSY.eval(wi, wo)
    se = REL * f + 0.002
    reading = f + np.random.default_rng(seed).normal(size=f.shape) * se
    cap = 0.8 * _peaks(GLOSSY).min()
    lower = reading.max(axis=1) >= cap
    return Samples(wi, wo, np.minimum(reading, cap), se, lower), cap


def test_a_clipped_peak_is_recovered_with_constraints_where_exclusion_loses_it() -> None:
    spec = lambert_ggx("schlick")
    true = np.array([GLOSSY.alpha, GLOSSY.f0])
    z: dict[str, list[Array]] = {"constrain": [], "exclude": []}
    lost = 0
    for seed in range(12):
        samples, cap = _clipped(seed)
        assert samples.lower_bound.sum() == 3  # the three mirror samples, nothing else
        kept = fit(spec, samples, warn=False)
        dropped = fit(spec, samples, lower_bounds="exclude", warn=False)
        for mode, res in (("constrain", kept), ("exclude", dropped)):
            z[mode].append((res.values[3:] - true) / res.std_errors[3:])
        # With the bounds: alpha and f0 within their uncertainties, and the peak at least at the ceiling
        # (within the bounds' noise), every time.
        assert np.all(np.abs(z["constrain"][-1]) < 3.0), kept.summary()
        assert _peaks(kept.model).min() > cap * (1.0 - 2.0 * REL)
        assert not any("below" in w for w in kept.warnings)
        if any("below" in w and "lower bounds" in w for w in dropped.warnings):
            # Exclusion lost the peak height (more than 2 std errors under the ceiling) and says so; the
            # constrained fit is closer to the truth on both counts.
            lost += 1
            assert _peaks(dropped.model).min() < cap * (1.0 - 2.0 * REL)
            assert np.all(np.abs(kept.values[3:] - true) < np.abs(dropped.values[3:] - true))
    assert lost >= 2, "the construction should make exclusion lose the peak for some seeds"
    rms = {k: np.sqrt(np.mean(np.square(v), axis=0)) for k, v in z.items()}
    assert np.all(rms["constrain"] < rms["exclude"]), rms


def _joined(a: Samples, b: Samples) -> Samples:
    cat = [np.concatenate([getattr(a, k), getattr(b, k)]) for k in ("wi", "wo", "value", "std_error", "lower_bound")]
    return Samples(cat[0], cat[1], cat[2], cat[3], cat[4])


def test_bounds_the_model_clears_change_nothing() -> None:
    samples, f = noisy(Lambert(rho_d=(0.2, 0.3, 0.4)), n=300, seed=1)
    low = Samples(samples.wi[:40], samples.wo[:40], 0.2 * f[:40], samples.std_error[:40], np.ones(40, dtype=bool))
    both = _joined(samples, low)
    plain, bounded = fit(LAMBERT, samples), fit(LAMBERT, both)
    assert bounded.n_bounds == 40 and bounded.bound_chi2 == 0.0
    assert np.allclose(bounded.values, plain.values, rtol=1e-9) and bounded.chi2 == pytest.approx(plain.chi2)


def test_a_bound_above_the_data_lifts_the_fit_and_a_missing_value_is_no_bound() -> None:
    samples, _ = noisy(Lambert(rho_d=(0.2, 0.3, 0.4)), n=200, seed=2)
    n_b = 50
    value = np.tile([0.5 / np.pi] * 3, (n_b, 1))
    value[0] = np.nan  # a saturated reading that could not be calibrated
    se = np.full((n_b, 3), 0.002)
    se[1] = 0.0  # one without a noise estimate of its own: borrows the samples' relative error
    high = Samples(samples.wi[:n_b], samples.wo[:n_b], value, se, np.ones(n_b, dtype=bool))
    both = _joined(samples, high)
    plain = fit(LAMBERT, samples)
    with pytest.warns(Warning) as caught:
        lifted = fit(LAMBERT, both)
    messages = " ".join(str(w.message) for w in caught)
    assert "1 saturated samples without a finite value" in messages and "below" in messages
    assert lifted.n_bounds == n_b - 1 and np.all(np.isfinite(lifted.values))
    assert np.all(lifted.values > plain.values + 5.0 * plain.std_errors)
    assert np.all(lifted.values < 0.5)  # a compromise: the data still pull it down


def test_an_unknown_lower_bounds_mode_is_refused() -> None:
    samples, _ = noisy(Lambert(), n=20)
    with pytest.raises(FitError, match="lower_bounds 'ignore'"):
        fit(LAMBERT, samples, lower_bounds="ignore")
