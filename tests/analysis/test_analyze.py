"""``gonio analyze`` on a real simulated run and on MERL files: the fit, the report, and clear errors on bad input.

One file past 400 lines on purpose: it mirrors one module, ``analysis.analyze``.
"""

from __future__ import annotations

import json
import re
import shutil
import struct
import subprocess
import sys
from html import escape
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from analysis.analyze import analyze, load_and_fit
from analysis.ladder import parse_models
from analysis.report.plots import angles_of, coverage, slices
from analysis.result import Analysis, AnalysisError
from gonio import cli
from model import CookTorrance
from model.base import Model
from model.fit.angular import fit_with_angular
from model.fit.select import Candidate, choose
from model.geometry import degrees_to_vector
from model.merl import MerlTable, write_merl
from model.serialize import from_json_dict
from rig.run.session import start_run
from tests.run_helpers import GOLD, in_plane_sweep, sim_rig

ROOT = Path(__file__).resolve().parents[2]
PNG = b"\x89PNG\r\n\x1a\n"
FIGURES = ("slices", "polar", "residuals", "coverage", "uncertainty")
# A simulated run's report also compares the fit with the true material.
RUN_FIGURES = (*FIGURES, "truth")
THETA_O = [-70.0, -50.0, -30.0, -10.0, 0.0, 10.0, 30.0, 50.0, 70.0]
PLASTIC = CookTorrance(alpha=0.2, fresnel="dielectric", eta=1.5, rho_d=(0.2, 0.3, 0.4))


@pytest.fixture(scope="module")
def gold_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One finished in-plane run of rough gold (GGX alpha 0.3) on the simulated rig, shared by the module."""
    run = tmp_path_factory.mktemp("gold") / "run"
    start_run(sim_rig(GOLD), in_plane_sweep([20.0, 50.0], THETA_O), run, progress=False)
    return run


@pytest.fixture(scope="module")
def gold_report(gold_run: Path) -> tuple[Analysis, Path]:
    """The run analysed from Python, with a ladder that holds the right model (a GGX conductor) and two simpler ones.

    Returns the analysis (fitted again: 17 samples fit in a fraction of a second) and the report's index.html.
    """
    lines: list[str] = []
    ladder = "lambert,lambert_ggx_schlick,ggx_conductor"
    page = analyze(gold_run, models=parse_models(ladder), log=lines.append, svg=True)
    assert any(line.startswith("fitting ggx_conductor (7 parameters)") for line in lines), lines
    assert f"wrote {gold_run / 'analysis' / 'fit.json'}" in lines
    return load_and_fit(gold_run, models=parse_models(ladder)), page


def write_merl_of(model: Model, path: Path) -> Path:
    """A MERL .binary file tabulating a known model (1.46 million bins)."""
    write_merl(MerlTable.from_model(model), path)
    return path


def stopped_copy(run: Path, dest: Path, points: int, reason: str = "interrupted by the operator") -> Path:
    """A copy of ``run`` as if it had stopped after ``points`` points: journal cut there, no table, status stopped."""
    shutil.copytree(run, dest, ignore=shutil.ignore_patterns("samples.csv", "status.json", "analysis", "lock"))
    kept, seen = [], 0
    for line in (run / "journal.jsonl").read_text().splitlines(keepends=True):
        if json.loads(line)["kind"] == "point":
            if seen == points:
                break
            seen += 1
        kept.append(line)
    (dest / "journal.jsonl").write_text("".join(kept))
    (dest / "status.json").write_text(json.dumps({"state": "stopped", "reason": reason}))
    return dest


def fit_doc(out: Path) -> dict[str, Any]:
    return json.loads((out / "fit.json").read_text())


def planned(run: Path) -> int:
    """The number of reachable points the run's plan held (from its manifest)."""
    return int(json.loads((run / "manifest.json").read_text())["points"])


@pytest.mark.mitsuba
def test_the_fit_recovers_the_simulated_gold_roughness(gold_report: tuple[Analysis, Path]) -> None:
    a, page = gold_report
    doc = fit_doc(page.parent)
    assert doc["chosen"] == "ggx_conductor" and doc["source"]["state"] == "finished"
    assert doc["source"]["measured"] == doc["source"]["planned"] == a.samples.n
    chosen = next(c for c in doc["candidates"] if c["name"] == "ggx_conductor")
    alpha, se = chosen["params"]["alpha"], chosen["std_errors"]["alpha"]
    assert abs(alpha - GOLD["alpha"]) < 4 * se and abs(alpha / GOLD["alpha"] - 1) < 0.03, (alpha, se)
    assert {c["name"] for c in doc["candidates"]} == {"lambert", "lambert+ggx_schlick", "ggx_conductor"}
    assert all(c["chi2"] > 0 and c["bic"] >= chosen["bic"] - 2.0 for c in doc["candidates"])
    # The chosen model's JSON form rebuilds the same model.
    model = from_json_dict(doc["model"], "fit.json")
    assert doc["model"]["model"] == "CookTorrance" and doc["model"]["params"]["alpha"] == alpha
    wi, wo = a.samples.wi, a.samples.wo
    np.testing.assert_allclose(model.eval(wi, wo), a.selection.chosen.model.eval(wi, wo), rtol=1e-12)


@pytest.mark.mitsuba
def test_point_errors_weight_by_the_capture_noise_and_say_so(gold_run: Path, tmp_path: Path) -> None:
    # The table's brdf_se holds the calibration's share (albedo 0.5 %, references), common to every point;
    # counted per point it pushes chi2/dof well below 1. The capture's own errors test the model against its noise.
    ladder = parse_models("ggx_conductor")
    total = load_and_fit(gold_run, models=ladder).selection.chosen
    point = load_and_fit(gold_run, models=ladder, errors="point").selection.chosen
    assert point.reduced_chi2 > 1.5 * total.reduced_chi2 and abs(point.reduced_chi2 - 1) < abs(total.reduced_chi2 - 1)
    assert point.param("alpha")[1] < total.param("alpha")[1]
    assert abs(point.param("alpha")[0] - GOLD["alpha"]) < 4 * point.param("alpha")[1] + 1e-4
    page = analyze(gold_run, tmp_path / "report", models=ladder, errors="point")
    assert fit_doc(page.parent)["errors"] == "point"


@pytest.mark.mitsuba
def test_the_ladder_chooses_exactly_as_select_does(gold_report: tuple[Analysis, Path]) -> None:
    a, _ = gold_report
    # A run's points carry a direction covariance, so each candidate is fitted with effective errors
    # (photometric plus angular); the choice among them is select()'s own.
    assert a.samples.direction_cov.size
    cands = [Candidate(s.name, len(s.labels(a.samples.channels)),
                       fit_with_angular(s, a.samples, a.loss, starts=a.starts)[0]) for s in a.ladder]  # fmt: skip
    ref = choose(cands)
    assert a.selection.chosen_name == ref.chosen_name and a.selection.reason == ref.reason
    assert a.selection.table() == ref.table()
    assert set(a.fit_times_s) == {c.name for c in ref.candidates} and min(a.fit_times_s.values()) > 0


@pytest.mark.mitsuba
def test_the_report_shows_source_choice_reason_warnings_and_figures(gold_report: tuple[Analysis, Path]) -> None:
    a, page = gold_report
    assert page == page.parent / "index.html" and page.parent.name == "analysis"
    html = page.read_text()
    for name in RUN_FIGURES:
        png, svg = page.parent / "figures" / f"{name}.png", page.parent / "figures" / f"{name}.svg"
        assert png.read_bytes()[:8] == PNG and png.stat().st_size > 10_000
        assert svg.read_text().lstrip().startswith("<?xml") and "<svg" in svg.read_text()[:1000]
    links = re.findall(r'(?:src|href)="([^"]+)"', html)
    figure_links = [link for link in links if link.startswith("figures/")]
    assert len(figure_links) == 2 * len(RUN_FIGURES) and all((page.parent / link).is_file() for link in links)
    assert "<script" not in html.lower()
    assert "ggx_conductor (chosen)" in html and "CookTorrance" in html and "alpha" in html
    # The reason verbatim (escaped) and every candidate's row.
    assert escape(a.selection.reason) in html
    assert all(f"<td>{escape(c.name)}" in html for c in a.selection.candidates)
    # The fits' warnings are listed (an in-plane sweep leaves out-of-plane behaviour to isotropy).
    assert "lie in one plane" in html and a.warnings
    n = planned(page.parent.parent)
    assert "finished" in html and f"{n} measured of {n} planned" in html and "in_plane" in html
    assert "CookTorrance(alpha=0.3" in html  # the simulated material
    # Every sample of an in-plane sweep is in the plane of incidence: the slices use them all.
    assert a.samples.n == n and f"({n} of {n} samples within 2° of the plane" in html
    assert re.search(r"\d+ of 81 \(theta_h, theta_d\) cells", html)


def same_files(a: Path, b: Path) -> list[str]:
    """Relative paths of every file under a and b, after checking both trees hold the same files byte for byte."""
    names = sorted(str(p.relative_to(a)) for p in a.rglob("*") if p.is_file())
    assert names == sorted(str(p.relative_to(b)) for p in b.rglob("*") if p.is_file())
    differ = [n for n in names if (a / n).read_bytes() != (b / n).read_bytes()]
    assert not differ, f"differ between {a} and {b}: {differ}"
    return names


@pytest.mark.mitsuba
def test_the_same_inputs_give_the_same_bytes(gold_report: tuple[Analysis, Path], gold_run: Path,
                                             tmp_path: Path) -> None:
    # A batch must never be a different analysis: everything gonio analyze writes depends on the inputs alone
    # (no wall-clock fit times, no dates or random ids in the SVGs).
    _, page = gold_report
    again = analyze(gold_run, tmp_path / "again", models=parse_models("lambert,lambert_ggx_schlick,ggx_conductor"),
                    svg=True)
    names = same_files(page.parent, again.parent)
    assert {"fit.json", "index.html", "figures/slices.svg", "export/material.json"} <= set(names)
    assert all(c["time_s"] is None for c in fit_doc(again.parent)["candidates"])
    assert "<dc:date>" not in (again.parent / "figures" / "polar.svg").read_text()


def test_the_slices_log_axes_make_only_the_ticks_in_view() -> None:
    from matplotlib.ticker import LogLocator

    from analysis.report.slices import _InViewLogLocator

    for lo, hi in [(0.01, 3.0), (1.3e-4, 0.5), (0.2, 0.9), (2.0, 2000.0)]:
        for subs in [(1.0, 2.0, 5.0), (1.0,)]:
            full = LogLocator(subs=subs, numticks=8).tick_values(lo, hi)
            inside = [t for t in full if lo * (1 - 1e-9) <= t <= hi * (1 + 1e-9)]
            assert list(_InViewLogLocator(subs=subs, numticks=8).tick_values(lo, hi)) == inside
            assert len(inside) < len(full)  # LogLocator's own reach beyond the view, built and never drawn


@pytest.mark.mitsuba
def test_reading_and_fitting_a_run_loads_neither_plots_nor_numba_nor_mitsuba(gold_run: Path) -> None:
    from tests.analysis.test_analyze_speed import loaded_after

    loaded = loaded_after(f"from analysis.analyze import load_and_fit\na = load_and_fit({str(gold_run)!r})\n"
                          "assert a.samples.n > 0 and a.references")  # fmt: skip
    assert loaded == [], f"loaded to read and fit {gold_run}: {loaded}"


@pytest.mark.mitsuba
def test_a_report_from_forked_workers_is_the_same_bytes(gold_report: tuple[Analysis, Path], gold_run: Path,
                                                        tmp_path: Path) -> None:
    # gonio analyze's default (--jobs 2) in a fresh process, where forking is safe: the exports made in a standby
    # forked before the fit, the figures in another and its worker; the same files as drawn and exported one after
    # the other.
    _, page = gold_report
    out = tmp_path / "forked"
    gonio = Path(sys.executable).with_name("gonio")
    done = subprocess.run([str(gonio), "analyze", str(gold_run), "--out", str(out), "--svg", "--quiet", "--jobs", "2",
                           "--models", "lambert,lambert_ggx_schlick,ggx_conductor"], capture_output=True, text=True,
                          timeout=900)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert {"fit.json", "index.html", "figures/slices.png", "export/material.json"} <= set(same_files(page.parent, out))


@pytest.mark.mitsuba
def test_the_command_leaves_plots_and_mitsuba_to_its_standbys(gold_run: Path, tmp_path: Path) -> None:
    # Where forking is safe, gonio analyze's own process fits and writes the page: matplotlib loads in the figures'
    # standby and Mitsuba in the exports', each while this one fits; its collector runs again after the imports.
    out = tmp_path / "report"
    code = (f"import gc, json, sys\nfrom gonio import cli\ncode = cli.main(['analyze', {str(gold_run)!r}, '--out', "
            f"{str(out)!r}, '--quiet', '--jobs', '2', '--models', 'lambert,ggx_conductor', '--starts', '2'])\n"
            "print(json.dumps([code, gc.isenabled(), sorted({m.split('.')[0] for m in sys.modules} & "
            "{'matplotlib', 'mitsuba', 'drjit'})]))")  # fmt: skip
    done = subprocess.run([sys.executable, "-c", code], cwd=Path(__file__).resolve().parents[2], capture_output=True,
                          text=True, timeout=900)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.splitlines()[-1]) == [0, True, []]
    assert {"slices.png", "truth.png"} <= {p.name for p in (out / "figures").iterdir()}
    assert (out / "export" / "mitsuba_bsdf.xml").is_file() and 'href="export/material.json"' in (
        out / "index.html").read_text()


@pytest.mark.mitsuba
def test_a_stopped_run_is_analysed_as_far_as_it_got_with_a_warning(gold_run: Path, tmp_path: Path, capsys) -> None:
    run = stopped_copy(gold_run, tmp_path / "run", points=11)
    out = tmp_path / "report"
    code = cli.main(["analyze", str(run), "--out", str(out), "--models", "lambert,ggx_conductor", "--starts", "2"])
    assert code == 0, capsys.readouterr().err
    stdout = capsys.readouterr().out.splitlines()
    assert stdout[0] == str(out / "index.html") and stdout[1].startswith("chosen: ggx_conductor")
    html = (out / "index.html").read_text()
    assert f"run stopped: interrupted by the operator; 11 of {planned(gold_run)} points" in html
    doc = fit_doc(out)
    assert doc["source"]["state"] == "stopped" and doc["source"]["measured"] == doc["n_samples"] == 11
    alpha = next(c for c in doc["candidates"] if c["name"] == "ggx_conductor")["params"]["alpha"]
    assert abs(alpha / GOLD["alpha"] - 1) < 0.05
    # The chosen model is exported and linked: a Mitsuba fragment and a glTF material (gold is a metal).
    for name in ("material.json", "mitsuba_bsdf.xml", "mitsuba_bsdf.json", "mitsuba_scene.xml", "gltf_material.json",
                 "material.gltf", "README.md"):
        assert (out / "export" / name).stat().st_size > 0 and f'href="export/{name}"' in html
    # The page says which Mitsuba the export is for and how exact it is (a GGX conductor maps exactly).
    assert "stock Mitsuba 3, no gonio needed: exact native mapping, relative RMS BRDF difference 0.00%" in html
    gltf = json.loads((out / "export" / "gltf_material.json").read_text())
    assert gltf["pbrMetallicRoughness"]["metallicFactor"] > 0.9
    assert not (out / "export" / "material.binary").exists()  # 35 MB: only with --merl


@pytest.mark.slow  # about 7 s: a fit, the figures, the projection fit and the table
def test_a_fit_without_a_native_plugin_exports_the_table_and_the_page_states_both_errors(
    gold_run: Path, tmp_path: Path, capsys
) -> None:
    # Lambert + GGX with Schlick Fresnel has no stock plugin: export/ holds the RGL table and the projection, and
    # --mitsuba-stock projection keeps the projection in mitsuba_bsdf.xml.
    out = tmp_path / "report"
    args = ["analyze", str(gold_run), "--out", str(out), "--models", "lambert_ggx_schlick", "--starts", "1", "--quiet"]
    assert cli.main([*args, "--mitsuba-stock", "projection"]) == 0, capsys.readouterr().err
    facts = json.loads((out / "export" / "material.json").read_text())["facts"]
    assert facts["mitsuba_stock"]["form"] == "projection"
    html = (out / "index.html").read_text()
    table, projection = facts["mitsuba_tabulated"], facts["mitsuba_projection"]
    for name in ("material.bsdf", "mitsuba_measured.xml", "mitsuba_measured.json", "mitsuba_projection.xml"):
        assert (out / "export" / name).stat().st_size > 0 and f'href="export/{name}"' in html
    assert f"relative RMS BRDF difference {table['error']['rms_rel']:.2%} (cosine weighted " in html
    assert f"RGL .bsdf table for stock Mitsuba&#x27;s measured plugin ({table['size_bytes'] / 1e6:.2f} MB)" in html
    assert f"a projection, relative RMS BRDF difference {projection['error']['rms_rel']:.2%}" in html
    with pytest.raises(SystemExit) as refused:
        cli.main([*args, "--force", "--mitsuba-stock", "tabular"])
    assert refused.value.code == 2 and "'tabular'" in capsys.readouterr().err


@pytest.fixture(scope="module")
def plastic_merl(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_merl_of(PLASTIC, tmp_path_factory.mktemp("merl") / "plastic.binary")


def test_a_merl_file_is_imported_and_its_model_recovered(plastic_merl: Path, tmp_path: Path, capsys) -> None:
    source = tmp_path / "paint.binary"
    source.symlink_to(plastic_merl)
    assert cli.main(["analyze", str(source), "--samples", "3000", "--compare", str(plastic_merl)]) == 0
    out = tmp_path / "paint-analysis"  # the default report directory sits beside the MERL file
    captured = capsys.readouterr()
    assert captured.out.splitlines()[0] == str(out / "index.html")
    assert "loaded MERL table" in captured.err and "fitting lambert+ggx_dielectric (5 parameters)" in captured.err
    doc = fit_doc(out)
    assert doc["chosen"] == "lambert+ggx_dielectric" and doc["source"]["kind"] == "merl"
    assert doc["n_samples"] == 3000 and doc["model"]["model"] == "CookTorrance"
    params = doc["model"]["params"]
    assert params["alpha"] == pytest.approx(0.2, rel=1e-3) and params["eta"] == pytest.approx(1.5, rel=1e-3)
    assert params["rho_d"] == pytest.approx([0.2, 0.3, 0.4], rel=1e-3)
    html = (out / "index.html").read_text()
    assert "std errors assumed" in html and "references dotted" in html
    assert "MERL reference plastic.binary" in html and "MERL table paint.binary (source)" in html
    assert all((out / "figures" / f"{n}.png").read_bytes()[:8] == PNG for n in FIGURES)


def short_file(d: Path) -> Path:
    (d / "short.binary").write_bytes(b"\0" * 100)
    return d / "short.binary"


def merl_header(d: Path) -> Path:
    (d / "short.binary").write_bytes(np.array([90, 90, 180], dtype="<i4").tobytes() + b"\0" * 100)
    return d / "short.binary"


@pytest.mark.parametrize(
    ("make", "extra", "expected", "names_source"),
    [
        (lambda d: d / "missing", [], "no such file or directory", True),
        (lambda d: d, [], "not a run directory", True),
        (short_file, [], "named .binary, but not a MERL table: its header is (0, 0, 0), a MERL table's is (90, 90, "
         "180)); SOURCE: expected a run directory", True),
        (short_file, ["--models", "lambert,phong"], "unknown model 'phong'", False),
        (short_file, ["--loss", "l3"], "--loss 'l3': expected one of l2, cosine_l2, log, cbrt", False),
        (merl_header, ["--errors", "point"], "is a MERL file, which has no readings", True),
    ],
    ids=["missing", "not-a-run", "bad-merl", "unknown-model", "bad-loss", "point-errors-of-merl"],
)
def test_bad_input_is_exit_code_2_naming_what_was_wrong(make, extra, expected, names_source, tmp_path, capsys) -> None:
    source = make(tmp_path)
    assert cli.main(["analyze", str(source), "--quiet", *extra]) == 2
    err = capsys.readouterr().err
    assert expected in err, err
    assert (str(source) in err) == names_source, err


def test_a_merl_compare_file_that_is_not_merl_is_bad_input(plastic_merl: Path, tmp_path: Path, capsys) -> None:
    bogus = tmp_path / "ref.binary"
    bogus.write_bytes(np.array([90, 90, 90], dtype="<i4").tobytes())
    assert cli.main(["analyze", str(plastic_merl), "--compare", str(bogus), "--quiet", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert str(bogus) in err and "header dimensions" in err


@pytest.mark.mitsuba
def test_a_run_with_too_few_points_names_the_run_and_the_fit_error(gold_run: Path, tmp_path: Path, capsys) -> None:
    run = stopped_copy(gold_run, tmp_path / "run", points=1)
    assert cli.main(["analyze", str(run), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"{run}: cannot fit" in err and "no candidate could be fitted" in err and "cannot determine" in err
    assert not (run / "analysis").exists()
    assert cli.main(["analyze", str(gold_run), "--samples", "100", "--out", str(tmp_path / "other"), "--quiet"]) == 2
    assert "only a MERL source is subsampled" in capsys.readouterr().err


@pytest.mark.mitsuba
def test_a_table_cut_short_is_refused_naming_the_line(gold_run: Path, tmp_path: Path, capsys) -> None:
    run = tmp_path / "run"
    shutil.copytree(gold_run, run, ignore=shutil.ignore_patterns("analysis", "lock"))
    lines = (run / "samples.csv").read_text().splitlines(keepends=True)
    (run / "samples.csv").write_text("".join(lines[:4]) + lines[4][: len(lines[4]) // 2])  # a copy cut mid-row
    assert cli.main(["analyze", str(run), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"{run / 'samples.csv'}: line 5 has no " in err and "cut short or corrupt" in err, err


def test_help_shows_an_example(capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.main(["analyze", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert "Example: gonio analyze" in out and "--compare" in out and "--samples" in out


def test_slices_keep_only_samples_near_the_plane_of_incidence() -> None:
    # Two incidences in the plane (phi_o = 180 or 0), plus points 1 and 10 degrees out of it.
    ti = np.array([30.0] * 5 + [60.0] * 5 + [30.0, 30.0])
    to = np.array([10.0, 20.0, 40.0, 60.0, 0.0] * 2 + [40.0, 40.0])
    po = np.array([180.0, 0.0, 180.0, 0.0, 0.0] * 2 + [181.0, 190.0])
    ang = angles_of(degrees_to_vector(ti, 0.0), degrees_to_vector(to, po))
    np.testing.assert_allclose(ang.signed_theta_o[:5], [10.0, -20.0, 40.0, -60.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(ang.off_plane[10:], [np.degrees(np.arcsin(np.sin(np.radians(40)) * np.sin(
        np.radians(d)))) for d in (1.0, 10.0)], rtol=1e-9)  # fmt: skip
    cuts = slices(ang)
    assert [round(c.theta_i_deg, 6) for c in cuts] == [30.0, 60.0]
    assert cuts[0].index.tolist() == [0, 1, 2, 3, 4, 10] and cuts[1].index.tolist() == [5, 6, 7, 8, 9]


def test_slices_fall_back_to_a_grid_of_incidences_and_coverage_counts_cells() -> None:
    rng = np.random.default_rng(0)
    wi = degrees_to_vector(rng.uniform(0, 85, 4000), rng.uniform(0, 360, 4000))
    wo = degrees_to_vector(rng.uniform(0, 85, 4000), rng.uniform(0, 360, 4000))
    ang = angles_of(wi, wo)
    cuts = slices(ang)
    assert [c.theta_i_deg for c in cuts] == [15.0, 30.0, 45.0, 60.0, 75.0]
    for c in cuts:
        assert np.all(np.abs(ang.theta_i[c.index] - c.theta_i_deg) <= c.tol_deg) and np.all(ang.off_plane[c.index] <= 2)
    cov = coverage(angles_of(degrees_to_vector([5.0, 5.0, 45.0], 0.0), degrees_to_vector([5.0, 5.0, 45.0], 180.0)))
    # Mirror pairs: theta_h = 0, theta_d = theta_i: two distinct cells of 81.
    assert int(cov.occupied_hd.sum()) == 2 and cov.fraction_hd == pytest.approx(2 / 81)


def test_an_existing_analysis_is_replaced_only_with_force(gold_run: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "report"
    base = ["analyze", str(gold_run), "--out", str(out), "--models", "lambert", "--starts", "1", "--quiet"]
    assert cli.main(base) == 0
    first = (out / "fit.json").read_bytes()
    (out / "notes.txt").write_text("kept unless replaced")
    capsys.readouterr()
    assert cli.main([*base[:5], "lambert,ggx_conductor", *base[6:]]) == 2  # refused before any fitting
    err = capsys.readouterr().err
    assert f"{out}: holds an analysis already (chose lambert from 1 models, " in err and "--force replaces it" in err
    assert (out / "fit.json").read_bytes() == first
    bad = tmp_path / "ref.binary"
    bad.write_bytes(b"not MERL")
    assert cli.main([*base, "--force", "--compare", str(bad)]) == 2  # a failed replacement leaves the old one
    assert (out / "fit.json").read_bytes() == first and (out / "notes.txt").exists()
    assert cli.main([*base[:5], "lambert,ggx_conductor", *base[6:8], "--force"]) == 0  # not quiet: progress shown
    err = capsys.readouterr().err
    assert "warning: replacing the analysis in" in err
    wrote = [line for line in err.splitlines() if line.startswith("wrote ")]
    assert wrote and all(line.startswith(f"wrote {out}/") for line in wrote)  # where the files end up, not the stage
    assert fit_doc(out)["chosen"] == "ggx_conductor" and not (out / "notes.txt").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # nothing staged is left behind


@pytest.mark.mitsuba
@pytest.mark.parametrize(("content", "what"), [("", "is empty (no header, no rows)"),
                                               ("theta_i_deg,phi_i_deg\n", "has a header but no rows")])  # fmt: skip
def test_an_empty_samples_table_beside_a_full_journal_is_blamed_not_the_journal(
    gold_run: Path, tmp_path: Path, capsys, content: str, what: str
) -> None:
    run = tmp_path / "run"
    shutil.copytree(gold_run, run, ignore=shutil.ignore_patterns("analysis", "lock"))
    (run / "samples.csv").write_text(content)
    for source in (run / "samples.csv", run):
        assert cli.main(["analyze", str(source), "--quiet", "--out", str(tmp_path / "report")]) == 2
        err = capsys.readouterr().err
        assert f"{run / 'samples.csv'}: {what}" in err, err
        assert "holds none" not in err
    assert not (tmp_path / "report").exists()


@pytest.mark.parametrize(
    ("name", "content", "looks"),
    [("rig.toml", (ROOT / "examples" / "rig_simulated.toml").read_bytes(), "it looks like a TOML rig or sweep file"),
     ("paint.binary", b"\x00" * 64, "named .binary, but not a MERL table: its header is (0, 0, 0)"),
     ("notes.txt", b"hello", "")],
)  # fmt: skip
def test_a_source_that_is_no_run_table_or_merl_file_is_named_with_what_is_accepted(
    tmp_path: Path, capsys, name: str, content: bytes, looks: str
) -> None:
    source = tmp_path / name
    source.write_bytes(content)
    assert cli.main(["analyze", str(source), "--quiet", "--out", str(tmp_path / "report")]) == 2
    err = capsys.readouterr().err
    assert f"{source}: not something gonio analyze reads" in err and looks in err
    assert "SOURCE: expected a run directory" in err and "a samples table (.csv or .parquet)" in err
    assert "a MERL .binary file (a 12-byte header 90 90 180" in err and "header dimensions" not in err
    assert not (tmp_path / "report").exists()


def test_a_merl_file_is_known_by_its_header_whatever_its_name(tmp_path: Path) -> None:
    from analysis.sources import source_kind

    source = tmp_path / "paint.dat"
    source.write_bytes(struct.pack("<3i", 90, 90, 180) + b"\x00" * 16)
    assert source_kind(source) == "merl"
    with pytest.raises(AnalysisError, match=r"paint\.dat: .* bytes, expected .* for a full MERL table"):
        load_and_fit(source)
