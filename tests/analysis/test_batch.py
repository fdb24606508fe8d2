"""``gonio batch analyze`` on a local Dask cluster of 2 workers: the same bytes as gonio analyze, failures kept to
their input, a restart that skips what is done, a worker killed mid-task, and the catalogue read as Parquet."""

from __future__ import annotations

import functools
import json
import os
import shutil
import signal
import threading
import time
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pytest

from analysis.batch.analyze_batch import BatchResult, batch_analyze
from analysis.batch.catalogue import COLUMNS
from analysis.batch.cluster import LOCAL_CONFIG, ClusterSettings, cluster_client
from analysis.batch.inputs import AnalyzeSettings, batch_inputs, fingerprint
from analysis.batch.records import TASKS, staged_dir, sweep_partials
from gonio import cli
from model import CookTorrance
from rig.run.session import start_run
from tests.analysis.test_analyze import same_files, write_merl_of
from tests.run_helpers import GOLD, in_plane_sweep, sim_rig

pytestmark = [pytest.mark.mitsuba, pytest.mark.slow]

MODELS, STARTS, MERL_SAMPLES = "lambert,ggx_conductor", 2, 400
# With SVGs: their ids and metadata are where a batch could most easily differ from gonio analyze.
SETTINGS = AnalyzeSettings(models=MODELS, starts=STARTS, samples=MERL_SAMPLES, svg=True)
ORDER = ("gold", "corrupt", "paint")
#: Generous: a loaded CI host is many times slower than a quiet one; nothing here waits this long when things work.
TIMEOUT_S = 600.0


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A finished run of rough gold, a MERL file of a glossy paint, and a copy of the run cut short mid-row."""
    d = tmp_path_factory.mktemp("inputs")
    sweep = in_plane_sweep([30.0], [-50.0, -20.0, 0.0, 15.0, 30.0, 45.0, 60.0])
    start_run(sim_rig(GOLD), sweep, d / "gold", progress=False)
    merl = write_merl_of(CookTorrance(alpha=0.25, fresnel="dielectric", eta=1.5, rho_d=(0.3, 0.3, 0.2)),
                         d / "paint.binary")  # fmt: skip
    shutil.copytree(d / "gold", d / "corrupt")
    text = (d / "corrupt" / "samples.csv").read_text()
    (d / "corrupt" / "samples.csv").write_text(text[: len(text) * 2 // 3])  # a copy that stopped mid-row
    return {"gold": d / "gold", "paint": merl, "corrupt": d / "corrupt"}


@pytest.fixture(scope="module")
def serial(inputs: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Each good input analysed by ``gonio analyze`` itself, one after the other, in this process."""
    d = tmp_path_factory.mktemp("serial")
    for key in ("gold", "paint"):
        extra = ["--samples", str(MERL_SAMPLES)] if key == "paint" else []
        argv = ["analyze", str(inputs[key]), "--out", str(d / key), "--models", MODELS, "--starts", str(STARTS),
                "--svg"]
        assert cli.main([*argv, *extra, "--quiet"]) == 0
    return {key: d / key for key in ("gold", "paint")}


@pytest.fixture(scope="module")
def first(cluster: Any, inputs: dict[str, Path], tmp_path_factory: pytest.TempPathFactory) -> tuple[BatchResult, Path]:
    out = tmp_path_factory.mktemp("batch") / "out"
    order = [inputs[k] for k in ORDER]
    return batch_analyze(order, out, SETTINGS, client=cluster, progress=False), out


def test_every_output_is_the_same_bytes_as_gonio_analyze(first: tuple[BatchResult, Path], serial: dict[str, Path]):
    result, out = first
    assert sorted(result.analysed) == ["gold", "paint"] and not result.skipped
    for key, serial_dir in serial.items():
        names = same_files(serial_dir, out / key)
        assert {"fit.json", "index.html", "figures/residuals.svg", "export/gltf_material.json"} <= set(names)


def test_a_corrupt_input_fails_alone_with_its_error_in_the_catalogue(first: tuple[BatchResult, Path],
                                                                     inputs: dict[str, Path]) -> None:  # fmt: skip
    result, out = first
    assert list(result.failed) == ["corrupt"] and str(inputs["corrupt"] / "samples.csv") in result.failed["corrupt"]
    assert not (out / "corrupt").exists()
    rows = {r["key"]: r for r in pq.read_table(out / "catalogue.parquet").to_pylist()}
    assert list(rows) == list(ORDER)  # the order given
    bad = rows["corrupt"]
    assert bad["status"] == "failed" and bad["error"] == result.failed["corrupt"] and bad["chosen"] is None
    assert all(rows[k]["status"] == "done" and rows[k]["error"] is None for k in ("gold", "paint"))


def test_the_catalogue_holds_model_fit_run_and_outputs_for_any_parquet_reader(
    first: tuple[BatchResult, Path], inputs: dict[str, Path]
) -> None:
    _, out = first
    table = pq.read_table(out / "catalogue.parquet")
    assert table.column_names == list(COLUMNS)
    docs = json.loads(table.schema.metadata[b"gonio.columns"])
    assert all(docs[c]["description"] for c in COLUMNS) and docs["wall_s"]["unit"] == "s"
    rows = {r["key"]: r for r in table.to_pylist()}
    for key in ("gold", "paint"):
        row, doc = rows[key], json.loads((out / rows[key]["fit_json"]).read_text())
        chosen = next(c for c in doc["candidates"] if c["name"] == doc["chosen"])
        assert row["chosen"] == doc["chosen"] and dict(row["params"]) == chosen["params"]
        assert dict(row["std_errors"]) == chosen["std_errors"] and row["reduced_chi2"] == chosen["reduced_chi2"]
        assert json.loads(row["model_json"]) == doc["model"] and row["n_samples"] == doc["n_samples"]
        for col in ("report", "fit_json", "material_json", "mitsuba_xml", "gltf"):
            assert (out / row[col]).is_file(), (key, col)
        assert row["wall_s"] > 0 and row["cpu_s"] > 0 and row["worker"]
    gold = rows["gold"]
    assert gold["chosen"] == "ggx_conductor" and abs(dict(gold["params"])["alpha"] / GOLD["alpha"] - 1) < 0.1
    assert gold["state"] == "finished" and gold["measured"] == 7 and gold["material"].startswith("CookTorrance(")
    assert gold["created_utc"] and gold["samples_parquet"] == str(inputs["gold"] / "samples.parquet")
    assert rows["paint"]["kind"] == "merl" and rows["paint"]["measured"] == MERL_SAMPLES
    duckdb = pytest.importorskip("duckdb")
    got = duckdb.connect().execute(
        "SELECT key, params['alpha'] FROM read_parquet(?) WHERE status = 'done' AND chosen = 'ggx_conductor'",
        [str(out / "catalogue.parquet")]).fetchall()
    assert ("gold", dict(gold["params"])["alpha"]) in got


def test_a_restarted_batch_skips_what_is_done(first: tuple[BatchResult, Path], inputs: dict[str, Path],
                                              cluster: Any) -> None:  # fmt: skip
    _, out = first
    stamps = {k: (out / k / "fit.json").stat().st_mtime_ns for k in ("gold", "paint")}
    again = batch_analyze([inputs[k] for k in ORDER], out, SETTINGS, client=cluster, progress=False)
    assert sorted(again.skipped) == ["gold", "paint"] and not again.analysed
    assert list(again.failed) == ["corrupt"]  # a failed input is tried again: it may have been repaired
    assert {k: (out / k / "fit.json").stat().st_mtime_ns for k in stamps} == stamps
    assert [r["status"] for r in pq.read_table(out / "catalogue.parquet").to_pylist()] == ["done", "failed", "done"]


def test_the_fingerprint_follows_the_files_read_and_the_settings(inputs: dict[str, Path], tmp_path: Path) -> None:
    # What decides that a restart redoes an input: a re-calibrated run (its table rewritten), other settings.
    run = tmp_path / "gold"
    shutil.copytree(inputs["gold"], run)
    gold = batch_inputs([run])[0]
    base = fingerprint(gold, SETTINGS)
    assert fingerprint(gold, SETTINGS) == base and fingerprint(gold, AnalyzeSettings(models="lambert")) != base
    assert fingerprint(gold, AnalyzeSettings(**{**SETTINGS.as_dict(), "seed": 1})) != base
    table = run / "samples.parquet"  # derived, and possibly written by a batch: not an input
    os.utime(table, ns=(table.stat().st_atime_ns, table.stat().st_mtime_ns + 10**9))
    assert fingerprint(gold, SETTINGS) == base
    table = run / "samples.csv"
    os.utime(table, ns=(table.stat().st_atime_ns, table.stat().st_mtime_ns + 10**9))
    assert fingerprint(gold, SETTINGS) != base


def test_the_command_runs_on_an_existing_scheduler_and_shows_progress(cluster: Any, first: tuple[BatchResult, Path],
                                                                      inputs: dict[str, Path], tmp_path: Path,
                                                                      capsys) -> None:  # fmt: skip
    out = tmp_path / "cli"
    shutil.copytree(first[1], out)  # a batch directory moves whole: its records and relative paths still hold
    argv = ["batch", "analyze", str(inputs["gold"]), str(inputs["corrupt"]), "--out", str(out), "--models", MODELS,
            "--starts", str(STARTS), "--samples", str(MERL_SAMPLES), "--svg",
            "--scheduler", cluster.scheduler.address]  # fmt: skip
    code = cli.main(argv)
    captured = capsys.readouterr()
    assert code == 2, captured.err  # one input failed: bad input, named on stderr
    assert captured.out.splitlines() == [str(out / "catalogue.parquet"),
                                         "2 inputs: 0 analysed, 1 already done (skipped), 1 failed"]  # fmt: skip
    assert f"dashboard: {cluster.dashboard_link}" in captured.err
    assert "analysing: 100%" in captured.err and "2/2" in captured.err and "1 failed" in captured.err
    assert f"failed: corrupt: AnalysisError: {inputs['corrupt'] / 'samples.csv'}: line" in captured.err
    assert [r["status"] for r in pq.read_table(out / "catalogue.parquet").to_pylist()] == ["done", "failed"]


def _pools() -> dict[str, int]:
    """The thread pools of this (worker) process once a task has loaded numba's kernels and Mitsuba."""
    import dask
    import drjit as dr
    import numba

    import model.mitsuba.variant  # noqa: F401  (where gonio loads Mitsuba: it caps Dr.Jit's pool)

    return {"numba": numba.config.NUMBA_NUM_THREADS, "drjit": dr.thread_count(),
            "omp": int(os.environ.get("OMP_NUM_THREADS", "0")),
            "malloc_trim": os.environ.get("MALLOC_TRIM_THRESHOLD_"),
            "config": {key: dask.config.get(key) for key in LOCAL_CONFIG}}  # fmt: skip


def test_each_worker_computes_on_one_thread_with_mallocs_own_settings(cluster: Any, first: Any) -> None:
    # Two workers with two numba and two Dr.Jit threads each would be eight threads taking turns on two cores;
    # Dask's MALLOC_TRIM_THRESHOLD_ made each analysis fault its pages in again, and its frequent event-loop ticks
    # and stack samples kept the cores busy (analysis/batch/cluster.py).
    pools = cluster.run(_pools)
    assert len(pools) == 2
    want = {"numba": 1, "drjit": 1, "omp": 1, "malloc_trim": None, "config": LOCAL_CONFIG}
    assert all(p == want for p in pools.values()), pools


def test_an_unreachable_scheduler_is_named() -> None:
    with pytest.raises(ValueError, match=r"--scheduler tcp://127.0.0.1:9: cannot reach a Dask scheduler there"):
        with cluster_client(ClusterSettings(scheduler="tcp://127.0.0.1:9", connect_timeout_s=1.0)):
            pass


def _hold_when_written(key: str, stage: str, *, victim: str, gate: str) -> None:
    """Runs on a worker: the victim's first attempt says where it is once its outputs are staged, then waits to die."""
    g = Path(gate)
    if key != victim or stage != "written" or (g / "killed").exists():
        return
    (g / "pid.tmp").write_text(str(os.getpid()))
    (g / "pid.tmp").rename(g / "pid")  # whole, or not there
    deadline = time.monotonic() + TIMEOUT_S
    while not (g / "killed").exists() and time.monotonic() < deadline:
        time.sleep(0.05)  # a barrier: released by the test, which kills this process first


def test_a_worker_killed_mid_batch_leaves_every_input_done(
    cluster: Any, inputs: dict[str, Path], serial: dict[str, Path], tmp_path: Path
) -> None:
    gate, out = tmp_path / "gate", tmp_path / "out"
    gate.mkdir()
    killed: list[int] = []
    seen: list[tuple[list[str], bool]] = []  # what was on disk at the kill (asserted below, not in the thread)

    def kill_when_staged() -> None:
        deadline = time.monotonic() + TIMEOUT_S
        while not (gate / "pid").exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        if (gate / "pid").exists():
            pid = int((gate / "pid").read_text())
            seen.append(([p.name for p in out.iterdir() if p.name.startswith(".tmp-gold-")], (out / "gold").exists()))
            os.kill(pid, signal.SIGKILL)
            killed.append(pid)
        (gate / "killed").touch()

    probe = functools.partial(_hold_when_written, victim="gold", gate=str(gate))
    killer = threading.Thread(target=kill_when_staged)
    killer.start()
    try:
        result = batch_analyze([inputs["gold"], inputs["paint"]], out, SETTINGS, client=cluster, progress=False,
                               probe=probe)  # fmt: skip
    finally:
        (gate / "killed").touch()
        killer.join(TIMEOUT_S)
    assert len(killed) == 1, "the victim's worker never reported in"
    [(staged, in_place)] = seen
    assert len(staged) == 1 and not in_place  # killed with its outputs written, but only under a temporary name
    assert sorted(result.analysed) == ["gold", "paint"] and not result.failed
    record = json.loads((out / TASKS / "gold.json").read_text())
    assert record["status"] == "done" and not record["worker"].endswith(f":{killed[0]}")  # run again elsewhere
    assert not [p for p in out.iterdir() if p.name.startswith((".tmp-", ".old-"))]
    for key in ("gold", "paint"):
        same_files(serial[key], out / key)


def test_inputs_get_unique_keys_and_a_duplicate_is_refused(tmp_path: Path) -> None:
    for d in ("a/gold", "b/gold", "c/x y"):
        (tmp_path / d).mkdir(parents=True)
    (tmp_path / "paint.binary").write_bytes(b"")
    got = batch_inputs([tmp_path / "a/gold", tmp_path / "b/gold", tmp_path / "c/x y", tmp_path / "paint.binary",
                        tmp_path / "gone"])  # fmt: skip
    keys = [i.key for i in got]
    assert keys[0].startswith("gold-") and keys[1].startswith("gold-") and keys[0] != keys[1]
    assert keys[2:] == ["x_y", "paint", "gone"] and [i.kind for i in got] == ["run"] * 3 + ["merl", "missing"]
    with pytest.raises(ValueError, match="listed twice"):
        batch_inputs([tmp_path / "a/gold", tmp_path / "a" / ".." / "a" / "gold"])


def test_outputs_are_swapped_in_whole_or_not_at_all(tmp_path: Path) -> None:
    final = tmp_path / "out" / "gold"
    with staged_dir(final) as tmp:
        (tmp / "fit.json").write_text("first")
    assert (final / "fit.json").read_text() == "first"
    with pytest.raises(RuntimeError), staged_dir(final) as tmp:
        (tmp / "fit.json").write_text("half")
        raise RuntimeError("the task died here")
    assert (final / "fit.json").read_text() == "first" and [p.name for p in final.parent.iterdir()] == ["gold"]
    with staged_dir(final) as tmp:
        (tmp / "index.html").write_text("second")
    assert sorted(p.name for p in final.iterdir()) == ["index.html"]  # replaced whole: nothing of the first left
    (final.parent / ".tmp-gold-0123").mkdir()  # what a killed attempt leaves
    assert [p.name for p in sweep_partials(final.parent)] == [".tmp-gold-0123"]
