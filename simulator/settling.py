"""What a virtual device served on a pty does for a settling ManualClock: pause, resume and settle.

A device's serving thread marks ``_handling`` (under ``_idle``) while it holds client input, and notifies
``_idle`` when it is done; ``settle`` returns once nothing is in hand or waiting, so simulated time moves
only after every device has acted on what a client sent (``rig.instrument.clock.ManualClock.add_settler``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

#: Wall seconds a settling clock waits for a serving thread at most: a dead one must not hang the simulation.
SETTLE_TIMEOUT_S = 60.0


class Settling:
    """Mixin for a pty-served device: its serving thread holds at ``pause`` and is waited for by ``settle``."""

    _idle: threading.Condition
    _handling: bool
    _running: threading.Event
    _stop: threading.Event  # set when the serving thread is to end
    _unsettle: Callable[[], None] | None
    settling: int

    def _init_settling(self) -> None:
        self._idle = threading.Condition()
        self._handling = False  # the serving thread has client input in hand (read or about to be)
        self._running = threading.Event()  # cleared by pause(): the thread holds before reading
        self._running.set()
        self.settling = 0  # clocks waiting in settle() now (for tests)

    def _settle_with(self, clock: object) -> None:
        """Have ``clock`` wait for this device before time moves on, if it is a clock that settles."""
        add_settler = getattr(clock, "add_settler", None)
        self._unsettle = add_settler(self.settle) if add_settler is not None else None

    def _stop_serving(self) -> None:
        """Leave the clock's settlers and tell the serving thread to end, letting it go if paused (idempotent)."""
        if self._unsettle is not None:
            self._unsettle()
            self._unsettle = None
        self._stop.set()
        self._running.set()

    def _serving(self) -> bool:
        """Whether the serving thread is there to handle input."""
        raise NotImplementedError

    def _input_waiting(self) -> bool:
        """Whether a client's bytes wait on the pty, unread."""
        raise NotImplementedError

    def _settle_poll_s(self) -> float:
        """How often (s) a settling clock looks again, should a notification be missed."""
        return 0.05

    def pause(self) -> None:
        """Hold the serving thread before it reads its next input: a host too busy to run it (for tests)."""
        self._running.clear()

    def resume(self) -> None:
        """Let a paused serving thread go on."""
        self._running.set()

    def settle(self) -> None:
        """Return once every byte a client wrote is handled and answered (at most SETTLE_TIMEOUT_S wall seconds)."""
        deadline = time.monotonic() + SETTLE_TIMEOUT_S
        with self._idle:
            self.settling += 1
            try:
                while self._serving() and (self._handling or self._input_waiting()):
                    left = deadline - time.monotonic()
                    if left <= 0.0:
                        return  # a thread that never gets there must not hang the simulation too
                    self._idle.wait(min(left, self._settle_poll_s()))
            finally:
                self.settling -= 1
