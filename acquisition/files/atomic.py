"""Atomic file writes: nothing is ever partially written in place (docs/architecture.md, Conventions)."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike[str]) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; on success fsync it and rename it over ``target``.

    On any exception (Ctrl-C included) the temporary file is removed and ``target`` is untouched. The
    temporary file lives in the same directory so the rename is atomic on POSIX file systems.
    """
    final = Path(target)
    final.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(dir=final.parent, prefix=f".{final.name}.", suffix=".tmp")
    os.close(fd)
    tmp = Path(name)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, final)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_atomic(path: Path, write: Callable[[Path], object]) -> Path:
    """Write ``path`` through ``write(tmp)`` on a temporary file and a rename, readable by all (for sharing)."""
    with atomic_path(path) as tmp:
        write(tmp)
        tmp.chmod(0o644)  # mkstemp makes 0600
    return path
