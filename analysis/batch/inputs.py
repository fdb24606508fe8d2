"""A batch's inputs: what each is, the name of its output directory, and the fingerprint that says it is done.

An input is named by the path the user gave (that string is what ``fit.json`` records, exactly as with
``gonio analyze``); its key is the name of its directory in the batch's output: the run directory's name or
the MERL file's stem, cleaned to letters, digits, ``_ . -``, with a short hash of the absolute path added
where two inputs would share one. The fingerprint covers what the analysis reads (the run's manifest,
journal, status and table, or the MERL file, and a --compare file) by size and modification time, the
analysis settings and gonio's version: a restarted batch skips an input whose fingerprint matches its
finished record, and re-analyses it when any of those changed (a re-calibrated run, other settings).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from analysis.result import AnalysisError
from model.version import gonio_version
from rig.run.storage.store import JOURNAL, MANIFEST, STATUS

#: The files of a run directory that an analysis reads (samples.parquet is derived, and may be written by a batch).
RUN_FILES = (MANIFEST, JOURNAL, STATUS, "samples.csv")
_UNSAFE = re.compile(r"[^A-Za-z0-9_.\-]+")


@dataclass(frozen=True)
class AnalyzeSettings:
    """The options of ``gonio analyze`` a batch applies to every input (``samples`` to MERL inputs only)."""

    models: str | None = None
    loss: str = "l2"
    starts: int = 4
    samples: int | None = None
    seed: int = 0
    compare: str | None = None
    y_scale: str = "auto"
    merl: bool = False
    errors: str = "total"
    svg: bool = False

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (batch.json, fingerprints)."""
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class BatchInput:
    """One input: the path as given, its key (its output directory's name) and kind ("run", "merl" or "missing")."""

    source: str
    key: str
    kind: str


def _kind(path: Path) -> str:
    return "run" if path.is_dir() else "merl" if path.is_file() else "missing"


def _stem(path: Path) -> str:
    name = path.name if path.is_dir() or not path.suffix else path.stem
    clean = _UNSAFE.sub("_", name).lstrip("._-")
    return clean or "input"


def batch_inputs(sources: Sequence[str | os.PathLike[str]]) -> list[BatchInput]:
    """The inputs in the order given, each with a unique key; ValueError if an input is listed twice."""
    paths = [str(s) for s in sources]
    if not paths:
        raise AnalysisError("batch: no inputs (expected run directories or MERL .binary files)")
    seen: dict[str, str] = {}
    for p in paths:
        real = os.path.realpath(p)
        if real in seen:
            raise AnalysisError(f"batch: {p!r} is listed twice (also as {seen[real]!r})")
        seen[real] = p
    stems = [_stem(Path(p)) for p in paths]
    out = []
    for p, stem in zip(paths, stems, strict=True):
        key = stem
        if stems.count(stem) > 1:  # e.g. lab-a/gold and lab-b/gold: keyed apart by where they are
            key = f"{stem}-{hashlib.sha1(os.path.realpath(p).encode()).hexdigest()[:8]}"
        out.append(BatchInput(p, key, _kind(Path(p))))
    return out


def _stat(path: Path) -> list[Any]:
    try:
        st = path.stat()
    except OSError:
        return [path.name, None, None]
    return [path.name, st.st_size, st.st_mtime_ns]


def fingerprint(inp: BatchInput, settings: AnalyzeSettings) -> str:
    """A digest of what the analysis of ``inp`` reads and how: equal digests mean the same analysis."""
    path = Path(inp.source)
    files = [_stat(path / name) for name in RUN_FILES] if inp.kind == "run" else [_stat(path)]
    if settings.compare is not None:
        files.append(_stat(Path(settings.compare)))
    doc = {"source": os.path.realpath(path), "kind": inp.kind, "files": files, "settings": settings.as_dict(),
           "gonio": gonio_version()}  # fmt: skip
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()
