"""Fitting very many samples: every bin of a MERL table, the staged solve and its projected residuals."""

from typing import Any

import numpy as np
import pytest

from model.fit import problem as fit_problem
from model.fit.solve import Samples, fit, lambert_ggx
from model.merl import N_THETA_H, MerlTable
from tests.model.fit.test_fit import CASES, PLASTIC, Array, noisy, truth
from tests.model.fit.test_fit_bounds import _clipped


@pytest.fixture(scope="module")
def plastic_table() -> MerlTable:
    return MerlTable.from_model(PLASTIC)


@pytest.fixture(scope="module")
def every_bin(plastic_table: MerlTable) -> Samples:
    return Samples.from_merl(plastic_table, None)


def _theta_h(s: Samples) -> Array:
    h = s.wi + s.wo
    return np.arccos(h[:, 2] / np.linalg.norm(h, axis=1))


def test_every_bin_with_data_above_the_horizon_is_one_sample(plastic_table: MerlTable, every_bin: Samples) -> None:
    s = every_bin
    # 90 x 90 x 180 bins, of which those whose centre has both directions above the horizon.
    assert s.n == 1_096_216 and s.channels == 3 and s.std_error_assumed
    assert np.all(s.wi[:, 2] > 0) and np.all(s.wo[:, 2] > 0)
    assert np.allclose(s.wi[:, 1] + s.wo[:, 1], 0.0, atol=1e-12)  # phi_h = 0: h in the xz plane
    rows = np.random.default_rng(0).choice(s.n, 5000, replace=False)
    assert np.array_equal(s.value[rows], plastic_table.eval(s.wi[rows], s.wo[rows]))  # each bin's own value
    # Bins without data are left out: keep the first 10 theta_h rows of the table only.
    edge = (10 / N_THETA_H) ** 2 * np.pi / 2
    part = plastic_table.values.copy()
    part[:, 10:] = np.nan
    sub = Samples.from_merl(MerlTable(part), None)
    assert sub.n == int(np.sum(_theta_h(s) < edge)) > 0 and np.all(np.isfinite(sub.value))
    with pytest.raises(Exception, match="n >= 1"):
        Samples.from_merl(plastic_table, 0)


def test_a_large_noise_free_table_gives_back_its_model(every_bin: Samples, monkeypatch: pytest.MonkeyPatch) -> None:
    # Every fourth bin (274,054 RGB samples, 822,162 residuals): the compiled kernel, the staged solve and
    # the projected residuals all take part, as for the whole table (bench/fit.py times that).
    calls = []
    tall = fit_problem.solve_tall

    def counted(*args: Any) -> Any:
        calls.append(args)
        return tall(*args)

    monkeypatch.setattr(fit_problem, "solve_tall", counted)
    s = every_bin.subset(np.arange(0, every_bin.n, 4))
    assert s.n * s.channels >= fit_problem.TALL_RESIDUALS and s.n >= fit_problem.COMPILED_ROWS
    res = fit(lambert_ggx(), s, warn=False)
    assert calls and fit_problem.stage_sizes(s.n, 4) == [2000, 40_000, s.n]
    assert np.allclose(res.values, truth(lambert_ggx(), PLASTIC), rtol=1e-6, atol=0)
    assert res.chi2 < 1e-12 and res.n_samples == s.n


@pytest.mark.parametrize(
    ("case", "loss", "robust"),
    [(1, "l2", None), (1, "l2", "soft_l1"), (4, "log", None), (3, "cbrt", "cauchy"), (4, "cosine_l2", "huber")],
)
def test_projected_residuals_reach_the_same_optimum(
    case: int, loss: str, robust: str | None, monkeypatch: pytest.MonkeyPatch
) -> None:
    spec, model = CASES[case]
    samples, _ = noisy(model, n=400, seed=3)
    plain = fit(spec, samples, loss, robust, warn=False)
    monkeypatch.setattr(fit_problem, "TALL_RESIDUALS", 0)  # every solve, from every start, projected
    projected = fit(spec, samples, loss, robust, warn=False)
    assert np.all(np.abs(projected.values - plain.values) < 0.01 * plain.std_errors)
    assert projected.loss_value == pytest.approx(plain.loss_value, rel=1e-7)


def test_projected_residuals_keep_the_lower_bounds(monkeypatch: pytest.MonkeyPatch) -> None:
    samples, _ = _clipped(0)
    plain = fit(lambert_ggx("schlick"), samples, warn=False)
    monkeypatch.setattr(fit_problem, "TALL_RESIDUALS", 0)
    projected = fit(lambert_ggx("schlick"), samples, warn=False)
    assert np.all(np.abs(projected.values - plain.values) < 0.01 * plain.std_errors)
    assert projected.bound_chi2 == pytest.approx(plain.bound_chi2, rel=1e-3, abs=1e-6)


def test_stages_grow_from_the_screen_to_all_rows() -> None:
    assert fit_problem.stage_sizes(1500, 4) == [1500]
    assert fit_problem.stage_sizes(10_000, 4) == [2000, 10_000]
    assert fit_problem.stage_sizes(10_000, 1) == [10_000]
    assert fit_problem.stage_sizes(1_096_216, 1) == [2000, 40_000, 1_096_216]
    assert fit_problem.stage_sizes(5_000_000, 4) == [2000, 40_000, 800_000, 5_000_000]


def test_a_table_without_data_is_an_error() -> None:
    with pytest.raises(Exception, match="no bins with data"):
        Samples.from_merl(MerlTable(np.full((3, 90, 90, 180), np.nan)), None)


def test_a_fit_through_the_kernel_matches_numpy(monkeypatch: pytest.MonkeyPatch) -> None:
    samples, _ = noisy(PLASTIC, n=5000, seed=4)  # above the kernel's smallest batch (4096 pairs)
    numpy_path = fit(lambert_ggx(), samples, starts=1, warn=False)
    monkeypatch.setattr(fit_problem, "COMPILED_ROWS", 0)
    kernel_path = fit(lambert_ggx(), samples, starts=1, warn=False)
    assert np.array_equal(kernel_path.values, numpy_path.values)  # the kernel repeats numpy bit for bit
