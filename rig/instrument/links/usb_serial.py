"""A USB serial adapter's latency timer, read from sysfs, and whether it is set too high for a servo bus.

FTDI chips (the U2D2, most USB-RS485 adapters) hold received bytes for up to their latency timer (16 ms by
default) before sending them to the host, so every status packet waits for it: a bus that could answer in
1 ms answers in 16. Linux shows the timer as ``/sys/bus/usb-serial/devices/<tty>/latency_timer``
(milliseconds); adapters without one (CDC-ACM boards, a pseudo-terminal) have no such file. The SDK's reply
timeout counts twice ``[link] latency_timer_ms``, so a timer above that value also makes replies look lost.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

#: Where Linux mounts sysfs; tests and containers pass another root.
SYSFS = Path("/sys")
#: The timer a fast bus wants (ms): the lowest an FTDI chip takes.
RECOMMENDED_MS = 1


@dataclass(frozen=True)
class LatencyTimer:
    """The latency timer of the adapter behind a serial port: its tty name, the sysfs file and its value in ms."""

    tty: str
    path: Path
    value_ms: int


def tty_name(port: str | os.PathLike[str]) -> str:
    """The kernel's name of a serial port (``ttyUSB0``), following udev's symlinks (``/dev/serial/by-id/...``)."""
    return Path(os.path.realpath(port)).name


def read_latency_timer(port: str | os.PathLike[str], sysfs: str | os.PathLike[str] = SYSFS) -> LatencyTimer | None:
    """The latency timer (ms) of the USB serial adapter behind ``port``, or None if it has none (not USB-serial).

    Raises ValueError naming the file if it holds something other than a whole number of milliseconds.
    """
    tty = tty_name(port)
    path = Path(sysfs) / "bus" / "usb-serial" / "devices" / tty / "latency_timer"
    try:
        text = path.read_text(encoding="ascii").strip()
    except (FileNotFoundError, NotADirectoryError):
        return None
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: cannot read the latency timer: {exc}") from exc
    try:
        value = int(text)
    except ValueError:
        raise ValueError(f"{path}: {text!r} is not a latency timer (expected whole milliseconds, e.g. 16)") from None
    return LatencyTimer(tty, path, value)


def latency_advice(timer: LatencyTimer | None, configured_ms: float) -> str | None:
    """A warning when the adapter's timer is above ``configured_ms`` (replies look lost) or above 1 ms (slow)."""
    if timer is None or timer.value_ms <= RECOMMENDED_MS:
        return None
    fix = (f"set it to {RECOMMENDED_MS} ms: `echo {RECOMMENDED_MS} | sudo tee {timer.path}` now, or for good the udev "
           "rule in docs/hardware.md")  # fmt: skip
    if timer.value_ms > configured_ms:
        return (f"warning: {timer.tty}: the USB adapter's latency timer is {timer.value_ms} ms, above the "
                f"{configured_ms:g} ms gonio was told ([link] latency_timer_ms / --latency-ms): replies arrive after "
                f"gonio's timeout and look lost; {fix}")  # fmt: skip
    return (f"warning: {timer.tty}: the USB adapter's latency timer is {timer.value_ms} ms: every servo reply waits "
            f"for it (a poll of the bus takes {timer.value_ms} ms or more); {fix}")  # fmt: skip
