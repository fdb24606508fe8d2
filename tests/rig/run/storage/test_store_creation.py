"""Run creation is atomic: SIGKILL at any step of RunStore.create leaves a complete run or none, never a husk;
and a damaged journal is refused with the line named, before a resume or a table trusts it."""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path

import pytest

from rig.run.storage.journal import JournalError, check_records
from rig.run.storage.store import JOURNAL, LOCK, MANIFEST, RunStore, RunStoreError

DOC = {"rig": {"name": "sim"}, "sweep": {"points": 3}}
# The system calls a creation is made of; the child is killed just before the k-th of them.
STEPS = ("open", "fsync", "write", "pwrite", "rename", "replace", "mkdir", "rmdir", "ftruncate")


def _create_killed_at(run: Path, k: int) -> bool:
    """Fork, SIGKILL the child at the k-th step of RunStore.create(run); False if it completed before step k."""
    pid = os.fork()
    if pid == 0:  # pragma: no cover (the child never returns)
        count = [0]

        def hooked(name: str, real: object) -> object:
            def call(*args: object, **kw: object) -> object:
                count[0] += 1
                if count[0] == k:
                    os.kill(os.getpid(), signal.SIGKILL)
                return real(*args, **kw)  # type: ignore[operator]

            return call

        for name in STEPS:
            setattr(os, name, hooked(name, getattr(os, name)))
        try:
            RunStore.create(run, DOC).close()
        finally:
            os._exit(0)
    _, status = os.waitpid(pid, 0)
    return os.WIFSIGNALED(status)


def test_a_creation_killed_at_any_step_leaves_a_complete_run_or_none(tmp_path: Path) -> None:
    killed_steps = 0
    for k in range(1, 200):
        run = tmp_path / f"k{k}" / "run"
        killed = _create_killed_at(run, k)
        if run.exists():
            names = {p.name for p in run.iterdir()}
            assert {MANIFEST, JOURNAL, LOCK} <= names, (k, names)
            with RunStore.open(run) as store:  # a complete run: resumable
                assert store.manifest["sweep"] == DOC["sweep"]
        else:
            with RunStore.create(run, DOC) as store:  # none: `gonio run` with the same --out works
                store.append({"kind": "event", "event": "started"})
            leftovers = [p.name for p in run.parent.iterdir() if p.name != "run"]
            assert leftovers == [], (k, leftovers)
        if not killed:
            break
        killed_steps += 1
    assert killed_steps >= 8  # the creation really was interrupted at each of its steps


def test_the_husk_of_a_creation_killed_by_an_older_gonio_is_accepted_by_run(tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / LOCK).write_text("{}")
    (run / JOURNAL).write_bytes(b"")
    with RunStore.create(run, DOC) as store:
        assert store.records() == []
    assert (run / MANIFEST).is_file()


def test_a_directory_with_other_files_is_still_refused(tmp_path: Path) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / JOURNAL).write_text('{"kind":"point","index":0}\n')
    with pytest.raises(RunStoreError, match="not empty"):
        RunStore.create(run, DOC)


def _point(index: int, position: int) -> dict[str, object]:
    return {
        "kind": "point", "index": index, "position": position, "target_deg": [10.0, 0.0, 20.0, 180.0],
        "theta_i_deg": 10.0, "phi_i_deg": 0.0, "theta_o_deg": 20.0, "phi_o_deg": 180.0,
        "joints_deg": {"light": 1.0}, "reading": [1.0, 1.0, 1.0], "reading_std_error": [0.1, 0.1, 0.1],
        "n_pixels": 4, "lower_bound": False, "exposures_s": [0.01],
        "level": {"peak": 1.0, "mean": 1.0, "dark": 0.0, "n_pixels": 4},
    }  # fmt: skip


def test_a_point_without_its_index_names_the_line() -> None:
    records = [{"kind": "event", "event": "x"}, _point(0, 0), {"kind": "point"}]
    with pytest.raises(JournalError, match=r"journal.jsonl: line 3: a 'point' record without 'index'"):
        check_records(records, "run/journal.jsonl")


def test_a_duplicated_point_names_both_lines() -> None:
    records = [_point(0, 0), _point(1, 1), _point(1, 1)]
    with pytest.raises(JournalError, match=r"line 3: point 1 is already recorded on line 2"):
        check_records(records, "run/journal.jsonl")


def test_a_wrongly_typed_key_is_named_with_its_value() -> None:
    bad = {**_point(0, 0), "target_deg": [1.0, 2.0]}
    with pytest.raises(JournalError, match=r"line 1: point target_deg = \[1.0, 2.0\]: expected a list of 4"):
        check_records([bad], "j")


def test_a_clean_journal_passes() -> None:
    check_records([_point(0, 0), _point(1, 1), {"kind": "reference", **{k: v for k, v in _point(0, 0).items()
                   if k not in ("kind", "index", "position")}, "slot": 0}], "j")  # fmt: skip
    assert json.dumps(_point(0, 0))
