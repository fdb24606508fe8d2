import csv
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from model import BlinnPhong, CookTorrance, Lambert, ParameterError, Ward
from model.base import Model
from model.fit.solve import (
    LAMBERT,
    FitError,
    FitSpec,
    FitWarning,
    Samples,
    blinn_phong,
    fit,
    ggx_conductor,
    lambert_ggx,
    ward_anisotropic,
)
from model.merl import MerlTable

Array = npt.NDArray[Any]

PLASTIC = CookTorrance(alpha=0.15, fresnel="dielectric", eta=1.5, rho_d=(0.2, 0.3, 0.4))
CASES = [
    (LAMBERT, Lambert(rho_d=(0.2, 0.3, 0.4))),
    (lambert_ggx(), PLASTIC),
    (ggx_conductor(), CookTorrance(alpha=0.3, eta=(1.657, 0.880, 0.521), k=(9.224, 6.270, 4.837))),
    (blinn_phong(), BlinnPhong(rho_d=(0.2, 0.3, 0.4), rho_s=0.3, n=80.0)),
    (ward_anisotropic(), Ward(rho_d=(0.2, 0.3, 0.4), rho_s=0.3, alpha_x=0.1, alpha_y=0.25, variant="balanced")),
]


def hemisphere(rng: np.random.Generator, n: int) -> Array:
    z = rng.random(n)
    r = np.sqrt(1.0 - z * z)
    phi = 2.0 * np.pi * rng.random(n)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def noisy(
    model: Model, n: int = 300, seed: int = 0, rel: float = 0.02, floor: float = 0.002,
    wi: Array | None = None, wo: Array | None = None,
) -> tuple[Samples, Array]:
    """Samples of the model plus Gaussian noise with known std errors (relative plus a floor)."""
    rng = np.random.default_rng(seed)
    wi = hemisphere(rng, n) if wi is None else wi
    wo = hemisphere(rng, n) if wo is None else wo
    f: Array = model.eval(wi, wo).reshape(len(wi), -1)
    se = rel * f + floor
    return Samples(wi, wo, f + rng.normal(size=f.shape) * se, se), f


def noisy_in_plane(model: Model, n: int, seed: int) -> tuple[Samples, Array]:
    """``noisy`` samples whose directions all lie in the x-z plane: incidence 0 to 80 deg, outgoing -80 to 80."""
    rng = np.random.default_rng(seed)
    ti, to = rng.uniform(0, 80, n), rng.uniform(-80, 80, n)
    wi = np.stack([np.sin(np.radians(ti)), 0 * ti, np.cos(np.radians(ti))], axis=-1)
    wo = np.stack([np.sin(np.radians(to)), 0 * to, np.cos(np.radians(to))], axis=-1)
    return noisy(model, wi=wi, wo=wo, seed=seed)


def saturated_plastic() -> tuple[Samples, Array]:
    """600 noisy samples of PLASTIC whose brightest tenth is clipped at the 90th percentile and marked as lower
    bounds, and the mask of those."""
    samples, f = noisy(PLASTIC, n=600, seed=6)
    cap = np.quantile(f.max(axis=1), 0.9)
    lower = f.max(axis=1) > cap
    return Samples(samples.wi, samples.wo, np.minimum(samples.value, cap), samples.std_error, lower), lower


def truth(spec: FitSpec, model: Model) -> Array:
    return np.concatenate([np.broadcast_to(np.atleast_1d(getattr(model, p.name)), (3 if p.per_channel else 1,))
                           for p in spec.params])  # fmt: skip


@pytest.mark.parametrize(("spec", "model"), CASES, ids=[c[0].name for c in CASES])
def test_recovers_known_parameters_within_the_reported_uncertainties(spec: FitSpec, model: Model) -> None:
    samples, _ = noisy(model, n=400, seed=1)
    with np.errstate(all="raise"):
        res = fit(spec, samples, seed=1)
    z = (res.values - truth(spec, model)) / res.std_errors
    assert np.all(np.abs(z) < 3.5), res.summary()
    assert res.noise_reached and not res.warnings
    assert res.model.eval(samples.wi[:1], samples.wo[:1]).shape == (1, 3)


def test_reported_uncertainties_cover_the_truth_over_seeds() -> None:
    spec = lambert_ggx()
    scores = []
    for seed in range(8):
        res = fit(spec, noisy(PLASTIC, seed=seed)[0], seed=seed)
        scores.append((res.values - truth(spec, PLASTIC)) / res.std_errors)
    z = np.array(scores)
    # 40 z-scores of a N(0, 1): rms near 1, about 95 % inside 2 sigma, none beyond 4.
    assert 0.6 < np.sqrt(np.mean(z**2)) < 1.5
    assert np.mean(np.abs(z) < 2.0) >= 0.85
    assert np.abs(z).max() < 4.0


@pytest.mark.parametrize("loss", ["l2", "cosine_l2", "log", "cbrt"])
def test_every_loss_recovers_the_parameters(loss: str) -> None:
    samples, _ = noisy(PLASTIC, n=400, seed=2)
    res = fit(lambert_ggx(), samples, loss=loss)
    assert np.all(np.abs(res.values - truth(lambert_ggx(), PLASTIC)) < 4.0 * res.std_errors), res.summary()
    assert res.loss == loss and res.chi2 > 0


def test_robust_loss_resists_outliers() -> None:
    samples, _ = noisy(PLASTIC, n=400, seed=3)
    value = samples.value.copy()
    value[::20] *= 3.0  # 5 % gross outliers
    bad = Samples(samples.wi, samples.wo, value, samples.std_error)
    plain = fit(lambert_ggx(), bad, warn=False)
    robust = fit(lambert_ggx(), bad, robust="soft_l1", warn=False)
    err = lambda r: np.abs(r.values - truth(lambert_ggx(), PLASTIC)) / truth(lambert_ggx(), PLASTIC)  # noqa: E731
    assert not plain.noise_reached
    assert err(robust).max() < 0.02 < err(plain).max()


def test_more_samples_shrink_the_uncertainty_like_one_over_root_n() -> None:
    small = fit(lambert_ggx(), noisy(PLASTIC, n=250, seed=4)[0])
    large = fit(lambert_ggx(), noisy(PLASTIC, n=4000, seed=4)[0])
    assert np.allclose(small.std_errors / large.std_errors, 4.0, rtol=0.35)


def test_too_few_points_is_an_error_naming_the_counts() -> None:
    samples, _ = noisy(PLASTIC, n=2)
    with pytest.raises(FitError, match=r"2 usable samples.*5 parameters \(3 per channel: rho_d, alpha, eta\)"):
        fit(lambert_ggx(), samples)


def test_points_in_one_plane_warn_for_isotropic_and_fail_for_anisotropic_models() -> None:
    samples, _ = noisy_in_plane(PLASTIC, n=300, seed=5)
    with pytest.warns(FitWarning, match="one plane"):
        res = fit(lambert_ggx(), samples)
    assert any("one plane" in w for w in res.warnings)
    with pytest.raises(FitError, match=r"one plane.*alpha_x, alpha_y"):
        fit(ward_anisotropic(), samples)


@pytest.mark.parametrize("bad", [0.0, -1e-3, np.nan])
def test_zero_or_negative_std_error_is_an_error_naming_the_sample(bad: float) -> None:
    samples, _ = noisy(PLASTIC, n=10)
    se = samples.std_error.copy()
    se[3, 1] = bad
    with pytest.raises(FitError, match=r"sample 3: std_error .* channel 1 must be positive"):
        Samples(samples.wi, samples.wo, samples.value, se)


@pytest.mark.filterwarnings("ignore::model.fit.solve.FitWarning")
def test_saturated_samples_are_excluded_with_a_warning_on_request() -> None:
    sat, lower = saturated_plastic()
    with pytest.warns(FitWarning, match=f"{lower.sum()} saturated"):
        res = fit(lambert_ggx(), sat, lower_bounds="exclude")
    assert res.n_samples == 600 - lower.sum() and res.n_excluded == lower.sum() and res.n_bounds == 0
    assert np.all(np.abs(res.values - truth(lambert_ggx(), PLASTIC)) < 4.0 * res.std_errors)
    # A model that cannot reach the saturated peak says so instead of ignoring it.
    with pytest.warns(FitWarning, match="below .* saturated lower bounds"):
        fit(LAMBERT, sat, lower_bounds="exclude")


@pytest.mark.filterwarnings("ignore::model.fit.solve.FitWarning")
def test_saturated_samples_are_lower_bounds_by_default() -> None:
    sat, lower = saturated_plastic()
    res = fit(lambert_ggx(), sat)
    assert res.n_samples == 600 - lower.sum() and res.n_bounds == lower.sum() and res.n_excluded == 0
    # chi2 and dof count the ordinary samples only.
    assert res.residuals.shape == (600 - lower.sum(), 3) and res.dof == 3 * (600 - lower.sum()) - 5
    assert np.all(np.abs(res.values - truth(lambert_ggx(), PLASTIC)) < 4.0 * res.std_errors)
    assert res.bound_chi2 < 4.0 * lower.sum() and "lower bounds" in res.summary()
    # Even constrained, a model that cannot reach the peak lies below it, and says so.
    with pytest.warns(FitWarning, match="below .* saturated lower bounds.*even as constraints"):
        flat = fit(LAMBERT, sat)
    assert flat.bound_chi2 > 100.0


def test_misfit_inflates_the_uncertainties_and_says_so() -> None:
    samples, _ = noisy(PLASTIC, n=300, seed=7)
    with pytest.warns(FitWarning, match="residuals exceed the noise"):
        res = fit(LAMBERT, samples)
    assert res.reduced_chi2 > 10 and not res.noise_reached


def test_unconstrained_parameters_are_flagged_not_reported_confidently() -> None:
    # Only normal-incidence, normal-exitance samples: alpha and eta trade off against rho_d.
    n = 50
    z = np.tile([0.0, 0.0, 1.0], (n, 1))
    samples = Samples(z, z, np.full((n, 3), 0.3), np.full((n, 3), 0.003))
    with pytest.warns(FitWarning):
        res = fit(lambert_ggx(), samples, starts=1)
    flagged = [name for name, e in zip(res.names, res.std_errors, strict=True) if not np.isfinite(e)]
    assert {"alpha", "eta"} <= set(flagged)
    assert any("do not constrain" in w for w in res.warnings)


def test_spec_channel_options() -> None:
    spec = lambert_ggx().shared("rho_d").per_channel("eta")
    assert spec.labels(3) == ["rho_d", "alpha", "eta_r", "eta_g", "eta_b"]
    with pytest.raises(ParameterError, match="one value for all channels"):
        lambert_ggx().per_channel("alpha")
    with pytest.raises(ParameterError, match="no fitted parameter"):
        lambert_ggx().shared("nope")


def test_table_rows_and_csv_convert_degrees_and_the_cosine(tmp_path: Path) -> None:
    model = Lambert(rho_d=(0.2, 0.3, 0.4))
    rows: list[dict[str, Any]] = []
    for i, (ti, to, po) in enumerate([(10, 20, 180), (30, 40, 90), (50, 60, 0), (20, 70, 45), (0, 30, 120)]):
        f = np.array([0.2, 0.3, 0.4]) / np.pi * (np.cos(np.radians(ti)) if i == 1 else 1.0)
        rows.append({"theta_i_deg": ti, "phi_i_deg": 0.0, "theta_o_deg": to, "phi_o_deg": po, "includes_cosine": i == 1,
                     "lower_bound": False, **{f"brdf_{c}": v for c, v in zip("rgb", f, strict=True)},
                     **{f"brdf_se_{c}": 0.01 for c in "rgb"}})  # fmt: skip
    rows.append({**rows[0], "brdf_r": None, "brdf_g": None, "brdf_b": None})
    rows.append({**rows[0], "theta_o_deg": 95.0})
    path = tmp_path / "samples.csv"
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows({k: ("" if v is None else str(v).lower() if isinstance(v, bool) else v) for k, v in r.items()}
                    for r in rows)  # fmt: skip
    for s in (Samples.from_table_rows(rows), Samples.from_csv(path)):
        assert s.n == 5 and s.channels == 3
        assert np.allclose(s.value, model.eval(s.wi, s.wo))
        assert any("without a BRDF value" in note for note in s.notes)
        assert any("below the horizon" in note for note in s.notes)


def test_point_errors_leave_out_the_calibration_share() -> None:
    # A run's table: brdf_se holds the point's reading, the references' and the albedo's errors;
    # errors="point" keeps the point's own relative reading error only.
    row: dict[str, Any] = {"theta_i_deg": 20.0, "phi_i_deg": 0.0, "theta_o_deg": 30.0, "phi_o_deg": 180.0,
                           "lower_bound": False, "reading_se_r": 2.0, "reading_se_g": 6.0, "reading_se_b": 20.0}
    for c in "rgb":
        row |= {f"brdf_{c}": 0.1, f"brdf_se_{c}": 0.0007, f"reading_{c}": 2000.0}
    total, point = Samples.from_table_rows([row]), Samples.from_table_rows([row], errors="point")
    assert np.allclose(total.std_error, 0.0007)
    assert np.allclose(point.std_error, [[1e-4, 3e-4, 1e-3]])
    dark = {**row, "brdf_b": 0.0, "reading_b": 0.0, "brdf_se_b": 0.0004}  # nothing read in blue: se is its own
    assert np.allclose(Samples.from_table_rows([dark], errors="point").std_error, [[1e-4, 3e-4, 4e-4]])
    with pytest.raises(FitError, match="reading_se_r"):
        Samples.from_table_rows([{k: v for k, v in row.items() if k != "reading_se_r"}], "t.csv", errors="point")
    with pytest.raises(FitError, match="'total', 'point' or 'readings'"):
        Samples.from_table_rows([row], errors="reading")
    with pytest.raises(FitError, match=r"'readings' needs the columns \['brdf_se_readings_r'"):
        Samples.from_table_rows([row], errors="readings")


def test_from_merl_subsamples_a_table_and_recovers_its_model() -> None:
    table = MerlTable.from_model(PLASTIC)
    s = Samples.from_merl(table, 2000, seed=0, relative_error=0.05)
    assert s.n == 2000 and s.std_error_assumed and np.all(s.wi[:, 2] > 0)
    res = fit(lambert_ggx(), s, warn=False)
    assert np.allclose(res.values, truth(lambert_ggx(), PLASTIC), rtol=1e-3)
    assert "assumed" in res.summary()


def test_summary_names_every_parameter_and_the_goodness_of_fit() -> None:
    res = fit(lambert_ggx(), noisy(PLASTIC, seed=8)[0])
    text = res.summary()
    assert all(name in text for name in res.names) and "chi2" in text and "dof" in text
    assert res.param("alpha")[1] == res.std_errors[res.names.index("alpha")]
