"""What makes a batch's tasks idempotent: per-task records, outputs swapped in whole, partial attempts swept away.

A task writes its outputs into a fresh temporary directory beside their final place (``.tmp-<key>-<id>``),
then swaps it in with renames, then writes its record ``.tasks/<key>.json`` atomically: the record is the
last thing written, so a record that says "done" means the outputs are complete. A worker killed at any
point leaves at worst a temporary directory, which no reader mistakes for output and the next batch removes;
the rescheduled task simply does everything again. Running a task twice (a restart, a rescheduling) gives
the same outputs.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import math
import os
import shutil
import socket
import uuid
from collections.abc import Iterator
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from acquisition.files.atomic import write_atomic
from analysis.result import AnalysisError

TASKS = ".tasks"
LOCK = ".lock"
_PARTIAL = (".tmp-", ".old-")


def record_path(out: Path, key: str) -> Path:
    """Where the record of task ``key`` lives in the batch directory ``out``."""
    return out / TASKS / f"{key}.json"


def write_record(out: Path, key: str, doc: dict[str, Any]) -> Path:
    """Write the record of task ``key`` atomically (JSON; inf and NaN as null)."""
    text = json.dumps(_finite(doc), indent=2, allow_nan=False) + "\n"
    return write_atomic(record_path(out, key), lambda tmp: tmp.write_text(text, encoding="utf-8"))


def _finite(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def read_record(out: Path, key: str) -> dict[str, Any] | None:
    """The record of task ``key``, or None if there is none or it cannot be read (then the task runs again)."""
    try:
        doc = json.loads(record_path(out, key).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) else None


def is_done(record: dict[str, Any] | None, fingerprint: str) -> bool:
    """Whether a record says its task finished on exactly this fingerprint (a failed task is not done)."""
    return record is not None and record.get("status") == "done" and record.get("fingerprint") == fingerprint


def worker_name() -> str:
    """host:pid of this process (where a task ran)."""
    return f"{socket.gethostname()}:{os.getpid()}"


def utc_now() -> str:
    """The current time, ISO 8601 in UTC."""
    return datetime.now(UTC).isoformat()


@contextlib.contextmanager
def staged_dir(final: Path) -> Iterator[Path]:
    """Yield an empty temporary directory beside ``final``; on success it replaces ``final`` whole.

    On an exception the temporary directory is removed and ``final`` is untouched.
    """
    tmp = final.parent / f"{_PARTIAL[0]}{final.name}-{uuid.uuid4().hex[:12]}"
    tmp.mkdir(parents=True)
    try:
        yield tmp
        swap_in(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def swap_in(tmp: Path, final: Path) -> None:
    """Put directory ``tmp`` in the place of ``final`` (which may exist): two renames, the old one then removed."""
    for _ in range(10):  # another attempt of the same task may be swapping at the same moment
        old = final.parent / f"{_PARTIAL[1]}{final.name}-{uuid.uuid4().hex[:12]}"
        try:
            os.rename(final, old)
        except FileNotFoundError:
            old = None  # type: ignore[assignment]
        try:
            os.rename(tmp, final)
        except OSError:
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
            continue
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
        return
    raise OSError(f"{final}: could not be replaced by {tmp} (another process keeps recreating it)")


def sweep_partials(out: Path) -> list[Path]:
    """Remove what killed attempts left in ``out`` (temporary and replaced directories); returns what went."""
    gone = []
    if out.is_dir():
        for p in out.iterdir():
            if p.is_dir() and p.name.startswith(_PARTIAL):
                shutil.rmtree(p, ignore_errors=True)
                gone.append(p)
    return gone


@contextlib.contextmanager
def batch_lock(out: Path) -> Iterator[None]:
    """Hold OUT/.lock for the length of a batch: two batches writing one directory would sweep each other's work."""
    fd = os.open(out / LOCK, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = (out / LOCK).read_text(encoding="utf-8", errors="replace").strip() or "another process"
            raise AnalysisError(f"--out {out}: another batch is writing there ({holder}); wait for it or use another "
                             "directory") from None  # fmt: skip
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"batch of {worker_name()} since {utc_now()}".encode(), 0)
        yield
    finally:
        os.close(fd)
