"""The run store (rig/run/storage/store.py): manifest, journal with repair, lock across processes, EXR images, tables.
"""

from __future__ import annotations

import errno
import json
import math
import os
import re
import selectors
import subprocess
import sys
import tempfile
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from subprocess import PIPE

import numpy as np
import OpenEXR
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import rig.run.storage.store as store_mod
from rig.run.storage.store import RunLockedError, RunStore, RunStoreError, RunStoreWarning

REPO = Path(__file__).resolve().parents[4]
MANIFEST = {"rig": {"name": "sim", "axes": ["theta_i", "theta_o"]}, "sweep": {"points": 3}}

# Takes the lock and says so, then holds it until its stdin closes (or it is killed).
HOLDER = ("import sys, rig.run.storage.store as m; s = m.RunStore.open(sys.argv[1]); print('locked', flush=True); "
          "sys.stdin.read()")


@contextmanager
def holder(run: Path) -> Iterator[subprocess.Popen[str]]:
    cmd = [sys.executable, "-c", HOLDER, str(run)]
    proc = subprocess.Popen(cmd, stdin=PIPE, stdout=PIPE, stderr=PIPE, text=True, cwd=REPO)
    try:
        assert proc.stdout is not None
        sel = selectors.DefaultSelector()
        sel.register(proc.stdout, selectors.EVENT_READ)
        ready = sel.select(60.0)  # an upper bound only: the child says when it holds the lock
        line = proc.stdout.readline().strip() if ready else ""
        if line != "locked":
            proc.kill()
            raise AssertionError(
                f"holder did not take the lock: {line!r}; stderr: {proc.stderr.read() if proc.stderr else ''}"
            )
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=30)


@pytest.fixture
def run(tmp_path: Path) -> Path:
    path = tmp_path / "runs" / "r1"
    RunStore.create(path, MANIFEST).close()
    return path


def test_create_writes_manifest_journal_and_lock(tmp_path: Path) -> None:
    path = tmp_path / "a" / "b" / "run"
    with RunStore.create(path, MANIFEST) as s:
        assert s.path == path
        doc = json.loads((path / "manifest.json").read_text())
        assert doc == s.manifest
        assert doc["rig"] == MANIFEST["rig"] and doc["format"] == "gonio-run/1"
        assert doc["gonio_version"] and doc["created_utc"].endswith("+00:00")
        assert (path / "journal.jsonl").read_bytes() == b""
        assert json.loads((path / "lock").read_text())["pid"] == os.getpid()
        assert s.status() == {"state": "running"} and s.records() == []
    assert sorted(p.name for p in path.iterdir()) == ["journal.jsonl", "lock", "manifest.json"]


def test_create_refuses_a_run_or_a_non_empty_directory(run: Path, tmp_path: Path) -> None:
    with pytest.raises(RunStoreError, match=r"already holds a run.*gonio resume") as exc:
        RunStore.create(run, MANIFEST)
    assert str(run) in str(exc.value)
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    with pytest.raises(RunStoreError, match=r"not empty \(notes\.txt\)"):
        RunStore.create(other, MANIFEST)
    assert [p.name for p in other.iterdir()] == ["notes.txt"]  # no lock file left behind
    with pytest.raises(RunStoreError, match="format"):
        RunStore.create(tmp_path / "x", {"format": "mine"})
    with pytest.raises(RunStoreError, match=r"manifest\['sweep'\]\['step'\] = nan"):
        RunStore.create(tmp_path / "y", {"sweep": {"step": math.nan}})


def test_open_refuses_what_is_not_a_run(tmp_path: Path) -> None:
    with pytest.raises(RunStoreError, match="not a run directory"):
        RunStore.open(tmp_path)
    (tmp_path / "manifest.json").write_text('{"format": "other/2"}')
    with pytest.raises(RunStoreError, match=r"manifest\.json.*gonio-run/1"):
        RunStore.open(tmp_path)


def test_append_then_reopen_gives_the_same_records(run: Path) -> None:
    recs = [
        {"kind": "reference", "value": [0.25, 1e-300], "note": "snow\u00e9"},
        {"kind": "point", "index": 0, "theta_i": 10.000000000000002, "ok": True, "missing": None},
        {"kind": "point", "index": [1, 2], "exposure_s": np.float64(0.125), "counts": np.arange(3)},
        {"kind": "event", "what": "line\nbreak"},
    ]
    with RunStore.open(run) as s:
        for r in recs:
            s.append(r)
        written = s.records()
        assert written[2]["counts"] == [0, 1, 2] and written[2]["exposure_s"] == 0.125
        written[0]["value"].append(5)  # a copy: the store is unaffected
        assert s.records()[0]["value"] == [0.25, 1e-300]
    with RunStore.open(run) as s:
        assert s.records() == json.loads(json.dumps([{**r, "counts": [0, 1, 2]} if "counts" in r else r for r in recs]))
        assert s.completed() == {0, (1, 2)}
        assert s.completed("reference", "value") == {(0.25, 1e-300)}
        with pytest.raises(RunStoreError, match=r"record 4 \('event'\) has no 'index'"):
            s.completed("event")
    assert len((run / "journal.jsonl").read_bytes().splitlines()) == 4


def test_invalid_records_are_refused_naming_the_key(run: Path) -> None:
    with RunStore.open(run) as s:
        with pytest.raises(RunStoreError, match="needs a 'kind'"):
            s.append({"index": 1})
        with pytest.raises(RunStoreError, match="needs a 'kind'"):
            s.append({"kind": 3})
        with pytest.raises(RunStoreError, match=r"journal\.jsonl: record\['fit'\]\['rho'\] = nan"):
            s.append({"kind": "point", "fit": {"rho": float("nan")}})
        with pytest.raises(RunStoreError, match=r"record\['value'\]\[1\] = inf"):
            s.append({"kind": "point", "value": np.array([1.0, np.inf])})
        with pytest.raises(RunStoreError, match=r"record\['m'\] has key 3"):
            s.append({"kind": "point", "m": {3: "x"}})
        with pytest.raises(RunStoreError, match=r"record\['when'\] = .*object.*not representable"):
            s.append({"kind": "point", "when": object()})
        assert s.records() == []
    assert (run / "journal.jsonl").read_bytes() == b""


@pytest.mark.parametrize("tail", [b'{"kind":"point","ind', b'{"kind":"point","index":2}', b"\x00\x00\x00", b"{bad\n"])
def test_a_torn_last_line_is_cut_with_a_warning(run: Path, tail: bytes) -> None:
    with RunStore.open(run) as s:
        s.append({"kind": "point", "index": 0})
        s.append({"kind": "point", "index": 1})
    journal = run / "journal.jsonl"
    good = journal.read_bytes()
    with open(journal, "ab") as fh:
        fh.write(tail)  # what a SIGKILL in the middle of os.write leaves behind
    assert [r["index"] for r in RunStore.read(run).records()] == [0, 1]  # a reader skips it, leaves it
    assert journal.read_bytes() == good + tail
    torn = rf"journal\.jsonl: line 3 was half-written \({len(tail)} bytes, not a whole record\) and was dropped: "
    with pytest.warns(RunStoreWarning, match=torn + "the process before died in the middle of writing it"):
        s = RunStore.open(run)
    with s:
        assert journal.read_bytes() == good
        assert s.completed() == {0, 1}
        s.append({"kind": "point", "index": 2})
    with warnings.catch_warnings():
        warnings.simplefilter("error", RunStoreWarning)
        with RunStore.open(run) as s:  # clean now: no warning
            assert s.completed() == {0, 1, 2}


def test_a_bad_line_in_the_middle_is_corruption(run: Path) -> None:
    journal = run / "journal.jsonl"
    journal.write_bytes(b'{"kind":"point","index":0}\n{"kind":"point",\n{"kind":"point","index":2}\n')
    with pytest.raises(RunStoreError, match=r"journal\.jsonl: line 2 is not valid JSON.*corrupt"):
        RunStore.open(run)
    with pytest.raises(RunStoreError, match="line 2"):
        RunStore.read(run)
    journal.write_bytes(b'{"kind":"point"}\n[1, 2]\n{"kind":"point"}\n')
    with pytest.raises(RunStoreError, match=r"line 2 is not a record"):
        RunStore.open(run)
    journal.write_bytes(b'{"kind":"point","x":NaN}\n{"kind":"point"}\n')
    with pytest.raises(RunStoreError, match=r"line 1 is not valid JSON \(NaN is not allowed\)"):
        RunStore.open(run)
    journal.write_bytes(b'{"kind":"point"}\n')
    RunStore.open(run).close()  # the failed opens released the lock


def test_a_failed_write_is_undone_and_a_failed_fsync_poisons_the_store(
    run: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    real_write = os.write
    calls = []

    def half_then_full_disk(fd: int, data: bytes) -> int:
        calls.append(len(data))
        if len(calls) == 1:
            return real_write(fd, data[: len(data) // 2])
        raise OSError(errno.ENOSPC, "No space left on device")

    with RunStore.open(run) as s:
        s.append({"kind": "point", "index": 0})
        size = (run / "journal.jsonl").stat().st_size
        monkeypatch.setattr(store_mod.os, "write", half_then_full_disk)
        with pytest.raises(RunStoreError, match=r"journal\.jsonl: cannot append.*No space"):
            s.append({"kind": "point", "index": 1})
        monkeypatch.setattr(store_mod.os, "write", real_write)
        assert (run / "journal.jsonl").stat().st_size == size  # the half line was cut off again
        s.append({"kind": "point", "index": 2})
        monkeypatch.setattr(store_mod.os, "fsync", lambda fd: (_ for _ in ()).throw(OSError(errno.EIO, "I/O error")))
        with pytest.raises(RunStoreError, match="cannot fsync"):
            s.append({"kind": "point", "index": 3})
        monkeypatch.undo()
        with pytest.raises(RunStoreError, match=r"fsync failed.*reopen the run"):
            s.append({"kind": "point", "index": 4})
    with RunStore.open(run) as s:
        assert s.completed() == {0, 2, 3}  # 3 reached the file, though its fsync failed


def test_a_second_store_in_this_process_is_refused(run: Path) -> None:
    with RunStore.open(run) as s:
        with pytest.raises(
            RunLockedError, match=rf"{re.escape(str(run))}: run is in use .*lock held by pid {os.getpid()}"
        ):
            RunStore.open(run)
        with pytest.raises(RunLockedError):
            RunStore.create(run, MANIFEST)
        assert RunStore.read(run).manifest == s.manifest
    RunStore.open(run).close()


def test_another_process_holds_the_lock_until_killed(run: Path) -> None:
    with RunStore.open(run) as s:
        s.append({"kind": "point", "index": 0})
    with holder(run) as proc:
        with pytest.raises(RunLockedError) as exc:
            RunStore.open(run)
        assert exc.value.holder["pid"] == proc.pid and f"pid {proc.pid}" in str(exc.value)
        assert "host" in exc.value.holder and "since" in exc.value.holder
        view = RunStore.read(run)  # analysis while the run is held
        assert view.completed() == {0}
        with pytest.raises(RunStoreError, match="read-only"):
            view.append({"kind": "point", "index": 1})
        proc.kill()  # SIGKILL: no cleanup runs in the child; the kernel drops its flock
        proc.wait(timeout=30)
    with RunStore.open(run) as s:
        assert s.completed() == {0}
        assert json.loads((run / "lock").read_text())["pid"] == os.getpid()


def test_read_view_follows_the_writer_and_cannot_write(run: Path) -> None:
    view = RunStore.read(run)
    with RunStore.open(run) as s:
        s.append({"kind": "point", "index": 0})
        assert view.records() == s.records()
        s.write_table([{"a": 1}])
    assert view.read_table() == [{"a": "1"}]
    for call in (
        lambda: view.save_image("x", np.zeros((1, 1, 3))),
        lambda: view.write_table([]),
        lambda: view.mark_finished({}),
        lambda: view.mark_stopped("why"),
    ):
        with pytest.raises(RunStoreError, match="read-only"):
            call()


def test_exr_round_trip_is_exact_for_float32(run: Path) -> None:
    rng = np.random.default_rng(7)
    img = rng.standard_normal((5, 7, 3)).astype(np.float32) * np.float32(1e3)
    img[0, 0] = [np.nan, np.inf, -0.0]
    img[1, 1] = [1e-45, 3.4e38, -1e-38]  # a subnormal and the ends of the range
    var = np.abs(rng.standard_normal((5, 7, 3))).astype(np.float32)
    with RunStore.open(run) as s:
        path = s.save_image("point-0001", img, variance=var)
        assert path == run / "images" / "point-0001.exr"
        back, back_var = s.load_image("point-0001")
        assert back.dtype == np.float32 and back.shape == img.shape
        assert np.array_equal(back.view(np.uint32), img.view(np.uint32))  # bit for bit, NaN and -0 included
        assert back_var is not None and np.array_equal(back_var, var)
        mono = rng.random((4, 6))  # float64 in: stored as float32
        s.save_image("dark", mono)  # 2-D with the default channels: one channel, "Y"
        y, none = s.load_image("dark")
        assert none is None and y.shape == (4, 6) and np.array_equal(y, mono.astype(np.float32))
        assert list(OpenEXR.File(str(run / "images" / "dark.exr")).channels()) == ["Y"]
        odd = rng.random((2, 3, 3)).astype(np.float32)
        s.save_image("odd", odd, channels=("Z", "A", "M"))  # EXR sorts channels; the order comes back
        assert np.array_equal(s.load_image("odd")[0], odd)
        s.save_image("odd", odd[::-1])  # replaced in place, atomically
        assert np.array_equal(s.load_image("odd")[0], odd[::-1])
    raw = OpenEXR.File(str(path), separate_channels=True)
    assert set(raw.channels()) == {"R", "G", "B", "R.var", "G.var", "B.var"}
    assert all(ch.pixels.dtype == np.float32 for ch in raw.channels().values())
    assert sorted(p.name for p in (run / "images").iterdir()) == ["dark.exr", "odd.exr", "point-0001.exr"]


def test_bad_images_and_names_are_refused(run: Path) -> None:
    with RunStore.open(run) as s:
        for name in ("../escape", "a/b", ".hidden", "", "x" * 200):
            with pytest.raises(RunStoreError, match="image name"):
                s.save_image(name, np.zeros((1, 1, 3)))
        with pytest.raises(RunStoreError, match=r"image 'p': image has shape \(2, 2\) but 2 channel"):
            s.save_image("p", np.zeros((2, 2)), channels=("R", "G"))
        with pytest.raises(RunStoreError, match="variance has shape"):
            s.save_image("p", np.zeros((2, 2, 3)), variance=np.zeros((2, 2, 1)))
        with pytest.raises(RunStoreError, match="negative"):
            s.save_image("p", np.zeros((2, 2, 3)), variance=-np.ones((2, 2, 3)))
        with pytest.raises(RunStoreError, match="float32 range"):
            s.save_image("p", np.full((1, 1, 3), 1e300))
        with pytest.raises(RunStoreError, match="repeat"):
            s.save_image("p", np.zeros((1, 1, 2)), channels=("R", "R"))
        with pytest.raises(RunStoreError, match="no image 'p'"):
            s.load_image("p")
        with pytest.raises(RunStoreError, match="table name"):
            s.write_table([], name="../x.csv")
    assert not (run / "images").exists() or list((run / "images").iterdir()) == []


ROWS = [
    {"index": 0, "theta_i_deg": 10.0, "f_r_R": 0.1 + 0.2, "se_R": 1e-17, "lower_bound": False},
    {"index": 1, "theta_i_deg": 20.000000000000004, "f_r_R": None, "note": 'a "quoted", text'},
    {"index": 2, "f_r_R": np.float32(0.1), "lower_bound": np.True_, "se_R": 5e-324},
]


def test_write_table_is_deterministic_and_exact(tmp_path: Path) -> None:
    texts = []
    for name in ("a", "b"):
        with RunStore.create(tmp_path / name, MANIFEST) as s:
            path = s.write_table(ROWS)
            texts.append(path.read_bytes())
            rows = s.read_table()
    assert texts[0] == texts[1]
    assert texts[0].splitlines()[0] == b"index,theta_i_deg,f_r_R,se_R,lower_bound,note"
    assert b"\r" not in texts[0]
    assert rows[1]["f_r_R"] == "" and rows[1]["se_R"] == "" and rows[0]["note"] == ""
    assert rows[1]["note"] == 'a "quoted", text'
    assert float(rows[0]["f_r_R"]) == 0.1 + 0.2 and float(rows[1]["theta_i_deg"]) == 20.000000000000004
    assert float(rows[2]["f_r_R"]) == float(np.float32(0.1)) and float(rows[2]["se_R"]) == 5e-324
    assert [r["lower_bound"] for r in rows] == ["false", "", "true"]


def test_write_table_refuses_what_it_cannot_write_exactly(run: Path) -> None:
    with RunStore.open(run) as s:
        with pytest.raises(RunStoreError, match=r"samples\.csv: row 1, column 'v' = nan"):
            s.write_table([{"v": 1.0}, {"v": math.nan}])
        with pytest.raises(RunStoreError, match=r"row 0 has keys \['w'\] not among the columns"):
            s.write_table([{"v": 1.0, "w": 2}], columns=["v"])
        with pytest.raises(RunStoreError, match=r"column 'v' = \[1, 2\]"):
            s.write_table([{"v": [1, 2]}])
        path = s.write_table([{"v": 1}], columns=["u", "v"], name="other.csv")
        assert path.read_text() == "u,v\n,1\n"
        assert not (run / "samples.csv").exists()
        with pytest.raises(RunStoreError, match=r"cannot read table 'samples\.csv'"):
            s.read_table()


def test_status_finished_stopped_and_resumed(run: Path) -> None:
    with RunStore.open(run) as s:
        assert s.previous_status is None
        s.mark_stopped("user pressed Ctrl-C")
        stopped = s.status()
        assert stopped["state"] == "stopped" and stopped["reason"] == "user pressed Ctrl-C"
    assert RunStore.read(run).status() == stopped
    with RunStore.open(run) as s:  # a resume: running again, the stop kept for the runner to log
        assert s.status() == {"state": "running"} and s.previous_status == stopped
        s.append({"kind": "point", "index": 0})
        s.mark_finished({"points": 1, "rms": np.float64(0.5)})
        done = s.status()
        assert done["state"] == "finished" and done["summary"] == {"points": 1, "rms": 0.5}
        with pytest.raises(RunStoreError, match="finished"):
            s.append({"kind": "point", "index": 1})
    with RunStore.open(run) as s:
        assert s.status() == done
        with pytest.raises(RunStoreError, match="finished"):
            s.append({"kind": "point", "index": 1})
    s.close()  # idempotent
    with pytest.raises(RunStoreError, match=r"after close\(\)"):
        s.write_table([])


JSON = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False, allow_infinity=False) | st.text(),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=12,
)
RECORD = st.builds(
    lambda k, rest: {**rest, "kind": k}, st.text(min_size=1), st.dictionaries(st.text(), JSON, max_size=5)
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(RECORD, max_size=6))
def test_any_json_records_round_trip(records: list[dict[str, object]]) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        with RunStore.create(Path(tmp) / "run", {}) as s:
            for r in records:
                s.append(r)
            assert s.records() == records
        assert RunStore.read(Path(tmp) / "run").records() == records
        with RunStore.open(Path(tmp) / "run") as s:  # a resume sees exactly what was appended
            assert s.records() == records
