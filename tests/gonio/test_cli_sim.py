"""``gonio sim servos|grbl`` as a user runs them: a separate process, its device path on stdout, Ctrl-C."""

from __future__ import annotations

import contextlib
import selectors
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest
import serial

from rig.instrument.links.dynamixel_bus import DynamixelBus


def _first_line(proc: subprocess.Popen[str], timeout_s: float) -> str:
    """The first stdout line of ``proc``, waiting at most ``timeout_s`` seconds (never a blind sleep)."""
    assert proc.stdout is not None
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    if not sel.select(timeout_s):
        proc.kill()
        raise AssertionError(f"no device path on stdout within {timeout_s} s; stderr: {proc.stderr}")
    return proc.stdout.readline().strip()


@contextmanager
def gonio_sim(*args: str, stdin: bool = False) -> Iterator[tuple[subprocess.Popen[str], str]]:
    """``gonio sim ARGS`` running (its standard input a pipe with ``stdin``), and the device path it prints first."""
    with subprocess.Popen(
        [sys.executable, "-m", "gonio.cli", "sim", *args], stdin=subprocess.PIPE if stdin else None,
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    ) as proc:  # fmt: skip
        try:
            yield proc, _first_line(proc, timeout_s=300.0)
        finally:
            if proc.poll() is None:
                proc.kill()  # then leaving the Popen closes its pipes and waits for it


def _interrupt(proc: subprocess.Popen[str]) -> int:
    proc.send_signal(signal.SIGINT)
    return proc.wait(timeout=120)


def test_sim_servos_serves_a_bus_the_sdk_can_scan() -> None:
    with gonio_sim("servos", "--ids", "3,7", "--baud", "57600") as (proc, port):
        assert port.startswith("/dev/pts/")
        with DynamixelBus(port, 57_600, latency_timer_ms=60.0) as bus:
            found = bus.scan(baudrates=(57_600,))
        assert [(f.servo_id, f.model_number) for f in found] == [(3, 1020), (7, 1020)]
        assert _interrupt(proc) == 0


def test_sim_grbl_answers_with_its_banner() -> None:
    with gonio_sim("grbl", "--axes", "XY") as (proc, port):
        with serial.Serial(port, 115200, timeout=0.05) as ser:
            seen = b""
            deadline = time.monotonic() + 10.0
            while b"Grbl 1.1" not in seen and time.monotonic() < deadline:
                seen += ser.read(256)
        assert b"Grbl 1.1h ['$' for help]" in seen
        assert _interrupt(proc) == 0


def _lines_until(ser: serial.Serial, last: str, timeout_s: float = 30.0) -> list[str]:
    """Lines from ``ser`` up to and including ``last`` (wall-clock bounded, never a blind sleep)."""
    seen = b""
    deadline = time.monotonic() + timeout_s
    while last.encode() not in seen:
        assert time.monotonic() < deadline, f"no {last!r} within {timeout_s} s; got {seen!r}"
        seen += ser.read(256)
    return [line.strip() for line in seen.decode().splitlines() if line.strip()]


def test_sim_grbl_with_homing_starts_locked_and_a_link_homes_and_moves_on_it() -> None:
    from rig.instrument.axis import Axis
    from rig.instrument.clock import SystemClock
    from rig.instrument.links.grbl import GrblLink

    with gonio_sim("grbl", "--axes", "XY", "--homing", "--speed", "50") as (proc, port):
        with serial.Serial(port, 115200, timeout=0.05) as ser:
            # GRBL with homing enabled powers up locked, as a commissioned controller does.
            greeting = _lines_until(ser, "[MSG:'$H'|'$X' to unlock]")
            assert greeting[-2:] == ["Grbl 1.1h ['$' for help]", "[MSG:'$H'|'$X' to unlock]"]
            ser.write(b"?")
            assert _lines_until(ser, ">")[-1].startswith("<Alarm|")
            ser.write(b"$$\n")
            assert "$22=1" in _lines_until(ser, "ok")
            ser.write(b"G1 X-1 F100\n")
            assert _lines_until(ser, "error:9")[-1] == "error:9"  # G-code locked out until $H or $X
        # The link homes (the axes stood mid-travel), then moves where it is told, counted from the switches.
        axes = [Axis(name=n, address=n.upper(), units_per_degree=250.0, zero_offset_deg=0.0, min_deg=-150.0,
                     max_deg=-1.0, max_speed_deg_s=8.0) for n in ("x", "y")]  # fmt: skip
        with GrblLink(port, axes, clock=SystemClock(), poll_interval_s=0.002, require_home=True) as link:
            link.move_to({"x": -20.0, "y": -5.0})
            reached = link.wait_in_position(timeout_s=60.0)
            assert reached == pytest.approx({"x": -20.0, "y": -5.0}, abs=0.004)
            assert link.last_alarm is None and link.status().state == "Idle"
        assert _interrupt(proc) == 0


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["servos", "--ids", "1,x"], "servo ids '1,x': expected e.g. 1,2,3 or 1-4"),
        (["servos", "--baud", "1500000"], "invalid choice: 1500000"),
        (["grbl", "--speed", "0"], "speed '0': expected a positive factor"),
        (["rig", "--rig", "examples/rig_dynamixel.toml", "--link", "grbl", "--frames", "unused"],
         "--link grbl names another link than the file's"),
    ],
)
def test_sim_bad_arguments(args: list[str], message: str) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "gonio.cli", "sim", *args], capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 2
    assert message in result.stderr


@pytest.mark.mitsuba
def test_sim_rig_serves_servos_and_writes_frames_of_the_pose_they_hold(tmp_path) -> None:
    from acquisition.files.raw import read_raw
    from rig.instrument.clock import SystemClock
    from rig.instrument.geometry import RigGeometry
    from rig.instrument.kinematics import inverse, require
    from rig.instrument.links.dynamixel import DynamixelLink
    from rig.run.config.files import default_axes

    with gonio_sim("rig", "--frames", str(tmp_path), "--speed", "20", stdin=True) as (proc, port):
        axes = default_axes(RigGeometry())
        with DynamixelLink.open(port, axes, clock=SystemClock(), latency_timer_ms=60.0) as link:
            target = require(inverse(RigGeometry(), 30.0, 0.0, 20.0, 180.0))
            link.move_to({k: float(v) for k, v in target.as_dict().items()})
            held = link.wait_in_position(timeout_s=300.0)
            assert abs(held["light"] - float(target.light)) < 0.2
            assert proc.stdin is not None
            frames = []
            for _ in range(2):
                proc.stdin.write("capture 0.02\n")
                proc.stdin.flush()
                frames.append(read_raw(_first_line(proc, timeout_s=300.0)))
        assert frames[0].exposure_s == pytest.approx(0.02)
        black = max(np.atleast_1d(frames[0].black_level))
        assert float(frames[0].data.mean()) > black + 10  # lit: the sample is in view at this pose
        proc.stdin.write("focus now\n")
        proc.stdin.flush()
        assert "expected 'capture SECONDS'" in _first_line(proc, timeout_s=120.0)
        proc.stdin.close()
        assert proc.wait(timeout=120) == 0


@pytest.mark.mitsuba
def test_ctrl_c_stops_sim_rig_after_it_has_rendered(tmp_path) -> None:
    """Ctrl-C ends the rehearsal after a frame too (once the renderer had run, SIGINT never reached it)."""
    with gonio_sim("rig", "--frames", str(tmp_path), "--speed", "20", stdin=True) as (proc, _port):
        assert proc.stdin is not None
        proc.stdin.write("capture 0.01\n")
        proc.stdin.flush()
        assert _first_line(proc, timeout_s=300.0).endswith(".dng")
        proc.send_signal(signal.SIGINT)
        # The bound only ends a rehearsal that ignores Ctrl-C; the exit status is what is checked.
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(timeout=120)
        assert proc.poll() == 130, f"gonio sim rig did not stop on Ctrl-C (status {proc.poll()})"


@pytest.mark.mitsuba
def test_sim_rig_on_grbl_homes_and_writes_frames_of_the_pose_the_steppers_hold(tmp_path) -> None:
    from pathlib import Path

    from acquisition.files.raw import read_raw
    from rig.instrument.clock import SystemClock
    from rig.instrument.kinematics import inverse, require
    from rig.instrument.links.grbl import GrblLink
    from rig.run.config.files import load_rig

    rig_file = Path(__file__).resolve().parents[2] / "examples" / "rig_simulated_grbl.toml"
    rig = load_rig(rig_file)
    args = ("rig", "--rig", str(rig_file), "--frames", str(tmp_path), "--speed", "20")
    with gonio_sim(*args, stdin=True) as (proc, port):
        with GrblLink(port, rig.axes, clock=SystemClock(), require_home=True, reply_timeout_s=5.0) as link:
            target = require(inverse(rig.geometry, 30.0, 0.0, 20.0, 180.0))
            link.move_to({k: float(v) for k, v in target.as_dict().items()})  # homes first
            held = link.wait_in_position(timeout_s=300.0)
            assert abs(held["light"] - float(target.light)) < 0.2
            assert proc.stdin is not None
            proc.stdin.write("capture 0.02\n")
            proc.stdin.flush()
            frame = read_raw(_first_line(proc, timeout_s=300.0))
        assert float(frame.data.mean()) > max(np.atleast_1d(frame.black_level)) + 10  # lit: the sample in view
        proc.stdin.close()
        assert proc.wait(timeout=120) == 0


@pytest.mark.slow
def test_sim_merl_writes_the_documented_paint_or_the_rig_files_material(tmp_path, capsys):
    from gonio import cli
    from gonio.cli_sim import PAINT
    from model import CookTorrance
    from model.geometry import from_half_diff
    from model.merl import bin_centers, read_merl

    out = tmp_path / "paint.binary"
    assert cli.main(["sim", "merl", "--out", str(out)]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    table = read_merl(out)  # the MERL reader's own header and size checks pass
    # The paint the help text names, evaluated independently at a spread of bin centres (MERL's rounding: 1e-6).
    th, td, pd = (a.reshape(-1)[::9973] for a in bin_centers())
    wi, wo = from_half_diff(th, 0.0, td, pd)
    paint = CookTorrance(**{k: tuple(v) if isinstance(v, list) else v for k, v in PAINT.items() if k != "model"})
    assert np.allclose(table.eval(wi, wo), paint.eval(wi, wo), rtol=1e-6, atol=1e-9)

    rig = tmp_path / "rig.toml"
    rig.write_text('[simulation.material]\nmodel = "Lambert"\nrho_d = [0.1, 0.5, 0.9]\n')
    assert cli.main(["sim", "merl", "--rig", str(rig), "--out", str(out)]) == 0
    lambert = read_merl(out).values.reshape(3, -1)
    th, td, pd = (a.reshape(-1) for a in bin_centers())
    wi, wo = from_half_diff(th, 0.0, td, pd)
    lit = (wi[..., 2] > 0) & (wo[..., 2] > 0)  # a bin centre below either horizon holds 0
    assert 0.5 < lit.mean() < 1.0
    for c, rho in enumerate((0.1, 0.5, 0.9)):
        assert np.allclose(lambert[c], np.where(lit, rho / np.pi, 0.0), rtol=1e-6, atol=1e-9)
    rig.write_text('[simulation.material]\nmodel = "Lambertt"\n')
    assert cli.main(["sim", "merl", "--rig", str(rig), "--out", str(out)]) == 2
    assert "simulation.material.model = 'Lambertt'" in capsys.readouterr().err
