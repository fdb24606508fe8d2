"""``gonio batch study``: cells of a simulation study as tasks, the same numbers on a cluster as in one process."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest

from analysis.batch.study import file_cells, run_study, tradeoff_cells
from analysis.batch.study_report import Outcome, anchor_of, markdown_report, mean_outcomes, tradeoff_verdict
from analysis.batch.tradeoff import ADAPTIVE_VARIANTS, KEYS, MATERIALS
from gonio import cli

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
PNG = b"\x89PNG\r\n\x1a\n"


def sweep_file(path: Path, name: str, theta_o: list[float]) -> Path:
    path.write_text(f'name = "{name}"\n[sweep]\nkind = "in_plane"\ntheta_i_deg = [30.0]\ntheta_o_deg = {theta_o}\n')
    return path


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("study-files")
    rig = shutil.copyfile(EXAMPLES / "rig_simulated.toml", d / "gold.toml")
    sparse = sweep_file(d / "sparse.toml", "sparse", [-40.0, 0.0, 20.0, 45.0])
    dense = sweep_file(d / "dense.toml", "dense", [-50.0, -20.0, 0.0, 15.0, 30.0, 45.0])
    return {"rigs": [str(rig)], "sweeps": [str(sparse), str(dense)], "dir": d}


@pytest.fixture(scope="module")
def on_cluster(cluster: Any, files: dict[str, Any], tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, Path]:
    out = tmp_path_factory.mktemp("study") / "cluster"
    cells = file_cells(files["rigs"], files["sweeps"], [1], models="lambert,ggx_conductor")
    return run_study(cells, out, client=cluster, progress=False), out


@pytest.mark.mitsuba
@pytest.mark.slow
def test_a_study_of_files_gives_on_a_cluster_the_numbers_of_one_process(
    on_cluster: tuple[Any, Path], files: dict[str, Any], tmp_path: Path
) -> None:
    result, out = on_cluster
    assert sorted(result.ran) == sorted(c.key for c in file_cells(files["rigs"], files["sweeps"], [1]))
    serial = run_study(file_cells(files["rigs"], files["sweeps"], [1], models="lambert,ggx_conductor"),
                       tmp_path / "serial", serial=True, progress=False)  # fmt: skip
    assert serial.results == result.results and not serial.failed  # every float the same
    [(material, outcomes)] = result.results.items()
    assert material == "simulated four-axis rig (gold.toml)"  # the rig file's name, and which file
    assert [(o.strategy, o.captures) for o in outcomes] == [("sparse (sparse.toml)", 4), ("dense (dense.toml)", 6)]
    assert all(0 < o.error < 0.2 and o.rig_time_s > 0 and 0.3 < o.reduced_chi2 < 3 for o in outcomes)
    md = (out / "study.md").read_text()
    assert f"**{material}** (anchor: dense (dense.toml) (6 captures))" in md and "| sparse (sparse.toml) | 4 |" in md
    assert (out / "study.png").read_bytes()[:8] == PNG and (out / "study.txt").read_text().startswith(material)
    table = pq.read_table(out / "outcomes.parquet")
    assert table.num_rows == 2 and table.column("error").to_pylist() == [o.error for o in outcomes]
    assert json.loads(table.schema.metadata[b"gonio.columns"])["rig_time_s"]["unit"] == "s"
    assert not (out / "runs" / result.ran[0]).exists()  # a cell's runs go once it is scored (unless --keep-runs)


@pytest.mark.mitsuba
@pytest.mark.slow
def test_the_command_resumes_a_study_and_prints_where_it_wrote(
    cluster: Any, on_cluster: tuple[Any, Path], files: dict[str, Any], tmp_path: Path, capsys
) -> None:
    out = tmp_path / "again"
    shutil.copytree(on_cluster[1], out)
    argv = ["batch", "study", "--rig", *files["rigs"], "--sweep", *files["sweeps"], "--seeds", "1", "--models",
            "lambert,ggx_conductor", "--out", str(out), "--scheduler", cluster.scheduler.address]  # fmt: skip
    assert cli.main(argv) == 0
    captured = capsys.readouterr()
    assert captured.out.splitlines() == [str(out / "study.md"), str(out / "study.png"), str(out / "outcomes.parquet"),
                                         "2 cells: 0 run, 2 already done (skipped), 0 failed"]  # fmt: skip
    assert "dense (dense.toml)" in captured.err  # the table, for the person at the terminal


@pytest.mark.mitsuba
@pytest.mark.slow
def test_a_sweep_tradeoff_cell_runs_as_a_task(cluster: Any, tmp_path: Path) -> None:
    [cell] = [c for c in tradeoff_cells(["matte"], [2], quick=True) if c.key == "matte-s2-grid-30"]
    result = run_study([cell], tmp_path / "tradeoff", client=cluster, progress=False)
    [(name, [o])] = result.results.items()
    assert name == MATERIALS[KEYS.index("matte")].name and o.strategy == "grid" and 20 <= o.captures <= 40
    assert o.error < 0.05 and o.shape_error < 1e-6  # a Lambertian fit is a scale per channel: no shape error
    hours = f"{o.rig_time_s / 3600:.2f}"
    assert result.verdicts == {name: f"{name}: dense grid of {o.captures} captures ({hours} h rig time)"}


def test_the_tradeoff_grid_has_every_design_of_the_bench() -> None:
    cells = tradeoff_cells(KEYS, [1, 2])
    assert len(cells) == 3 * 2 * (4 + 3 + len(ADAPTIVE_VARIANTS)) and len({c.key for c in cells}) == len(cells)
    assert {c.design for c in cells} == {"grid", "rusinkiewicz", *(v[0] for v in ADAPTIVE_VARIANTS)}
    assert {c.size for c in cells if c.kind == "grid"} == {30, 100, 300, 1000}
    with pytest.raises(ValueError, match="--materials velvet: unknown"):
        tradeoff_cells(["velvet"])


def test_a_study_refuses_a_rig_that_is_not_simulated(files: dict[str, Any]) -> None:
    with pytest.raises(ValueError, match=r"rig_dynamixel.toml: \[link\] kind = 'dynamixel': a study runs on the sim"):
        file_cells([str(EXAMPLES / "rig_dynamixel.toml")], files["sweeps"], [1])


def test_the_verdict_says_where_the_adaptive_sweep_reaches_the_dense_grid() -> None:
    def run(dense: float, adaptive: list[float]) -> list[Outcome]:
        out = [Outcome("grid", 30, 60.0, 0.1, 0.05, 1.0), Outcome("grid", 1000, 3600.0, dense, 0.01, 1.0)]
        for label, _ in ADAPTIVE_VARIANTS:
            out += [Outcome(label, n, 36.0 * n, e, 0.01, 1.0) for n, e in zip((20, 60, 100), adaptive, strict=True)]
        return out

    runs = [run(0.02, [0.1, 0.03, 0.019]), run(0.02, [0.1, 0.05, 0.04])]
    res = mean_outcomes(runs)
    assert anchor_of(res).captures == 1000 and anchor_of(res).error == pytest.approx(0.02)
    verdict = tradeoff_verdict("gold", res, runs)
    assert verdict.startswith("gold: dense grid of 1000 captures (1.00 h rig time); BRDF error 2.00e-02, adaptive best")
    assert "adaptive at 100 at or below the dense grid in 1 of 2 seeds" in verdict
    assert "never below the dense grid's" in verdict  # the mean of 0.019 and 0.04 is not below 0.02
    md = markdown_report({"gold": res}, {"gold": verdict})
    assert "| grid | 1000 | 60.0 | 2.00e-02 | 1.00 |" in md and md.rstrip().endswith(verdict)


def test_a_cell_that_fails_is_recorded_with_its_error_and_the_command_says_so(
    files: dict[str, Any], tmp_path: Path, capsys
) -> None:
    # Every direction beyond the rig's 85 deg zenith limit: the run cannot start, before anything is opened.
    bad = sweep_file(tmp_path / "grazing.toml", "grazing", [88.0, 89.0])
    argv = ["batch", "study", "--rig", *files["rigs"], "--sweep", str(bad), "--seeds", "1", "--out",
            str(tmp_path / "out"), "--serial", "--quiet"]  # fmt: skip
    assert cli.main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out.splitlines()[-1] == "1 cells: 0 run, 0 already done (skipped), 1 failed"
    assert f"{bad}: no reachable point on this rig" in captured.err
    assert pq.read_table(tmp_path / "out" / "outcomes.parquet").num_rows == 0
