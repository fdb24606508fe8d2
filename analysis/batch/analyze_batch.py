"""``gonio batch analyze``: every input fitted, reported and exported as one task on a Dask cluster, then catalogued.

OUT holds one directory per input (``OUT/<key>``: exactly what ``gonio analyze --out OUT/<key>`` writes),
``catalogue.parquet`` (analysis/batch/catalogue.py), ``batch.json`` (the settings and the inputs) and the
task records in ``OUT/.tasks``. Inputs whose record says done on the same fingerprint are skipped, so a batch
stopped in any way (Ctrl-C, a lost cluster, a killed client) and started again does only what is left;
failed inputs are tried again. The catalogue is written at the end, also when the batch is interrupted.

Paths: on the local cluster a batch starts itself, the inputs are passed as given (the workers share this
process's working directory), so ``fit.json`` records the same source string as ``gonio analyze`` would. On
an existing cluster (``--scheduler``, or a ``client`` passed in) the workers may run elsewhere: every path is
made absolute, and must be the same path on every machine (a shared file system).
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from acquisition.files.atomic import write_atomic
from analysis.batch.analyze_task import Probe, analyze_input
from analysis.batch.catalogue import write_catalogue
from analysis.batch.cluster import ClusterSettings, Task, cluster_client, run_tasks
from analysis.batch.inputs import AnalyzeSettings, BatchInput, batch_inputs, fingerprint
from analysis.batch.records import batch_lock, is_done, read_record, sweep_partials, utc_now, write_record
from analysis.result import AnalysisError, Log
from model.version import gonio_version


@dataclass
class BatchResult:
    """What a batch did: keys analysed now, skipped as done before, failed (with their errors); the catalogue."""

    catalogue: Path
    analysed: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    records: dict[str, dict[str, Any]] = field(default_factory=dict)

    def summary(self) -> str:
        """One line: how many inputs were analysed, skipped and failed."""
        n = len(self.analysed) + len(self.skipped) + len(self.failed)
        return (f"{n} inputs: {len(self.analysed)} analysed, {len(self.skipped)} already done (skipped), "
                f"{len(self.failed)} failed")  # fmt: skip


def _check_settings(s: AnalyzeSettings) -> None:
    """Settings errors are the batch's, not each input's: refuse them before any task runs."""
    from analysis.ladder import parse_models
    from model.fit.solve import LOSSES

    if s.models:
        parse_models(s.models)
    if s.loss not in LOSSES:
        raise AnalysisError(f"--loss {s.loss!r}: expected one of {', '.join(LOSSES)}")
    if s.errors not in ("total", "point"):
        raise AnalysisError(f"--errors {s.errors!r}: expected 'total' or 'point'")
    if s.compare is not None and not Path(s.compare).is_file():
        raise AnalysisError(f"--compare {s.compare}: not found (expected a MERL .binary file)")


def _killed(inp: BatchInput, fp: str, exc: BaseException) -> dict[str, Any]:
    """The record of a task that never returned (its workers died under it, or Dask failed it)."""
    return {"key": inp.key, "source": inp.source, "kind": inp.kind, "fingerprint": fp, "status": "failed",
            "error": f"{type(exc).__name__}: {exc}", "timing": {}, "finished_utc": utc_now()}  # fmt: skip


def batch_analyze(
    sources: Sequence[str | os.PathLike[str]],
    out: str | os.PathLike[str],
    settings: AnalyzeSettings | None = None,
    *,
    cluster: ClusterSettings | None = None,
    client: Any = None,
    progress: bool = True,
    log: Log | None = None,
    probe: Probe | None = None,
) -> BatchResult:
    """Analyse every source into OUT/<key> on a Dask cluster (``client``, or one opened from ``cluster``)."""
    s = settings or AnalyzeSettings()
    _check_settings(s)
    say = log or (lambda _: None)
    remote = client is not None or (cluster is not None and cluster.scheduler is not None)
    given = [os.path.abspath(p) for p in sources] if remote else [str(p) for p in sources]
    if remote and s.compare is not None:
        s = AnalyzeSettings(**{**s.as_dict(), "compare": os.path.abspath(s.compare)})
    inputs = batch_inputs(given)
    root = Path(out).absolute()
    if root.exists() and not root.is_dir():
        raise AnalysisError(f"--out {root}: exists and is not a directory")
    root.mkdir(parents=True, exist_ok=True)
    with batch_lock(root):
        return _run(inputs, root, s, cluster, client, progress, say, probe)


def _run(inputs: list[BatchInput], root: Path, s: AnalyzeSettings, cluster: ClusterSettings | None, client: Any,
         progress: bool, say: Log, probe: Probe | None) -> BatchResult:  # fmt: skip
    sweep_partials(root)  # what killed attempts of an earlier batch left
    doc = {"gonio_version": gonio_version(), "settings": s.as_dict(), "inputs": [vars(i) for i in inputs]}
    write_atomic(root / "batch.json", lambda tmp: tmp.write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8"))
    prints = {i.key: fingerprint(i, s) for i in inputs}
    result = BatchResult(root / "catalogue.parquet")
    todo = []
    for inp in inputs:
        rec = read_record(root, inp.key)
        if is_done(rec, prints[inp.key]):
            result.skipped.append(inp.key)
        else:
            todo.append(inp)
    say(f"{len(inputs)} inputs, {len(result.skipped)} already done; analysing {len(todo)} into {root}")
    by_key = {i.key: i for i in inputs}
    try:
        if todo:
            tasks = [Task(i.key, analyze_input, (i, s, str(root), prints[i.key], probe)) for i in todo]
            if client is not None:
                got = run_tasks(client, tasks, desc="analysing", progress=progress, total=len(inputs),
                                initial=len(result.skipped))  # fmt: skip
            else:
                with cluster_client(cluster, say) as c:
                    got = run_tasks(c, tasks, desc="analysing", progress=progress, total=len(inputs),
                                    initial=len(result.skipped))  # fmt: skip
            for key, res in got.items():
                if isinstance(res, BaseException):
                    write_record(root, key, _killed(by_key[key], prints[key], res))
                elif res.get("status") == "done":
                    result.analysed.append(key)
    finally:
        sweep_partials(root)
        # A record of other inputs or settings (an older batch into this OUT) says nothing about this one.
        records = {i.key: rec for i in inputs
                   if (rec := read_record(root, i.key)) is not None and rec.get("fingerprint") == prints[i.key]}
        result.records = records
        result.failed = {k: str(r.get("error")) for k, r in records.items() if r.get("status") == "failed"}
        write_catalogue(root, inputs, records, s)
    return result
