"""Sources of an analysis: a run directory, an adaptive sweep, a samples table or a MERL file, as fit samples.

A finished run is read from its ``samples.csv``; a run that stopped (or is still running) from its journal
through the same ``rig.run.tables.samples.build_rows`` the runner uses at the end, so an unfinished run is analysed
exactly as far as it got, with a warning saying so; an adaptive sweep's directory (``adaptive.json``) from
its merged ``samples.csv``, or, unfinished, from every round's run read as above; a samples table
(``samples.csv`` or ``samples.parquet``, e.g. an adaptive sweep's) on its own, or through the run or sweep
directory that holds it; a MERL ``.binary`` file by drawing random bins (``Samples.from_merl``, errors
assumed), which is how MERL materials are imported for fitting and comparison.
"""

from __future__ import annotations

import csv
import struct
import warnings
from pathlib import Path
from typing import Any

from analysis.result import AnalysisError, Log, Reference, SourceSummary
from model.fit.samples import FitError, Samples
from model.merl import SHAPE, MerlFormatError, MerlTable, read_merl
from rig.run.adaptive.state import AdaptiveStateError, is_adaptive, read_state, rig_of
from rig.run.config.files import material_from
from rig.run.config.schema import run_metadata
from rig.run.session import configs_of, reference_settings
from rig.run.storage.journal import check_records
from rig.run.storage.store import JOURNAL, MANIFEST, RunStore, RunStoreError
from rig.run.tables.samples import build_rows

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


def _empty_table(table: Path, in_run: bool = True) -> str:
    """Why ``table`` has no rows (no header, or a header alone), and for a run's table how to recover them."""
    try:
        text = table.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        return f"{table}: cannot read the samples table: {exc}"
    if not text.strip():
        what = "is empty (no header, no rows)"
    else:
        what = "has a header but no rows"
    if not in_run:
        return f"{table}: {what}; expected a samples table with a header line and one row per sample"
    return (f"{table}: {what}: the table was cut short or overwritten; its run's journal "
            f"{table.parent / JOURNAL} still holds the points: remove {table.name} and analyse the run directory "
            f"{table.parent} to rebuild the rows from the journal")  # fmt: skip


def _run_rows(path: Path) -> tuple[RunStore, Any, Any, dict[str, Any], list[dict[str, Any]]]:
    """(store, rig, sweep, status, rows) of a run directory: its table, or its journal if unfinished."""
    try:
        store = RunStore.read(path)
        status = store.status()
        rig, sweep = configs_of(store)
        records = store.records_to_read()  # only read here: copying a long journal would cost the analysis
        check_records(records, path / JOURNAL)
    except (RunStoreError, ValueError, KeyError) as exc:
        raise AnalysisError(f"{path}: not a readable run directory: {exc}") from exc
    table = path / "samples.csv"
    if table.is_file():
        rows: list[dict[str, Any]] = list(store.read_table())
        if not rows:  # the journal may be full: the table, not the run, is what is empty
            raise AnalysisError(_empty_table(table))
        _check_complete(rows, table)
    elif status["state"] == "finished":
        raise AnalysisError(f"{path}: the run is marked finished but has no samples.csv ({table})")
    else:  # a stopped or running run has only its journal: build the table the runner would have written
        ref = reference_settings(rig)
        cosine = bool(store.manifest.get("options", {}).get("include_cosine", False))
        rows = build_rows(records, rig.geometry.joint_names, albedo=ref.albedo if ref else None,
                          albedo_std_error=ref.albedo_std_error if ref else 0.0, include_cosine=cosine)  # fmt: skip
    return store, rig, sweep, status, rows


def _samples(rows: list[dict[str, Any]], path: Path, errors: str) -> Samples:
    if not rows:
        raise AnalysisError(f"{path}: no measured points to analyse")
    try:
        return Samples.from_table_rows(rows, source=str(path), errors=errors)
    except FitError as exc:
        raise AnalysisError(f"{path}: cannot read the samples: {exc}") from exc


def _truth(rig: Any, rows: list[dict[str, Any]], path: Path) -> tuple[str | None, list[Reference]]:
    """The simulated material's description and, as a reference, the material itself (simulated rigs only)."""
    if rig.file.link.kind != "simulated":
        return None, []
    material = _describe_material(rig.file.simulation.material)
    try:
        # The simulated tile's albedo is exactly as stated: against the truth, its error is not an error.
        exact = Samples.from_table_rows(rows, source=str(path), errors="readings").std_error
        return material, [Reference("simulated material (truth)", material_from(rig), exact)]
    except ValueError as exc:
        warnings.warn(f"{path}: the simulated material cannot be built: {exc}", stacklevel=2)
        return material, []


def load_run(path: Path, log: Log, errors: str = "total") -> tuple[SourceSummary, Samples, list[Reference]]:
    """A run directory's samples (its table, or its journal if unfinished), summary and the simulated truth."""
    store, rig, sweep, status, rows = _run_rows(path)
    if not rows:
        raise AnalysisError(f"{path}: no measured points to analyse (journal {path / JOURNAL} holds none)")
    samples = _samples(rows, path, errors)
    material, refs = _truth(rig, rows, path)
    summary = SourceSummary(
        "run", path, status["state"], status.get("reason"), len(rows), store.manifest.get("points"),
        len(store.manifest.get("unreachable", [])), int(samples.lower_bound.sum()), sweep.file.sweep.kind,
        rig.file.name, sweep.file.name, material, samples.notes,
        tuple(store.manifest.get("metadata", run_metadata(rig.file, sweep.file)).items()),
    )  # fmt: skip
    log(f"loaded run {path}: {len(rows)} points ({status['state']}), {samples.n} usable samples")
    return summary, samples, refs


def load_adaptive(path: Path, log: Log, errors: str = "total") -> tuple[SourceSummary, Samples, list[Reference]]:
    """An adaptive sweep's samples: its merged table, or every round so far if it did not finish."""
    try:
        state = read_state(path)
        rig = rig_of(state, path)
    except (AdaptiveStateError, ValueError) as exc:
        raise AnalysisError(f"{path}: not a readable adaptive sweep: {exc}") from exc
    table = path / "samples.csv"
    finished = state["state"] == "finished" and table.is_file()
    if finished:
        rows = _csv_rows(table)
        if not rows:  # its rounds' runs still hold the points
            raise AnalysisError(f"{_empty_table(table, in_run=False)}; the rounds' runs {path}/round-* still hold "
                                "every point: remove it and analyse the sweep's directory to read them")  # fmt: skip
    else:  # every round's run, the last one as far as its journal goes
        rows = []
        for number, directory in enumerate(sorted(p for p in path.glob("round-*") if (p / MANIFEST).is_file())):
            rows += [{**row, "round": number} for row in _run_rows(directory)[4]]
    samples = _samples(rows, path, errors)
    material, refs = _truth(rig, rows, path)
    budget = state["settings"].get("budget")
    rounds = len({str(r.get("round")) for r in rows})
    # The budget counts captures (poses): in image mode one capture is a row per tile.
    captures = len({(str(r.get("round")), str(r.get("index"))) for r in rows})
    summary = SourceSummary(
        "adaptive", path, "finished" if finished else "stopped",
        None if finished else f"interrupted after {rounds} round(s); gonio adaptive --resume {path} continues it",
        captures, budget, 0, int(samples.lower_bound.sum()), "adaptive", rig.file.name,
        f"adaptive sweep, model {state['model']}", material, samples.notes, tuple(state.get("metadata", {}).items()),
    )  # fmt: skip
    log(f"loaded adaptive sweep {path}: {captures} captures in {rounds} round(s), {samples.n} usable samples")
    return summary, samples, refs


def _csv_rows(table: Path) -> list[dict[str, Any]]:
    try:
        with open(table, encoding="utf-8", newline="") as fh:
            rows: list[dict[str, Any]] = list(csv.DictReader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise AnalysisError(f"{table}: cannot read the samples table: {exc}") from exc
    _check_complete(rows, table)
    return rows


def load_table(path: Path, log: Log, errors: str = "total") -> tuple[SourceSummary, Samples, list[Reference]]:
    """A samples table (samples.csv or samples.parquet): through its run or adaptive sweep where it has one."""
    parent = path.parent
    if path.stem == "samples" and is_adaptive(parent):
        return load_adaptive(parent, log, errors)
    if path.name == "samples.csv" and (parent / MANIFEST).is_file():
        return load_run(parent, log, errors)
    if path.suffix == ".parquet":
        try:
            import pyarrow.parquet as pq

            rows: list[dict[str, Any]] = pq.read_table(path).to_pylist()
        except (OSError, ValueError, ImportError) as exc:
            raise AnalysisError(f"{path}: cannot read the Parquet samples table: {exc}") from exc
    else:
        rows = _csv_rows(path)
        if not rows:
            raise AnalysisError(_empty_table(path, in_run=False))
    samples = _samples(rows, path, errors)
    summary = SourceSummary("table", path, "file", measured=len(rows), lower_bound=int(samples.lower_bound.sum()),
                            notes=samples.notes)  # fmt: skip
    log(f"loaded samples table {path}: {len(rows)} rows, {samples.n} usable samples")
    return summary, samples, []


def source_kind(path: Path) -> str:
    """What ``path`` is as an analysis source: run, adaptive, table or merl (or missing / unknown, with why)."""
    if path.is_dir():
        if (path / MANIFEST).is_file():
            return "run"
        if is_adaptive(path):
            return "adaptive"
        return "unknown"
    if not path.exists():
        return "missing"
    if _merl_header(path):  # by content: a MERL file is one whatever its name
        return "merl"
    return "table" if path.suffix in (".csv", ".parquet") else "unknown file"


#: What gonio analyze reads, for the message about a file it cannot.
ACCEPTED = ("a run directory (written by gonio run), an adaptive sweep's directory (gonio adaptive), a samples "
            "table (.csv or .parquet) or a MERL .binary file (a 12-byte header 90 90 180, then 3 x 1,458,000 doubles)")


def _merl_header(path: Path) -> bool:
    """Whether ``path`` starts with a MERL table's header: its dimensions 90, 90, 180 as little-endian int32."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(12)
    except OSError:
        return False
    return len(head) == 12 and struct.unpack("<3i", head) == SHAPE


def unknown_file(path: Path) -> str:
    """Why ``path`` is no analysis source: what it looks like, and what gonio analyze reads."""
    try:
        head = path.read_bytes()[:64] if path.is_file() else b""
    except OSError:
        head = b""
    looks = ""
    if path.suffix == ".toml" or head.lstrip().startswith((b"[", b"#", b"name")):
        looks = " (it looks like a TOML rig or sweep file: analyse the run directory gonio run made with it)"
    elif path.suffix == ".binary":
        dims = struct.unpack("<3i", head[:12]) if len(head) >= 12 else None
        found = f"its header is {dims}" if dims else f"it has {len(head)} bytes, too few for a header"
        looks = f" (named .binary, but not a MERL table: {found}, a MERL table's is {SHAPE})"
    return f"{path}: not something gonio analyze reads{looks}; SOURCE: expected {ACCEPTED}"


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
