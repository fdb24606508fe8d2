"""One input of ``gonio batch analyze`` as one task: the analysis ``gonio analyze`` does, written whole or not at all.

The task calls exactly what ``gonio analyze`` calls (``load_and_fit``, then ``write_report``) with the same
arguments, so its outputs are the same bytes; it writes them into a staged directory that replaces
``OUT/<key>`` whole, then its record (analysis/batch/records.py). Any error of the input (a corrupt run, an
unreadable MERL file, too few points) becomes a "failed" record naming it, never an exception that would
stop the batch. A run recorded before gonio wrote Parquet gets its ``samples.parquet`` here, beside its CSV.
"""

from __future__ import annotations

import csv
import json
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

from analysis.analyze import fit_json, load_and_fit, write_report
from analysis.batch.inputs import AnalyzeSettings, BatchInput
from analysis.batch.records import staged_dir, utc_now, worker_name, write_record
from analysis.exports.write import FILES
from analysis.ladder import parse_models
from analysis.result import Analysis
from rig.run.storage.store import MANIFEST
from rig.run.tables.parquet import PARQUET_NAME, write_beside

#: A test's hook: called with (key, stage) at "started" and at "written" (outputs staged, not yet in place).
Probe = Callable[[str, str], None]


def _outputs(final: Path, out: Path) -> dict[str, str]:
    rel = final.relative_to(out)
    found = {"dir": str(rel), "report": str(rel / "index.html"), "fit_json": str(rel / "fit.json")}
    for kind, name in FILES.items():
        if (final / "export" / name).is_file():
            found[kind] = str(rel / "export" / name)
    return found


def _samples_parquet(inp: BatchInput) -> str | None:
    """The run's samples.parquet (written here from its CSV for a run older than the Parquet copy), or None."""
    run = Path(inp.source)
    table, parquet = run / "samples.csv", run / PARQUET_NAME
    if inp.kind != "run" or not table.is_file():
        return None
    if not parquet.is_file():
        with open(table, newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
        if write_beside(table, rows) is None:  # a read-only archive, say: warned, and the catalogue says None
            return None
    return str(parquet)


def _run_metadata(inp: BatchInput) -> dict[str, Any]:
    if inp.kind != "run":
        return {}
    try:
        manifest = json.loads((Path(inp.source) / MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return {"created_utc": manifest.get("created_utc"), "run_gonio_version": manifest.get("gonio_version")}


def summarise(a: Analysis) -> dict[str, Any]:
    """The numbers of an analysis the catalogue holds: the chosen model, its parameters, errors and goodness of fit."""
    doc = fit_json(a)
    chosen = next(c for c in doc["candidates"] if c["name"] == doc["chosen"])
    keys = ("chi2", "dof", "reduced_chi2", "p_value", "aic", "bic", "noise_reached")
    return {
        "chosen": doc["chosen"], "model_class": doc["model"]["model"], "model": doc["model"],
        "params": chosen["params"], "std_errors": chosen["std_errors"], **{k: chosen[k] for k in keys},
        "n_samples": doc["n_samples"], "criterion": doc["criterion"], "reason": doc["reason"],
        "n_warnings": len(doc["warnings"]), "source": doc["source"],
    }  # fmt: skip


def analyze_input(
    inp: BatchInput, settings: AnalyzeSettings, out: str, fingerprint: str, probe: Probe | None = None
) -> dict[str, Any]:
    """Analyse one input into OUT/<key> as ``gonio analyze`` would, record it in OUT/.tasks; returns the record."""
    root = Path(out)
    wall, cpu = time.perf_counter(), time.process_time()
    record: dict[str, Any] = {"key": inp.key, "source": inp.source, "kind": inp.kind, "fingerprint": fingerprint,
                              "worker": worker_name(), "started_utc": utc_now()}  # fmt: skip
    if probe is not None:
        probe(inp.key, "started")
    try:
        a = load_and_fit(
            inp.source, models=parse_models(settings.models) if settings.models else None, loss=settings.loss,
            starts=settings.starts, samples=settings.samples if inp.kind == "merl" else None, seed=settings.seed,
            compare=settings.compare, errors=settings.errors,
        )  # fmt: skip
        fitted = time.perf_counter()
        final = root / inp.key
        with staged_dir(final) as tmp:
            write_report(a, tmp, y_scale=settings.y_scale, merl=settings.merl, svg=settings.svg)
            if probe is not None:
                probe(inp.key, "written")
        record |= {"status": "done", "error": None, "outputs": _outputs(final, root),
                   "samples_parquet": _samples_parquet(inp), "result": summarise(a), "run": _run_metadata(inp),
                   "timing": {"fit_s": sum(a.fit_times_s.values()), "candidates_s": a.fit_times_s,
                              "report_s": time.perf_counter() - fitted}}  # fmt: skip
    except Exception as exc:  # an input's failure is its record, never the batch's end
        record |= {"status": "failed", "error": f"{type(exc).__name__}: {exc}",
                   "traceback": traceback.format_exc(limit=8), "run": _run_metadata(inp), "timing": {}}  # fmt: skip
    record["timing"] |= {"wall_s": time.perf_counter() - wall, "cpu_s": time.process_time() - cpu}
    record["finished_utc"] = utc_now()
    write_record(root, inp.key, record)
    return record
