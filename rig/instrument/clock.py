"""Injectable clocks: real time for hardware, manual or scaled time so simulations run faster than real time.

Everything that waits (links polling for in-position, virtual servos integrating their motion, cameras
exposing) takes a ``Clock``. A link and the virtual bus it talks to share one clock in tests, so a
two-second move settles after a handful of polls and no test ever depends on wall-clock speed.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Protocol, runtime_checkable


@runtime_checkable
class Clock(Protocol):
    """A source of monotonic time in seconds that can also be waited on."""

    def now(self) -> float:
        """Current time in seconds (monotonic, arbitrary origin)."""
        ...

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` of this clock's time pass."""
        ...


class SystemClock:
    """Wall-clock time: what real hardware runs on."""

    def now(self) -> float:
        """Seconds from ``time.monotonic``."""
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        """Block for ``seconds`` of real time."""
        if seconds > 0:
            time.sleep(seconds)


class ManualClock:
    """Simulated time that only moves when someone sleeps on it or advances it; thread-safe.

    ``sleep`` advances the time instantly instead of blocking, so a poll loop with a 10 ms interval
    moves the simulation forward 10 ms per poll at the speed of the bus round trip.

    Settling. A virtual device served from its own thread (a servo bus, a GRBL on a pty) reads what a client
    wrote whenever that thread gets to run. If time moved on first, a command sent at t would act at a later t:
    the simulation would then depend on thread scheduling, i.e. on the machine's speed and load. A device
    therefore registers a settler (``add_settler``), which ``advance`` calls first: it returns once the device
    has handled every byte written to it, so whatever a client sent before time moves acts when it was sent.
    """

    def __init__(self, start_s: float = 0.0) -> None:
        self._t = float(start_s)
        self._lock = threading.Lock()
        self._settlers: list[Callable[[], None]] = []

    def add_settler(self, settle: Callable[[], None]) -> Callable[[], None]:
        """Call ``settle()`` before every advance of time (see the class docstring); returns its remover."""
        with self._lock:
            self._settlers.append(settle)

        def remove() -> None:
            with self._lock:
                if settle in self._settlers:
                    self._settlers.remove(settle)

        return remove

    def now(self) -> float:
        """Current simulated time in seconds."""
        with self._lock:
            return self._t

    def settle(self) -> None:
        """Return once every settling device has handled all a client wrote (time does not move)."""
        with self._lock:
            settlers = list(self._settlers)
        for settle in settlers:
            settle()

    def sleep(self, seconds: float) -> None:
        """Advance simulated time by ``seconds`` without blocking."""
        self.advance(seconds)

    def advance(self, seconds: float) -> None:
        """Move simulated time forward by ``seconds`` (negative values are refused)."""
        if seconds < 0:
            raise ValueError(f"ManualClock.advance({seconds!r}): time cannot run backwards")
        self.settle()
        with self._lock:
            self._t += seconds


class ScaledClock:
    """Real time sped up by a constant factor, for simulators served to clients that use wall time.

    ``ScaledClock(20)`` makes a virtual servo finish a two-second move in 0.1 s of real time, which is
    what a process on the other end of a pseudo-terminal (e.g. ROBOTIS's own tools) can follow.
    """

    def __init__(self, factor: float = 1.0) -> None:
        if not factor > 0:
            raise ValueError(f"ScaledClock factor = {factor!r}: expected a positive number")
        self.factor = float(factor)
        self._origin = time.monotonic()

    def now(self) -> float:
        """Simulated seconds since this clock was made."""
        return (time.monotonic() - self._origin) * self.factor

    def sleep(self, seconds: float) -> None:
        """Block for ``seconds / factor`` of real time."""
        if seconds > 0:
            time.sleep(seconds / self.factor)


def poll_until(
    predicate: Callable[[], bool], timeout_s: float, interval_s: float, clock: Clock, what: str
) -> None:
    """Call ``predicate()`` every ``interval_s`` seconds of ``clock`` time until it is true.

    Raises ``TimeoutError`` naming ``what`` when ``timeout_s`` passes first.
    """
    deadline = clock.now() + timeout_s
    while True:
        if predicate():
            return
        if clock.now() >= deadline:
            raise TimeoutError(f"{what}: not done after {timeout_s:g} s")
        clock.sleep(interval_s)
