"""The run store: one directory per run (docs/architecture.md describes its place in a run).

A run directory holds manifest.json (the caller's manifest plus "format", "created_utc", "gonio_version"),
journal.jsonl (append-only, one JSON object with a "kind" per line), lock (flock()ed by the one writer; its
content is informational), status.json (absent while running), images/<name>.exr and tables (samples.csv).

Durability: a journal record is one os.write on an O_APPEND descriptor, fsynced before append() returns.
Every other file is written to a temporary file, fsynced and renamed (acquisition.files.atomic.atomic_path), then
its directory is fsynced so the rename survives a power loss. A SIGKILL during an append can leave a torn
last line: open() cuts it off (that point is measured again); a bad line anywhere else is corruption.
NaN and inf are refused with an error naming the key: JSON cannot spell them, and a missing value should
be None on purpose, not produced by accident.

One file past 400 lines on purpose: creation, locking, the journal's appends and the status are one
crash-safety story that reads best in one place; the formats it writes are in formats.py.
"""

from __future__ import annotations

import csv
import errno
import fcntl
import glob
import json
import os
import re
import shutil
import socket
import warnings
from collections.abc import Callable, Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Self

from numpy.typing import ArrayLike

from acquisition.files.atomic import atomic_path
from model.errors import InputError
from model.plain import json_copy, jsonable
from model.version import gonio_version
from rig.run.storage.formats import Float32Array, NotExactJson, csv_text, exact_json, parse_journal, read_exr, write_exr

FORMAT = "gonio-run/1"
MANIFEST, JOURNAL, LOCK, STATUS, IMAGES = "manifest.json", "journal.jsonl", "lock", "status.json", "images"
MaybeArray = ArrayLike | None
_RESERVED = ("format", "created_utc", "gonio_version")
_NAME_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]{0,127}")


class RunStoreError(InputError, RuntimeError):
    """A run directory or one of its files is missing, locked, corrupt, or the call would damage it."""


class RunLockedError(RunStoreError):
    """Another RunStore (this process or another) holds the run's lock; ``holder`` is the lock file's content."""

    def __init__(self, message: str, holder: Mapping[str, Any]) -> None:
        super().__init__(message)
        self.holder = dict(holder)


class RunStoreWarning(UserWarning):
    """Something was repaired on opening a run (a torn last journal line)."""


def _utc_now() -> str:
    return datetime.now(UTC).isoformat()



def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _check_empty(run: Path) -> None:
    """Refuse a directory that holds anything but a killed creation's leftovers (a free lock, an empty journal)."""
    if not run.exists():
        return
    if not run.is_dir():
        raise RunStoreError(f"{run}: exists and is not a directory")
    names = sorted(p.name for p in run.iterdir())
    if MANIFEST in names:
        raise RunStoreError(f"{run}: already holds a run ({MANIFEST}); to continue it: gonio resume {run} "
                            "(from Python: rig.run.session.resume_run); for a new run choose another directory")
    leftovers = set(names) <= {LOCK, JOURNAL} and (JOURNAL not in names or (run / JOURNAL).stat().st_size == 0)
    if names and leftovers and _lock_is_free(run / LOCK):
        # A creation by an older gonio killed before its manifest: nothing was measured; start afresh.
        for name in names:
            (run / name).unlink()
        return
    if names:
        raise RunStoreError(f"{run}: not empty ({', '.join(names[:5])}); a new run needs an empty directory")


def _cannot_create(run: Path, exc: OSError) -> OSError:
    """The OSError of a run directory that cannot be made, naming it (not the hidden staging sibling).

    An OSError, not a RunStoreError: a full disk, a read-only or virtual filesystem, a missing permission are
    the system's refusals (exit 74 with the path and the reason), not a mistake in the user's input.
    """
    failed = exc.filename if exc.filename is not None and not Path(exc.filename).name.startswith(".") else run
    what = "the run directory" if failed == run else f"the run directory {run}"
    return OSError(exc.errno, f"cannot create {what}: {exc.strerror or exc}", str(failed))


def _lock_is_free(lock: Path) -> bool:
    """Whether nobody holds ``lock`` (True also when it does not exist)."""
    try:
        fd = os.open(lock, os.O_RDONLY)
    except FileNotFoundError:
        return True
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return False
    finally:
        os.close(fd)
    return True


def _remove_abandoned(run: Path) -> None:
    """Delete staging directories of creations of ``run`` that were killed (their lock is free)."""
    for old in run.parent.glob(f".{glob.escape(run.name)}.creating-*"):
        if old.is_dir() and _lock_is_free(old / LOCK):
            shutil.rmtree(old, ignore_errors=True)


def _plain(value: Any, where: str, file: Path) -> Any:
    try:
        return jsonable(value, where)
    except ValueError as exc:
        raise RunStoreError(f"{file}: {exc}") from None


def _dumps(value: Any, **kw: Any) -> str:
    return json.dumps(value, allow_nan=False, ensure_ascii=True, **kw)


#: The journal line's encoder, made once (json.dumps with keywords builds one a call): the encoder json.dumps
#: builds from the same keywords, so the same text.
_encode_line = json.JSONEncoder(allow_nan=False, ensure_ascii=True, separators=(",", ":")).encode


def _hashable(value: Any) -> Any:
    return tuple(_hashable(v) for v in value) if isinstance(value, list) else value


class RunStore:
    """One run directory: manifest, journal, images, tables, status; writable while holding its lock."""

    def __init__(self, path: Path, *, writable: bool) -> None:
        self.path = path
        self.manifest: dict[str, Any] = {}
        self.previous_status: dict[str, Any] | None = None  # a "stopped" status cleared by open() on resume
        self._writable = writable
        self._lock_fd: int | None = None
        self._journal_fd: int | None = None
        self._journal_size = 0
        self._records: list[dict[str, Any]] = []
        self._broken: str | None = None
        self._finished = False

    @classmethod
    def create(cls, path: str | Path, manifest: Mapping[str, Any]) -> RunStore:
        """Create a new run in ``path`` (made if missing, else it must be empty) and take its lock.

        Creation is atomic: the run is assembled (lock, journal, manifest) in a hidden sibling directory and
        renamed into place, so a process killed at any instant leaves either a complete run or none (a
        leftover sibling is removed by the next creation of the same run).
        """
        run = Path(path)
        doc = _plain(manifest, "manifest", run / MANIFEST)
        if not isinstance(doc, dict) or any(k in doc for k in _RESERVED):
            raise RunStoreError(f"{run / MANIFEST}: expected a mapping without the keys {_RESERVED} (set here)")
        doc.update(format=FORMAT, created_utc=_utc_now(), gonio_version=gonio_version())
        parent = run.parent
        missing = [p for p in (parent, *parent.parents) if not p.exists()]
        try:
            blocking = next((p for p in (parent, *parent.parents) if p.exists() and not p.is_dir()), None)
            if blocking is not None:  # mkdir would say "File exists", which hides why
                raise NotADirectoryError(errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(blocking))
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise _cannot_create(run, exc) from exc
        for new in reversed(missing):  # make each new directory's entry durable in its parent
            _fsync_dir(new.parent)
        if not _lock_is_free(run / LOCK):
            cls(run, writable=True)._take_lock()  # raises RunLockedError naming the holder
        _check_empty(run)
        _remove_abandoned(run)
        staging = parent / f".{run.name}.creating-{os.getpid()}-{os.urandom(4).hex()}"
        try:
            staging.mkdir()
        except OSError as exc:
            raise _cannot_create(run, exc) from exc
        store = cls(staging, writable=True)
        try:
            store._take_lock()
            store._journal_fd = os.open(staging / JOURNAL, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_APPEND, 0o644)
            os.fsync(store._journal_fd)
            with atomic_path(staging / MANIFEST) as tmp:
                tmp.write_text(_dumps(doc, indent=2) + "\n", encoding="utf-8")
            _fsync_dir(staging)
            if run.is_dir() and not any(run.iterdir()):
                run.rmdir()  # rename(2) replaces an empty directory too, but not on every filesystem
            try:
                staging.rename(run)
            except OSError as exc:
                if exc.errno in (errno.EEXIST, errno.ENOTEMPTY):
                    raise RunStoreError(f"{run}: another process created a run here meanwhile") from None
                raise _cannot_create(run, exc) from exc
            _fsync_dir(parent)
        except BaseException:
            store.close()
            shutil.rmtree(staging, ignore_errors=True)
            raise
        store.path = run
        store.manifest = doc
        return store

    @classmethod
    def open(cls, path: str | Path) -> RunStore:
        """Open an existing run to resume it: take the lock, read the manifest, load (and repair) the journal."""
        store = cls._existing(path, writable=True)
        try:
            store._load_journal(repair=True)
            store._journal_fd = os.open(store.path / JOURNAL, os.O_WRONLY | os.O_APPEND)
            status = store.status()
            store._finished = status["state"] == "finished"
            if status["state"] == "stopped":  # resuming: the run is running again
                store.previous_status = status
                (store.path / STATUS).unlink()
                _fsync_dir(store.path)
        except BaseException:
            store.close()
            raise
        return store

    @classmethod
    def read(cls, path: str | Path) -> RunStore:
        """Open a run read-only without the lock (analysis while it runs); records() re-reads the journal."""
        store = cls._existing(path, writable=False)
        store._load_journal(repair=False)
        return store

    @classmethod
    def _existing(cls, path: str | Path, *, writable: bool) -> RunStore:
        store = cls(Path(path), writable=writable)
        where = store.path / MANIFEST
        if not store.path.exists():
            raise RunStoreError(f"{store.path}: does not exist (expected a run directory written by gonio run)")
        if not store.path.is_dir():
            raise RunStoreError(f"{store.path}: is a file, not a run directory")
        if not where.is_file():
            raise RunStoreError(f"{store.path}: not a run directory (no {MANIFEST})")
        if writable:
            store._take_lock()
        try:
            store.manifest = json.loads(where.read_text(encoding="utf-8"))
            if not isinstance(store.manifest, dict) or store.manifest.get("format") != FORMAT:
                raise ValueError(f"expected a JSON object with format {FORMAT!r}")
        except (OSError, ValueError) as exc:
            store.close()
            raise RunStoreError(f"{where}: cannot read the manifest: {exc}") from exc
        return store

    def _take_lock(self) -> None:
        lock = self.path / LOCK
        while True:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                os.close(fd)
                if exc.errno not in (errno.EWOULDBLOCK, errno.EACCES):
                    raise RunStoreError(f"{self.path}: cannot lock {lock}: {exc}") from exc
                try:  # the holder may not have written it yet
                    holder = json.loads(lock.read_text(encoding="utf-8"))
                except (OSError, ValueError):
                    holder = {}
                holder = holder if isinstance(holder, dict) else {}
                who = ", ".join(f"{k} {holder[k]}" for k in ("pid", "host", "since") if k in holder) or "unknown"
                raise RunLockedError(f"{self.path}: run is in use ({lock} held by {who})", holder) from None
            try:  # if the file was removed or replaced meanwhile we locked an orphan inode: start over
                if os.fstat(fd).st_ino == os.stat(lock).st_ino:
                    break
            except FileNotFoundError:
                pass
            os.close(fd)
        self._lock_fd = fd
        os.ftruncate(fd, 0)
        os.pwrite(fd, _dumps({"pid": os.getpid(), "host": socket.gethostname(), "since": _utc_now()}).encode(), 0)

    def _load_journal(self, *, repair: bool) -> None:
        where = self.path / JOURNAL
        try:
            records, good, torn = parse_journal(where.read_bytes())
        except OSError as exc:
            raise RunStoreError(f"{where}: cannot read the journal: {exc}") from exc
        except ValueError as exc:
            raise RunStoreError(f"{where}: {exc}") from None
        if torn and repair:  # a reader (no lock) leaves it: it may be a write in progress
            fd = os.open(where, os.O_RDWR)
            try:
                os.ftruncate(fd, good)
                os.fsync(fd)
            finally:
                os.close(fd)
            line = len(records) + 1  # every line before the torn one holds one record
            msg = (f"{where}: line {line} was half-written ({torn} bytes, not a whole record) and was dropped: the "
                   "process before died in the middle of writing it; that point is measured again")  # fmt: skip
            warnings.warn(msg, RunStoreWarning, stacklevel=3)
        self._records, self._journal_size = records, good

    def _check_writable(self, what: str) -> None:
        if not self._writable:
            raise RunStoreError(f"{self.path}: {what} on a read-only view (RunStore.read); use open or create")
        if self._lock_fd is None:
            raise RunStoreError(f"{self.path}: {what} after close()")
        if self._broken:
            raise RunStoreError(f"{self.path}: {what} refused: {self._broken}; reopen the run")

    def records(self) -> list[dict[str, Any]]:
        """Journal records in order (copies); a read-only view re-reads the journal each time."""
        if not self._writable:
            self._load_journal(repair=False)
        return [json_copy(r) for r in self._records]

    def records_to_read(self) -> Sequence[Mapping[str, Any]]:
        """Journal records in order, the store's own (not copied: read them, never change them).

        For a reader of every record, such as the table at the end of a run, which copying them all would slow.
        A read-only view re-reads the journal each time, as ``records`` does.
        """
        if not self._writable:
            self._load_journal(repair=False)
        return tuple(self._records)

    def append(self, record: Mapping[str, Any]) -> None:
        """Append one record (a mapping with a str "kind") to the journal; it is on disk when this returns."""
        self._check_writable("append")
        where = self.path / JOURNAL
        if not isinstance(record, Mapping) or not isinstance(record.get("kind"), str) or not record["kind"]:
            raise RunStoreError(f"{where}: record needs a 'kind' (a non-empty str): {record!r}")
        if self._finished:
            raise RunStoreError(f"{where}: the run is finished ({STATUS}); its journal is closed")
        try:  # nearly every record: exact plain types, kept as the copy that json.loads would read back
            plain, reparse = exact_json(record), False
        except NotExactJson:
            plain, reparse = _plain(record, "record", where), True
        data = (_encode_line(plain) + "\n").encode("ascii")
        assert self._journal_fd is not None
        fd, before = self._journal_fd, self._journal_size
        try:
            written = os.write(fd, data)  # one write: a crash leaves at most one torn last line
            while written < len(data):  # short only on a full disk or a signal; we are the only writer
                written += os.write(fd, data[written:])
        except OSError as exc:
            try:  # leave no torn line behind that a later append would bury in the middle
                os.ftruncate(fd, before)
            except OSError:
                self._broken = f"a failed write could not be undone ({exc})"
            raise RunStoreError(f"{where}: cannot append: {exc}") from exc
        try:
            os.fsync(fd)
        except OSError as exc:
            # After a failed fsync the kernel may have dropped the dirty pages: never trust this fd again.
            self._broken = f"fsync failed ({exc})"
            raise RunStoreError(f"{where}: cannot fsync: {exc}") from exc
        self._journal_size = before + len(data)
        self._records.append(json.loads(data) if reparse else plain)

    def completed(self, kind: str = "point", key: str = "index") -> set[Any]:
        """Values of ``key`` over the records of ``kind`` (lists become tuples): what a resume can skip."""
        done = set()
        for number, rec in enumerate(self.records(), 1):
            if rec["kind"] == kind:
                if key not in rec:
                    raise RunStoreError(f"{self.path / JOURNAL}: record {number} ({kind!r}) has no {key!r}")
                done.add(_hashable(rec[key]))
        return done

    def _file(self, name: str, what: str, suffix: str = "") -> Path:
        if not isinstance(name, str) or not _NAME_RE.fullmatch(name):
            raise RunStoreError(
                f"{self.path}: {what} name {name!r}: expected letters, digits, '_', '.', '-' (no path separator, "
                "not starting with '.', at most 128)"
            )
        return self.path / IMAGES / (name + suffix) if what == "image" else self.path / name

    def _write_atomic(self, target: Path, write: Callable[[Path], object]) -> None:
        try:
            with atomic_path(target) as tmp:
                write(tmp)
        except OSError as exc:
            raise RunStoreError(f"{self.path}: cannot write {target.name}: {exc}") from exc
        _fsync_dir(target.parent)

    def save_image(
        self, name: str, image: ArrayLike, channels: Sequence[str] = ("R", "G", "B"), *, variance: MaybeArray = None
    ) -> Path:
        """Write images/<name>.exr (float32, a 2-D image as channel "Y"; variance as "<ch>.var") atomically."""
        self._check_writable("save_image")
        target = self._file(name, "image", ".exr")
        if not target.parent.is_dir():
            target.parent.mkdir()
            _fsync_dir(self.path)
        try:
            self._write_atomic(target, lambda tmp: write_exr(tmp, image, channels, variance))
        except ValueError as exc:
            raise RunStoreError(f"{self.path}: image {name!r}: {exc}") from exc
        return target

    def load_image(self, name: str) -> tuple[Float32Array, Float32Array | None]:
        """Read images/<name>.exr back: (image, variance or None), float32, shaped as saved."""
        target = self._file(name, "image", ".exr")
        if not target.is_file():
            raise RunStoreError(f"{self.path}: no image {name!r} ({target})")
        try:
            image, variance, _ = read_exr(target)
        except ValueError as exc:
            raise RunStoreError(f"{self.path}: image {name!r}: {exc}") from exc
        return image, variance

    def write_table(
        self, rows: Sequence[Mapping[str, Any]], columns: Sequence[str] | None = None, name: str = "samples.csv"
    ) -> Path:
        """Write a tidy CSV atomically: exact float repr, None as empty; identical rows give identical bytes."""
        self._check_writable("write_table")
        target = self._file(name, "table")
        try:
            text = csv_text(rows, columns)
        except ValueError as exc:
            raise RunStoreError(f"{target}: {exc}") from None
        self._write_atomic(target, lambda tmp: tmp.write_text(text, encoding="utf-8", newline=""))
        return target

    def read_table(self, name: str = "samples.csv") -> list[dict[str, str]]:
        """Rows of a table written by write_table, as strings (missing values are "")."""
        try:
            with open(self._file(name, "table"), encoding="utf-8", newline="") as fh:
                return list(csv.DictReader(fh))
        except OSError as exc:
            raise RunStoreError(f"{self.path}: cannot read table {name!r}: {exc}") from exc

    def _mark(self, what: str, doc: dict[str, Any]) -> None:
        self._check_writable(what)
        text = _dumps({**doc, "time_utc": _utc_now()}, indent=2) + "\n"
        self._write_atomic(self.path / STATUS, lambda tmp: tmp.write_text(text, encoding="utf-8"))
        self._finished = doc["state"] == "finished"

    def mark_finished(self, summary: Mapping[str, Any]) -> None:
        """Record that the run is complete: status.json {"state": "finished", "summary", "time_utc"}."""
        self._mark("mark_finished", {"state": "finished", "summary": _plain(summary, "summary", self.path / STATUS)})

    def mark_stopped(self, reason: str) -> None:
        """Record that the run stopped before its end: status.json {"state": "stopped", "reason", "time_utc"}."""
        self._mark("mark_stopped", {"state": "stopped", "reason": str(reason)})

    def status(self) -> dict[str, Any]:
        """The run's state: {"state": "running"} without a status file, else the file's content."""
        where = self.path / STATUS
        try:
            doc = json.loads(where.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return {"state": "running"}
        except (OSError, ValueError) as exc:
            raise RunStoreError(f"{where}: cannot read the status: {exc}") from exc
        if not isinstance(doc, dict) or doc.get("state") not in ("finished", "stopped"):
            raise RunStoreError(f"{where}: expected a state 'finished' or 'stopped', got {doc!r}")
        return doc

    def close(self) -> None:
        """Close the journal and release the lock (the lock file stays; its content is informational)."""
        for attr in ("_journal_fd", "_lock_fd"):
            fd = getattr(self, attr, None)
            if fd is not None:
                setattr(self, attr, None)
                os.close(fd)  # closing the only descriptor of the lock file releases the flock

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        # A forgotten store must not keep the run locked for the life of the process.
        self.close()
