"""The run's time to go, from the points measured so far, with the first point's one-time costs left out.

The first point of a process pays for loading compiled kernels, building caches and the first render; a
rate that counts it promises a run several times longer than it will be. ``Eta`` estimates from the first
point alone until a second is done, then from the points after the first only. Wall seconds of an
injectable clock (tests drive it by hand).
"""

from __future__ import annotations

import time
from collections.abc import Callable


class Eta:
    """Remaining wall seconds of a run of ``remaining`` points, started when ``start`` is called."""

    def __init__(self, wall: Callable[[], float] = time.monotonic) -> None:
        self._wall = wall
        self._left = 0
        self._start = 0.0
        self._first_done: float | None = None
        self._last_done = 0.0
        self._after_first = 0  # points done since the first

    def start(self, remaining: int) -> None:
        """Begin timing ``remaining`` points (after any warm-up: it is not a point's cost)."""
        self._left = remaining
        self._start = self._wall()
        self._first_done, self._after_first = None, 0

    def point_done(self) -> None:
        """Count one point as measured now."""
        self._left = max(self._left - 1, 0)
        self._last_done = self._wall()
        if self._first_done is None:
            self._first_done = self._last_done
        else:
            self._after_first += 1

    def per_point_s(self) -> float | None:
        """Wall seconds per point: the first point's until a second is done, then the later points' mean."""
        if self._first_done is None:
            return None
        if self._after_first == 0:
            return self._first_done - self._start
        return (self._last_done - self._first_done) / self._after_first

    def remaining_s(self) -> float | None:
        """Estimated wall seconds until the last point is measured; None before the first one."""
        per = self.per_point_s()
        return None if per is None else per * self._left


def format_eta(seconds: float | None) -> str:
    """``ETA h:mm:ss`` (or ``ETA ?`` before there is any estimate)."""
    if seconds is None:
        return "ETA ?"
    s = round(seconds)
    return f"ETA {s // 3600}:{s // 60 % 60:02d}:{s % 60:02d}"
