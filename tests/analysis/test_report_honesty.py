"""The report says what the data pin down: bounds as bounds, undetermined parameters and why, p-values and the
noise in agreement, every warning once, a selection table that fits a narrow page, SVGs only on request."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest

from analysis.analyze import fit_json, write_report
from analysis.ladder import fit_ladder
from analysis.parameters import correlation, parameter_status
from analysis.report.html import page_warnings, render_html
from analysis.report.plots import write_figures
from analysis.result import Analysis, Reference, SourceSummary, noise_words
from model import CookTorrance
from model.fit.samples import Samples
from model.fit.solve import fit
from model.fit.spec import ggx_conductor, lambert_ggx
from model.geometry import degrees_to_vector

GOLD = CookTorrance(alpha=0.3, eta=(0.18, 0.42, 1.37), k=(3.42, 2.35, 1.77))
#: A plastic without a blue diffuse term: rho_d_b belongs at its lower bound, 0.
NO_BLUE = CookTorrance(alpha=0.2, fresnel="dielectric", eta=1.5, rho_d=(0.3, 0.2, 0.0))


def in_plane(brdf: CookTorrance, rel_error: float = 0.01, seed: int | None = 0) -> Samples:
    """Samples of ``brdf`` on two in-plane slices (theta_i 20 and 50 deg), with 1 % errors (noise if seeded)."""
    to = np.array([-70.0, -50.0, -30.0, -10.0, 0.0, 10.0, 30.0, 50.0, 70.0])
    wi = np.concatenate([np.repeat(degrees_to_vector(t, 0.0)[None], len(to), axis=0) for t in (20.0, 50.0)])
    wo = np.concatenate([degrees_to_vector(np.abs(to), np.where(to > 0, 180.0, 0.0))] * 2)
    f = np.asarray(brdf.eval(wi, wo), dtype=np.float64)
    se = rel_error * f
    noisy = f if seed is None else f + se * np.random.default_rng(seed).standard_normal(f.shape)
    return Samples(wi, wo, noisy, se)


def analysis_of(samples: Samples, ladder: list, truth: CookTorrance | None = None) -> Analysis:
    selection, times, caught = fit_ladder(samples, ladder, starts=2)
    refs = (Reference("simulated material (truth)", truth),) if truth is not None else ()
    source = SourceSummary("run", Path("synthetic"), "finished", measured=samples.n, planned=samples.n)
    return Analysis(source, samples, tuple(ladder), selection, times, tuple(caught), refs, "l2", 2)


@pytest.fixture(scope="module")
def conductor() -> Analysis:
    """A GGX conductor fitted to in-plane gold: in one plane the red eta and k trade against each other."""
    return analysis_of(in_plane(GOLD), [ggx_conductor()], truth=GOLD)


def test_a_parameter_at_its_bound_prints_as_the_bound() -> None:
    s = in_plane(NO_BLUE, seed=None)
    spec = lambert_ggx("dielectric")
    r = fit(spec, s, starts=2, warn=False)
    status = {p.name: p for p in parameter_status(r, spec, s.channels)}
    blue = status["rho_d_b"]
    assert blue.bound == "lower" and r.values[r.names.index("rho_d_b")] < 1e-6
    assert blue.value_text() == "0 (at its lower bound)"
    assert "lower bound 0" in blue.note() and "e-" not in blue.value_text()
    # The others are free and printed as value +- std error.
    assert status["alpha"].bound is None and "±" in status["alpha"].value_text() and status["alpha"].determined


def test_an_undetermined_parameter_is_named_with_the_one_it_trades_against(conductor: Analysis) -> None:
    r = conductor.selection.chosen
    status = {p.name: p for p in parameter_status(r, conductor.spec(r.spec), 3)}
    eta_r = status["eta_r"]
    rho = correlation(r.covariance)[r.names.index("eta_r"), r.names.index("k_r")]
    assert abs(rho) > 0.9
    assert not eta_r.determined and "not pinned down by the data" in eta_r.note()
    assert eta_r.correlated[0][0] == "k_r" and "trades against k_r" in eta_r.note()
    assert status["alpha"].determined and status["alpha"].note() == ""
    # The same words on stdout and on the page.
    text = conductor.text()
    assert re.search(r"eta_r = [0-9.]+ ± [0-9.e+]+ +\[not pinned down by the data", text), text
    assert "not pinned down by the data: " in text.splitlines()[-1] and "eta_r" in text.splitlines()[-1]


def test_fit_json_holds_the_covariance_and_correlation(conductor: Analysis) -> None:
    doc = json.loads(json.dumps(fit_json(conductor), allow_nan=False))
    cand = doc["candidates"][0]
    names = cand["parameter_names"]
    assert names == list(cand["params"]) and names == doc["parameter_names"]
    cov, rho = np.array(cand["covariance"], dtype=float), np.array(cand["correlation"], dtype=float)
    assert cov.shape == rho.shape == (len(names), len(names))
    np.testing.assert_allclose(cov, cov.T, rtol=1e-8, atol=0)
    np.testing.assert_allclose(np.sqrt(np.diag(cov)), [cand["std_errors"][n] for n in names], rtol=1e-9)
    np.testing.assert_allclose(np.diag(rho), 1.0)
    assert np.all(np.abs(rho) <= 1.0)
    assert doc["covariance"] == cand["covariance"] and doc["correlation"] == cand["correlation"]
    assert cand["parameters"]["eta_r"]["determined"] is False and cand["parameters"]["alpha"]["determined"] is True
    assert cand["parameters"]["eta_r"]["correlated"]["k_r"] > 0.9


def test_fitted_and_true_parameters_and_the_brdf_error_are_in_fit_json(conductor: Analysis) -> None:
    truth = fit_json(conductor)["truth"]
    assert truth["truth"] == "CookTorrance"
    alpha = truth["params"]["alpha"]
    assert alpha["true"] == 0.3 and alpha["z"] == pytest.approx((alpha["fitted"] - 0.3) / alpha["std_error"])
    assert truth["params"]["k_b"]["true"] == 1.77
    # 1 % noise on the samples: the fit is within a few per cent of the truth where it was measured.
    assert 0 < truth["brdf_rel_l2_error_at_samples"] < 0.05
    assert truth["brdf_rel_l2_error_hemisphere"] > 0


def test_the_noise_words_agree_with_the_p_value(conductor: Analysis) -> None:
    r = conductor.selection.chosen
    # chi2 = 130 on 100 dof: within 3 sigma of 1 (the selection's test passes) but p = 0.02.
    marginal = dataclasses.replace(r, chi2=130.0, dof=100)
    assert marginal.noise_reached and 0.01 < marginal.p_value < 0.05
    assert noise_words(marginal).startswith("slightly above the noise (p = 0.02")
    assert noise_words(dataclasses.replace(r, chi2=100.0, dof=100)).startswith("at the noise (p = 0.4")
    assert noise_words(dataclasses.replace(r, chi2=300.0, dof=100)).startswith("above the noise")
    assert noise_words(dataclasses.replace(r, chi2=40.0, dof=100)).startswith("below the noise")


@pytest.fixture(scope="module")
def page(conductor: Analysis, tmp_path_factory: pytest.TempPathFactory) -> tuple[str, Path]:
    out = tmp_path_factory.mktemp("report")
    index = write_report(conductor, out)
    return index.read_text(), out


def test_the_page_explains_bounds_correlations_and_the_truth(page: tuple[str, Path]) -> None:
    html, _ = page
    assert "not pinned down by the data: eta_r, k_r" in html or "not pinned down by the data: eta_r" in html
    assert "trades against k_r" in html and '<table class="corr">' in html
    assert "Against the truth (simulated run)" in html and "(fitted − true) / σ" in html
    # "at noise: yes" never sits beside a p-value that says otherwise: the column is in words.
    assert ">yes<" not in html.split("Model selection")[1].split("</table>")[0]


def test_wide_tables_scroll_inside_a_narrow_page(page: tuple[str, Path]) -> None:
    html, _ = page
    selection = html.split("<h2>Model selection</h2>")[1]
    assert selection.lstrip().startswith('<div class="scroll"><table>')
    assert re.search(r"\.scroll \{[^}]*overflow-x: auto", html)


def test_svg_only_on_request(conductor: Analysis, page: tuple[str, Path], tmp_path: Path) -> None:
    html, out = page
    assert not list((out / "figures").glob("*.svg")) and ".svg" not in html
    figs = write_figures(conductor, tmp_path, svg=True)
    assert all(f.svg is not None and f.svg.read_text().lstrip().startswith("<?xml") for f in figs.files)
    assert '.svg"' in render_html(conductor, figs)


def test_every_warning_once() -> None:
    s = in_plane(NO_BLUE)
    a = analysis_of(s, [lambert_ggx("dielectric"), lambert_ggx("schlick")])
    shared = [w for w in a.warnings if "lie in one plane" in w]
    assert len(shared) == 2  # one per candidate in fit.json
    listed = page_warnings(a)
    assert sum("lie in one plane" in w for w in listed) == 1
    assert any(w.endswith("(lambert+ggx_dielectric and lambert+ggx_schlick)") for w in listed), listed
    assert len(listed) == len(set(listed))


def test_figures_show_progress_with_an_eta(conductor: Analysis, tmp_path: Path, capsys) -> None:
    write_figures(conductor, tmp_path, progress=True)
    err = capsys.readouterr().err
    assert "figures" in err and re.search(r"\d+/6 \[[0-9:]+<[0-9:?]+", err), err


def test_figures_drawn_side_by_side_are_the_same_bytes(conductor: Analysis, tmp_path: Path) -> None:
    from model.runtime import fork_safe

    one = write_figures(conductor, tmp_path / "one", jobs=1)
    two = write_figures(conductor, tmp_path / "two", jobs=2)
    assert [f.name for f in one.files] == [f.name for f in two.files]
    assert all(f.png.read_bytes() == g.png.read_bytes() for f, g in zip(one.files, two.files, strict=True))
    # A fork copies only the calling thread: with another one running, the figures are drawn here instead.
    import threading

    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        assert not fork_safe()
    finally:
        stop.set()
        other.join()


def test_the_note_that_replaces_the_parameter_panel_stays_inside_it() -> None:
    # A fit of another Fresnel kind than the truth's says why its parameters are not compared; the reason is
    # long, and wrapped at the figure's edge (matplotlib's wrap=True) it ran across the error map beside it.
    from analysis.report.truth import TruthComparison, truth_figure

    rng = np.random.default_rng(0)
    why = ("the truth differs in the fields the fit holds fixed: fresnel = 'conductor' (fit: 'schlick'), "
           "distribution = 'beckmann' (fit: 'ggx')")  # fmt: skip
    cmp = TruthComparison("CookTorrance", None, why, 0.01, 0.02, (rng.uniform(0, 80, 50), rng.uniform(0, 80, 50)),
                          rng.uniform(1e-3, 1e-1, 50))  # fmt: skip
    fig, _ = truth_figure(cmp)
    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
    left, right = fig.axes[0], fig.axes[1]
    (note,) = left.texts
    box, panel = note.get_window_extent(renderer), left.get_window_extent(renderer)
    assert "fresnel = 'conductor'" in note.get_text().replace("\n", " ")
    assert box.x0 >= panel.x0 and box.x1 <= panel.x1, (box, panel)
    assert box.x1 < right.get_tightbbox(renderer).x0, "the note runs into the error map"
