"""``gonio batch study``: a simulation study, each design x material x seed one task on a Dask cluster.

A study is a list of cells. The study of bench/sweep_tradeoff (:func:`tradeoff_cells`) crosses its three
materials with grids, Rusinkiewicz grids and three adaptive variants over seeds; a user's study
(:func:`file_cells`) crosses rig files (each a simulated rig with its material) with sweep files over seeds,
fitting the ladder of ``gonio analyze`` and scoring the chosen model against the rig's true material. Every
cell runs its sweep on the simulated rig through ``rig.run.session`` (the registered ``simulated`` backend:
analysis never imports the simulator), fits, scores, and records its outcomes in ``OUT/.tasks/<key>.json``:
a restarted study skips finished cells, and a cell is deterministic in its seed, so the cluster gives the
numbers a serial run gives. The runs live in ``OUT/runs/<key>`` while a cell works (kept with keep_runs).

Written to OUT: ``study.md`` and ``study.txt`` (the tables, per material, and the verdicts), ``study.png``
(the figure), ``outcomes.parquet`` (every seed's outcome) and ``study.json`` (the cells).
"""

from __future__ import annotations

import csv
import dataclasses
import hashlib
import json
import os
import re
import shutil
import time
import traceback
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from acquisition.files.atomic import write_atomic
from analysis.batch.cluster import ClusterSettings, Task, cluster_client, run_tasks
from analysis.batch.records import batch_lock, is_done, read_record, sweep_partials, utc_now, worker_name, write_record
from analysis.batch.study_report import Outcome, markdown_report, mean_outcomes, plot, text_report, tradeoff_verdict
from analysis.batch.tradeoff import (
    ADAPTIVE_REFERENCE_SNR,
    ADAPTIVE_VARIANTS,
    BUDGET,
    KEYS,
    MATERIALS,
    MAX_THETA,
    SNR,
    grid_design,
    rig_for,
    rusinkiewicz_design,
    sizes,
)
from analysis.result import AnalysisError, Log
from model.version import gonio_version
from rig.run.tables.parquet import Column, write_parquet

_SLUG = re.compile(r"[^A-Za-z0-9_.\-]+")


@dataclass(frozen=True)
class Cell:
    """One task of a study: a design (``kind``) on one material with one simulator seed.

    kind "grid" or "rusinkiewicz": ``size`` captures of that design of the sweep_tradeoff material
    ``material_index``; "adaptive": its adaptive sweep at capture SNR ``snr``; "files": the sweep file on the
    rig file (seed replaced), fitted with the ``models`` ladder. Errors are scored up to ``max_theta_deg``.
    """

    key: str
    material: str
    design: str
    seed: int
    kind: str
    size: int
    material_index: int = -1
    snr: float = 0.0
    rig_path: str | None = None
    sweep_path: str | None = None
    models: str | None = None
    max_theta_deg: float = MAX_THETA

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (study.json, fingerprints)."""
        return dataclasses.asdict(self)


def _slug(text: str) -> str:
    return _SLUG.sub("-", text).strip("-.") or "x"


def tradeoff_cells(materials: Sequence[str] = KEYS, seeds: Iterable[int] = (1, 2, 3), *,
                   quick: bool = False) -> list[Cell]:  # fmt: skip
    """The cells of bench/sweep_tradeoff: per material (by KEYS name) and seed, every grid and adaptive variant."""
    unknown = [m for m in materials if m not in KEYS]
    if unknown:
        raise AnalysisError(f"--materials {' '.join(unknown)}: unknown; expected some of {', '.join(KEYS)}")
    grid_sizes, rus_sizes = sizes(quick)
    cells = []
    for key in materials:
        i = KEYS.index(key)
        name = MATERIALS[i].name
        for seed in seeds:
            for kind, ns in (("grid", grid_sizes), ("rusinkiewicz", rus_sizes)):
                cells += [Cell(f"{key}-s{seed}-{kind}-{n}", name, kind, seed, kind, n, i) for n in ns]
            cells += [Cell(f"{key}-s{seed}-{_slug(label)}", name, label, seed, "adaptive", BUDGET, i, snr)
                      for label, snr in ADAPTIVE_VARIANTS]  # fmt: skip
    return cells


def file_cells(rigs: Sequence[str], sweeps: Sequence[str], seeds: Iterable[int], *, models: str | None = None,
               max_theta_deg: float = MAX_THETA) -> list[Cell]:  # fmt: skip
    """The cells of a user's study: every sweep file on every rig file (simulated rigs) for every seed."""
    from analysis.ladder import parse_models
    from rig.run.config.files import load_rig, load_sweep

    if models:
        parse_models(models)
    if not rigs or not sweeps:
        raise AnalysisError("gonio batch study: --rig and --sweep each need at least one file (or neither, for the "
                         "study of bench/sweep_tradeoff)")  # fmt: skip
    labels = []
    for path in rigs:
        rig = load_rig(path)
        if rig.file.link.kind != "simulated":
            raise AnalysisError(f"{path}: [link] kind = {rig.file.link.kind!r}: a study runs on the simulated rig "
                             "(kind = 'simulated'), whose material it scores the fits against")  # fmt: skip
        labels.append(f"{rig.file.name} ({Path(path).name})")
    designs = [f"{load_sweep(p).file.name} ({Path(p).name})" for p in sweeps]
    points = [len(load_sweep(p).directions_deg) for p in sweeps]
    cells = []
    for r, (rig_path, label) in enumerate(zip(rigs, labels, strict=True)):
        for s, (sweep_path, design, n) in enumerate(zip(sweeps, designs, points, strict=True)):
            for seed in seeds:
                key = f"r{r}-{_slug(Path(rig_path).stem)}-s{s}-{_slug(Path(sweep_path).stem)}-seed{seed}"
                cells.append(Cell(key, label, design, seed, "files", n, rig_path=os.path.abspath(rig_path),
                                  sweep_path=os.path.abspath(sweep_path), models=models,
                                  max_theta_deg=max_theta_deg))  # fmt: skip
    return cells


def cell_fingerprint(cell: Cell) -> str:
    """A digest of the cell, the files it reads (size, mtime) and gonio's version."""
    files = []
    for p in (cell.rig_path, cell.sweep_path):
        if p is not None:
            st = Path(p).stat()
            files.append([p, st.st_size, st.st_mtime_ns])
    doc = {"cell": cell.as_dict(), "files": files, "gonio": gonio_version()}
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()


def _score(design: str, model: Any, truth: Any, pairs: Any, captures: int, rig_time_s: float, chi2: float) -> Outcome:
    from model.fit.design import brdf_error

    return Outcome(design, captures, rig_time_s, brdf_error(model, truth, pairs),
                   brdf_error(model, truth, pairs, scale_free=True), chi2)  # fmt: skip


def _outcomes(cell: Cell, work: Path) -> list[Outcome]:
    """Run the cell's sweep(s) into ``work`` and score the fit(s) against the true material."""
    from model.fit.design import error_pairs
    from model.fit.samples import Samples
    from model.fit.solve import fit
    from rig.run.adaptive.sweep import AdaptiveSettings, Round, measure_points, replace_table, run_adaptive
    from rig.run.config.files import load_rig, load_sweep, material_from

    pairs = error_pairs(4000, max_theta_deg=cell.max_theta_deg)
    if cell.kind == "files":
        from analysis.ladder import fit_ladder, parse_models
        from model.fit.select import default_ladder
        from rig.run.session import start_run

        assert cell.rig_path is not None and cell.sweep_path is not None
        rig = replace_table(load_rig(cell.rig_path), "simulation", seed=cell.seed)
        summary = start_run(rig, load_sweep(cell.sweep_path), work, progress=False)
        with open(summary.table, newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
        samples = Samples.from_table_rows(rows, source=str(work), errors="point")
        ladder = parse_models(cell.models) if cell.models else default_ladder()
        chosen = fit_ladder(samples, ladder)[0].chosen
        return [_score(cell.design, chosen.model, material_from(rig), pairs, len(rows), summary.rig_time_s,
                       chosen.reduced_chi2)]  # fmt: skip
    m = MATERIALS[cell.material_index]
    rig = rig_for(m, cell.seed)
    truth = material_from(rig)
    if cell.kind in ("grid", "rusinkiewicz"):
        pts = (grid_design if cell.kind == "grid" else rusinkiewicz_design)(rig, cell.size)
        rows, rig_time_s = measure_points(rig, pts, work, SNR)
        res = fit(m.spec, Samples.from_table_rows(rows, source=str(work), errors="point"), starts=4, warn=False)
        return [_score(cell.design, res.model, truth, pairs, len(rows), rig_time_s, res.reduced_chi2)]
    rounds: list[Round] = []
    out: list[Outcome] = []

    def record(r: Round) -> None:
        rig_s = sum(x.rig_time_s for x in rounds) + r.rig_time_s
        out.append(_score(cell.design, r.fit.model, truth, pairs, r.captures, rig_s, r.fit.reduced_chi2))
        rounds.append(r)

    settings = AdaptiveSettings(budget=cell.size, max_theta_deg=MAX_THETA, target_snr=cell.snr,
                                reference_snr=ADAPTIVE_REFERENCE_SNR, seed=cell.seed)  # fmt: skip
    run_adaptive(rig, work, m.spec, settings, pairs=pairs, on_round=record, log=lambda _: None)
    return out


def run_cell(cell: Cell, out: str, fingerprint: str, keep_runs: bool = False) -> dict[str, Any]:
    """Run one cell in OUT/runs/<key> (from scratch: a killed attempt's run is removed), record it; the record."""
    root = Path(out)
    work = root / "runs" / cell.key
    wall, cpu = time.perf_counter(), time.process_time()
    record: dict[str, Any] = {"key": cell.key, "cell": cell.as_dict(), "fingerprint": fingerprint,
                              "worker": worker_name(), "started_utc": utc_now()}  # fmt: skip
    shutil.rmtree(work, ignore_errors=True)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # early adaptive rounds are under-determined, and say so
            outcomes = _outcomes(cell, work)
        record |= {"status": "done", "error": None, "outcomes": [dataclasses.asdict(o) for o in outcomes]}
    except Exception as exc:  # a cell's failure is its record, never the study's end
        record |= {"status": "failed", "error": f"{type(exc).__name__}: {exc}",
                   "traceback": traceback.format_exc(limit=8)}  # fmt: skip
    if not keep_runs:
        shutil.rmtree(work, ignore_errors=True)
    record |= {"timing": {"wall_s": time.perf_counter() - wall, "cpu_s": time.process_time() - cpu},
               "finished_utc": utc_now()}  # fmt: skip
    write_record(root, cell.key, record)
    return record


@dataclass
class StudyResult:
    """A study's outcomes: per material the mean over seeds and each seed's, the verdicts, the files written."""

    results: dict[str, list[Outcome]] = field(default_factory=dict)
    per_seed: dict[str, list[list[Outcome]]] = field(default_factory=dict)
    verdicts: dict[str, str] = field(default_factory=dict)
    files: dict[str, Path] = field(default_factory=dict)
    ran: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)

    def summary(self) -> str:
        """One line: cells run, skipped as done, failed."""
        n = len(self.ran) + len(self.skipped) + len(self.failed)
        return f"{n} cells: {len(self.ran)} run, {len(self.skipped)} already done (skipped), {len(self.failed)} failed"


_OUTCOME_COLUMNS = {
    "key": Column("str", "", "the cell (task) the outcome came from"),
    "material": Column("str", "", "the material (sweep_tradeoff) or rig file"),
    "design": Column("str", "", "the design (sweep_tradeoff) or sweep file"),
    "seed": Column("int", "", "the simulator's seed"),
    "captures": Column("int", "", "points measured (an adaptive sweep: so far, after this round)"),
    "rig_time_s": Column("float", "s", "rig time on the simulated clock (an adaptive sweep: all rounds so far)"),
    "error": Column("float", "", "relative cosine-weighted RMS BRDF error of the fit against the true material"),
    "shape_error": Column("float", "", "the same error after the best scale per channel (no calibration share)"),
    "reduced_chi2": Column("float", "", "chi2/dof of the fit, weighted by each capture's own reading error"),
}


def _gather(cells: Sequence[Cell], records: dict[str, dict[str, Any]], result: StudyResult) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    by_seed: dict[str, dict[int, list[Outcome]]] = {}
    for c in cells:
        rec = records.get(c.key)
        if rec is None or rec.get("status") != "done":
            continue
        got = [Outcome(**o) for o in rec["outcomes"]]
        by_seed.setdefault(c.material, {}).setdefault(c.seed, []).extend(got)
        rows += [{"key": c.key, "material": c.material, "design": o.strategy, "seed": c.seed, **dataclasses.asdict(o)}
                 for o in got]  # fmt: skip
    for material, seeds in by_seed.items():
        result.per_seed[material] = [seeds[s] for s in sorted(seeds)]
        result.results[material] = mean_outcomes(result.per_seed[material])
    return rows


def _write(root: Path, cells: Sequence[Cell], rows: list[dict[str, Any]], result: StudyResult) -> None:
    tradeoff = all(c.kind != "files" for c in cells)
    if tradeoff:
        result.verdicts = {m: tradeoff_verdict(m, res, result.per_seed[m]) for m, res in result.results.items()
                           if any(o.strategy == "grid" for o in res)}  # fmt: skip
    table = write_parquet(root / "outcomes.parquet", rows, list(_OUTCOME_COLUMNS),
                          describe=_OUTCOME_COLUMNS.__getitem__, table_format="gonio-study/1")  # fmt: skip
    files = {"outcomes": table}
    if result.results:
        text, md = text_report(result.results, result.verdicts), markdown_report(result.results, result.verdicts)
        files["text"] = write_atomic(root / "study.txt", lambda tmp: tmp.write_text(text, encoding="utf-8"))
        page = md + "\n![error against captures and rig time](study.png)\n"
        files["markdown"] = write_atomic(root / "study.md", lambda tmp: tmp.write_text(page, encoding="utf-8"))
        files["figure"] = plot(result.results, root / "study.png")
    result.files = files


def run_study(
    cells: Sequence[Cell],
    out: str | os.PathLike[str],
    *,
    cluster: ClusterSettings | None = None,
    client: Any = None,
    serial: bool = False,
    keep_runs: bool = False,
    progress: bool = True,
    log: Log | None = None,
) -> StudyResult:
    """Run every cell not already done (on ``client``, a cluster from ``cluster``, or in this process if serial)."""
    if not cells:
        raise AnalysisError("gonio batch study: no cells to run")
    if len({c.key for c in cells}) != len(cells):
        raise AnalysisError("gonio batch study: two cells share a key (a rig or sweep file listed twice?)")
    say = log or (lambda _: None)
    root = Path(out).absolute()
    root.mkdir(parents=True, exist_ok=True)
    with batch_lock(root):
        sweep_partials(root)
        doc = {"gonio_version": gonio_version(), "cells": [c.as_dict() for c in cells]}
        write_atomic(root / "study.json", lambda tmp: tmp.write_text(json.dumps(doc, indent=2) + "\n"))
        prints = {c.key: cell_fingerprint(c) for c in cells}
        result = StudyResult()
        todo = [c for c in cells if not is_done(read_record(root, c.key), prints[c.key])]
        result.skipped = [c.key for c in cells if c not in todo]
        say(f"{len(cells)} cells, {len(result.skipped)} already done; running {len(todo)} into {root}")
        # The longest first (adaptive sweeps, dense grids), so no worker is left with one at the end.
        tasks = sorted((Task(c.key, run_cell, (c, str(root), prints[c.key], keep_runs),
                             priority=c.size * (3 if c.kind == "adaptive" else 1)) for c in todo),
                       key=lambda t: -t.priority)  # fmt: skip
        try:
            if serial:
                _serial(tasks, progress, len(cells), len(result.skipped))
            elif todo and client is not None:
                run_tasks(client, tasks, desc="study", progress=progress, total=len(cells), initial=len(result.skipped))
            elif todo:
                with cluster_client(cluster, say) as c:
                    run_tasks(c, tasks, desc="study", progress=progress, total=len(cells), initial=len(result.skipped))
        finally:
            records = {c.key: r for c in cells
                       if (r := read_record(root, c.key)) is not None and r.get("fingerprint") == prints[c.key]}
            result.ran = [c.key for c in todo if records.get(c.key, {}).get("status") == "done"]
            result.failed = {k: str(r.get("error")) for k, r in records.items() if r.get("status") == "failed"}
            result.failed |= {c.key: "never finished (a worker lost it too often, or the study was stopped)"
                              for c in todo if c.key not in records}  # fmt: skip
            _write(root, cells, _gather(cells, records, result), result)
    return result


def _serial(tasks: Sequence[Task], progress: bool, total: int, initial: int) -> None:
    """The same tasks one after the other in this process (the baseline a cluster is measured against)."""
    from tqdm import tqdm

    with tqdm(total=total, initial=initial, desc="study (serial)", unit="task", disable=not progress) as bar:
        for t in tasks:
            t.fn(*t.args)
            bar.update(1)
