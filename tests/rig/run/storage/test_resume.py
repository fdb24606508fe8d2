"""A run killed with SIGKILL and resumed (on either link) ends with exactly the table of an uninterrupted run, but for
the wall-clock column ``utc`` (when each point was really measured)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from gonio.cli import main
from rig.instrument.links.grbl import GrblLink
from rig.run.config.files import load_rig, load_sweep
from rig.run.measuring import runner as runner_module
from rig.run.measuring.runner import RunStopped
from rig.run.session import resume_run, start_run
from tests.run_helpers import read_rows

pytestmark = pytest.mark.mitsuba

RIG = """
[simulation]
seed = 11
link = "{link}"
[simulation.material]
model = "CookTorrance"
alpha = 0.25
eta = [0.18, 0.42, 1.37]
k = [3.42, 2.35, 1.77]
[reference]
every = 7
"""
SWEEP = """
[sweep]
kind = "in_plane"
theta_i_deg = [15.0, 40.0, 65.0]
theta_o_deg = [-70.0, -45.0, -20.0, 0.0, 20.0, 45.0, 70.0]
[capture]
target_snr = 150.0
"""


def _files(tmp_path: Path, link: str = "dynamixel") -> tuple[Path, Path]:
    rig, sweep = tmp_path / "rig.toml", tmp_path / "sweep.toml"
    rig.write_text(RIG.format(link=link))
    sweep.write_text(SWEEP)
    return rig, sweep


def _journal_lines(run: Path) -> int:
    try:
        return (run / "journal.jsonl").read_bytes().count(b"\n")
    except FileNotFoundError:
        return 0


def _run_and_kill(rig: Path, sweep: Path, run: Path, after_records: int, resume: bool = False) -> None:
    """Start `gonio run` (or resume) in a child process and SIGKILL it once the journal holds enough records."""
    cmd = ["resume", str(run)] if resume else ["run", str(sweep), "--rig", str(rig), "--out", str(run)]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[4])}
    child = subprocess.Popen([sys.executable, "-m", "gonio.cli", *cmd, "--quiet"], env=env,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)  # fmt: skip
    deadline = time.monotonic() + 120.0
    try:
        while _journal_lines(run) < after_records:
            assert child.poll() is None, f"the run ended before it could be killed: {child.stderr.read()!r}"  # type: ignore[union-attr]
            assert time.monotonic() < deadline, "the run never reached the kill point"
            time.sleep(0.002)  # polling a file written by another process; nothing here waits on hardware
        child.send_signal(signal.SIGKILL)
    finally:
        child.wait(timeout=30)
    assert child.returncode == -signal.SIGKILL
    assert not (run / "status.json").exists(), "the run finished before the kill"


@pytest.mark.parametrize("link", ["dynamixel", "grbl"])
def test_killed_twice_and_resumed_equals_uninterrupted(
    tmp_path: Path, link: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    rig, sweep = _files(tmp_path, link)
    reference = start_run(load_rig(rig), load_sweep(sweep), tmp_path / "whole", progress=False)
    run = tmp_path / "killed"
    _run_and_kill(rig, sweep, run, after_records=3)
    _run_and_kill(rig, sweep, run, after_records=11, resume=True)
    # A GRBL rig comes back where the journal left it, but its reopened port counts from 0 there: it must home.
    homed: list[dict[str, float]] = []
    home = GrblLink.home

    def counted(link: GrblLink, timeout_s: float | None = None) -> None:
        home(link, timeout_s)
        homed.append(link.read_positions())

    monkeypatch.setattr(GrblLink, "home", counted)
    resumed = resume_run(run, progress=False)
    assert resumed.already >= 9 and resumed.measured + resumed.already == 18  # 21 directions, 3 too close
    # Byte for byte once the UTC column is left out: it says when each point was really measured.
    got, want = Path(resumed.table).read_text().splitlines(), Path(reference.table).read_text().splitlines()
    utc = got[0].split(",").index("utc")
    assert want[0].split(",").index("utc") == utc and len(got) == len(want)
    assert [line.rsplit(",", 1)[0] for line in got] == [line.rsplit(",", 1)[0] for line in want]
    assert utc == len(got[0].split(",")) - 1  # the last column, so cutting it off above is exact
    if link == "grbl":  # homed once, before the first move, to the switches at the light's top, the camera's bottom
        axes = {a.name: a for a in load_rig(rig).axes}
        step = 1.0 / axes["light"].units_per_joint_degree  # the pull-off is a whole number of steps
        assert len(homed) == 1 and homed[0]["light"] == pytest.approx(axes["light"].max_deg, abs=step)
        assert homed[0]["camera"] == pytest.approx(axes["camera"].min_deg, abs=step)


def test_resume_of_a_finished_run_measures_nothing_new(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rig, sweep = _files(tmp_path)
    run = tmp_path / "run"
    assert main(["run", str(sweep), "--rig", str(rig), "--out", str(run), "--quiet"]) == 0
    before = (run / "samples.csv").read_bytes()
    # Resuming is idempotent (a script may resume whatever it finds): a finished run is done, not an error.
    assert main(["resume", str(run), "--quiet"]) == 0
    assert "finished" in capsys.readouterr().err
    assert (run / "samples.csv").read_bytes() == before


def test_a_damaged_journal_is_refused_naming_the_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rig, sweep = _files(tmp_path)
    run = tmp_path / "run"
    assert main(["run", str(sweep), "--rig", str(rig), "--out", str(run), "--quiet"]) == 0
    (run / "status.json").unlink()  # as if killed before the end
    journal = run / "journal.jsonl"
    good = journal.read_bytes()
    lines = good.splitlines(keepends=True)
    with open(journal, "ab") as fh:
        fh.write(b'{"kind":"point"}\n')
    capsys.readouterr()
    assert main(["resume", str(run), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"line {len(lines) + 1}: a 'point' record without 'index'" in err, err
    point = next(i for i, line in enumerate(lines) if b'"kind":"point"' in line)
    journal.write_bytes(good + lines[point])
    assert main(["resume", str(run), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"line {len(lines) + 1}: point " in err and f"already recorded on line {point + 1}" in err, err


def _interrupt_after(readings: int, monkeypatch: pytest.MonkeyPatch) -> None:
    """Make the runner's ``readings``-th camera reading (references included) a Ctrl-C, as a SIGINT there would be."""
    taken = 0
    take = runner_module.take_reading

    def reading(*args: object, **kwargs: object) -> object:
        nonlocal taken
        taken += 1
        if taken == readings:
            raise KeyboardInterrupt
        return take(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(runner_module, "take_reading", reading)


def test_a_grbl_run_interrupted_past_a_reference_resumes_to_the_uninterrupted_table(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # The shipped GRBL rig's tilt table names only its gear (and speed): what it leaves out (the switch beyond the
    # limit) must stay left out in the manifest a resume rebuilds the rig from, or the resumed tilt counts steps
    # from another zero and every point after the interruption lands on another step grid.
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG.format(link="grbl").replace("every = 7", "every = 5") + '[axes.tilt]\nletter = "Z"\n'
                   "gear_ratio = 3.0\nmax_speed_deg_s = 30.0\n")  # fmt: skip
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(SWEEP.replace("[15.0, 40.0, 65.0]", "[20.0, 50.0]"))
    reference = start_run(load_rig(rig), load_sweep(sweep), tmp_path / "whole", progress=False)
    run = tmp_path / "interrupted"
    # Readings: the reference, points 0-4, the reference at 5, point 5, then Ctrl-C during point 6's.
    _interrupt_after(9, monkeypatch)
    with pytest.raises(RunStopped) as stopped:
        start_run(load_rig(rig), load_sweep(sweep), run, progress=False)
    assert stopped.value.cause == "interrupted"
    monkeypatch.undo()
    resumed = resume_run(run, progress=False)
    assert (resumed.already, resumed.measured + resumed.already) == (6, reference.measured)
    got, want = read_rows(resumed.table), read_rows(reference.table)
    assert len(got) == len(want) == reference.measured
    for column in want[0]:
        if column != "utc":  # when each point was really measured
            assert [r[column] for r in got] == [r[column] for r in want], column
