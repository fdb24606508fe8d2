"""``gonio sim servos|grbl`` as a user runs them: a separate process, its device path on stdout, Ctrl-C."""

from __future__ import annotations

import selectors
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

import pytest
import serial

from rig.links.dynamixel_bus import DynamixelBus


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
def gonio_sim(*args: str) -> Iterator[tuple[subprocess.Popen[str], str]]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "rig.cli", "sim", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        yield proc, _first_line(proc, timeout_s=60.0)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.communicate(timeout=10)


def _interrupt(proc: subprocess.Popen[str]) -> int:
    proc.send_signal(signal.SIGINT)
    return proc.wait(timeout=10)


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


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["servos", "--ids", "1,x"], "servo ids '1,x': expected e.g. 1,2,3 or 1-4"),
        (["servos", "--baud", "1500000"], "invalid choice: 1500000"),
        (["grbl", "--speed", "0"], "speed '0': expected a positive factor"),
    ],
)
def test_sim_bad_arguments(args: list[str], message: str) -> None:
    result = subprocess.run([sys.executable, "-m", "rig.cli", "sim", *args], capture_output=True, text=True, timeout=60)
    assert result.returncode == 2
    assert message in result.stderr
