"""Sources of an analysis: a run directory or a MERL file, loaded into the samples a fit reads.

A finished run is read from its ``samples.csv``; a run that stopped (or is still running) from its journal
through the same ``rig.run.table.build_rows`` the runner uses at the end, so an unfinished run is analysed
exactly as far as it got, with a warning saying so; a MERL ``.binary`` file by drawing random bins
(``Samples.from_merl``, errors assumed), which is how MERL materials are imported for fitting and comparison.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

from analysis.result import AnalysisError, Log, Reference, SourceSummary
from model.fit.samples import FitError, Samples
from model.merl import MerlFormatError, MerlTable, read_merl
from rig.run.config import material_from
from rig.run.config_schema import run_metadata
from rig.run.journal import check_records
from rig.run.session import configs_of, reference_settings
from rig.run.store import JOURNAL, RunStore, RunStoreError
from rig.run.table import build_rows

DEFAULT_MERL_SAMPLES = 20_000


def _describe_material(table: Any) -> str:
    params = ", ".join(f"{k}={list(v) if isinstance(v, tuple) else v}" for k, v in table.parameters().items())
    return f"{table.model}({params})"


def _check_complete(rows: list[dict[str, Any]], table: Path) -> None:
    """Refuse a table with a short or long row (a copy cut off, a stray comma): its values would be misread."""
    for number, row in enumerate(rows, 2):  # line 1 is the header
        if None in row or any(v is None for v in row.values()):
            short = [k for k, v in row.items() if v is None and k is not None]
            what = f"no {', '.join(short[:3])}{', ...' if len(short) > 3 else ''}" if short else "extra fields"
            raise AnalysisError(f"{table}: line {number} has {what}: the table is cut short or corrupt (the "
                                f"journal {table.parent / JOURNAL} still holds every point)")  # fmt: skip


def load_run(path: Path, log: Log, errors: str = "total") -> tuple[SourceSummary, Samples, list[Reference]]:
    """A run directory's samples (its table, or its journal if unfinished), summary and the simulated truth."""
    try:
        store = RunStore.read(path)
        status = store.status()
        rig, sweep = configs_of(store)
        records = store.records()
        check_records(records, path / JOURNAL)
    except (RunStoreError, ValueError, KeyError) as exc:
        raise AnalysisError(f"{path}: not a readable run directory: {exc}") from exc
    table = path / "samples.csv"
    if table.is_file():
        rows: list[dict[str, Any]] = list(store.read_table())
        _check_complete(rows, table)
    elif status["state"] == "finished":
        raise AnalysisError(f"{path}: the run is marked finished but has no samples.csv ({table})")
    else:  # a stopped or running run has only its journal: build the table the runner would have written
        ref = reference_settings(rig)
        cosine = bool(store.manifest.get("options", {}).get("include_cosine", False))
        rows = build_rows(records, rig.geometry.joint_names, albedo=ref.albedo if ref else None,
                          albedo_std_error=ref.albedo_std_error if ref else 0.0, include_cosine=cosine)  # fmt: skip
    if not rows:
        raise AnalysisError(f"{path}: no measured points to analyse (journal {path / JOURNAL} holds none)")
    try:
        samples = Samples.from_table_rows(rows, source=str(path), errors=errors)
    except FitError as exc:
        raise AnalysisError(f"{path}: cannot read the samples: {exc}") from exc
    refs, material = [], None
    if rig.file.link.kind == "simulated":
        material = _describe_material(rig.file.simulation.material)
        try:
            # The simulated tile's albedo is exactly as stated: against the truth, its error is not an error.
            exact = Samples.from_table_rows(rows, source=str(path), errors="readings").std_error
            refs.append(Reference("simulated material (truth)", material_from(rig), exact))
        except ValueError as exc:
            warnings.warn(f"{path}: the simulated material cannot be built: {exc}", stacklevel=2)
    summary = SourceSummary(
        "run", path, status["state"], status.get("reason"), len(rows), store.manifest.get("points"),
        len(store.manifest.get("unreachable", [])), int(samples.lower_bound.sum()), sweep.file.sweep.kind,
        rig.file.name, sweep.file.name, material, samples.notes,
        tuple(store.manifest.get("metadata", run_metadata(rig.file, sweep.file)).items()),
    )  # fmt: skip
    log(f"loaded run {path}: {len(rows)} points ({status['state']}), {samples.n} usable samples")
    return summary, samples, refs


def read_merl_source(path: Path, what: str) -> MerlTable:
    """A MERL table named on the command line as ``what`` (SOURCE or --compare); AnalysisError names the path."""
    expect = f"{what}: expected a MERL .binary file" + (" or a run directory" if what == "SOURCE" else "")
    if not path.is_file():
        raise AnalysisError(f"{path}: not found ({expect})")
    try:
        return read_merl(path)
    except (MerlFormatError, OSError) as exc:
        msg = str(exc) if str(path) in str(exc) else f"{path}: {exc}"
        raise AnalysisError(f"{msg} ({expect})") from exc


def load_merl(path: Path, n: int, seed: int, log: Log) -> tuple[SourceSummary, Samples, list[Reference]]:
    """``n`` random bins of a MERL file (seeded) as samples, its summary, and the table itself as a reference."""
    table = read_merl_source(path, "SOURCE")
    try:
        samples = Samples.from_merl(table, n, seed)
    except FitError as exc:
        raise AnalysisError(f"{path}: {exc}") from exc
    log(f"loaded MERL table {path}: {samples.n} random bins (seed {seed})")
    return (
        SourceSummary("merl", path, "file", measured=samples.n, notes=samples.notes),
        samples,
        [Reference(f"MERL table {path.name} (source)", table)],
    )
