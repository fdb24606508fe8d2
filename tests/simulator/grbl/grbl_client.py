"""A bare pyserial client of the virtual GRBL, shared by its tests."""

from __future__ import annotations

import time

import serial

from rig.instrument.clock import ManualClock

BANNER = "Grbl 1.1h ['$' for help]"


class Client:
    """A bare pyserial client; every read is bounded by a wall-clock timeout so a test can never hang."""

    def __init__(self, port: str, clock: ManualClock) -> None:
        self.clock = clock
        self.ser = serial.Serial(port, 115200, timeout=0.01)
        self.buf = b""
        self.other: list[str] = []  # lines that arrived while waiting for status reports
        self.greeting = self.read_until(lambda line: line == BANNER)

    def close(self) -> None:
        self.ser.close()

    def readline(self, timeout_s: float = 30.0) -> str | None:
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self.buf:
            if time.monotonic() > deadline:
                return None
            self.buf += self.ser.read(self.ser.in_waiting or 1)
        line, _, self.buf = self.buf.partition(b"\n")
        return line.decode().strip()

    def read_until(self, pred, timeout_s: float = 30.0) -> list[str]:
        lines = []
        while True:
            line = self.readline(timeout_s)
            assert line is not None, f"timed out; got {lines!r}"
            lines.append(line)
            if pred(line):
                return lines

    def send(self, line: str) -> list[str]:
        """One line, and everything GRBL prints up to its ok / error:N."""
        self.ser.write(line.encode() + b"\n")
        return self.read_until(lambda s: s == "ok" or s.startswith("error:"))

    def query(self) -> str:
        self.ser.write(b"?")
        lines = self.read_until(lambda s: s.startswith("<"))
        self.other += lines[:-1]
        return lines[-1]

    def state(self) -> str:
        return self.query()[1:-1].split("|")[0]

    def mpos(self) -> tuple[float, ...]:
        fields = dict(f.split(":", 1) for f in self.query()[1:-1].split("|")[1:])
        return tuple(float(v) for v in fields["MPos"].split(","))

    def run_until(self, pred, step_s: float = 0.05, limit_s: float = 120.0) -> str:
        """Advance simulated time in steps, polling '?', until ``pred(report)``; bounded by ``limit_s``."""
        start = self.clock.now()
        while True:
            report = self.query()
            if pred(report):
                return report
            assert self.clock.now() - start < limit_s, f"still {report} after {limit_s} s"
            self.clock.advance(step_s)
