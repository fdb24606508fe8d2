"""Motion of the virtual GRBL: a queue of straight moves, each run as a trapezoidal speed profile from rest to rest.

Positions are in controller units (millimetres for GRBL; the gonio uses one unit per motor degree), time in
seconds of the controller's clock. The queue is integrated lazily: the controller asks for the time of the next
event (a move finishing, a feed hold coming to rest) and steps to it or to "now", so the state is exact whatever
the polling rate.

Simplification (documented in ``simulator/grbl/server.py``): GRBL plans junction speeds between consecutive blocks;
here every move starts and ends at rest, which is what a sweep of separate G1 lines to distinct poses does anyway.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field


@dataclass
class Move:
    """One planned straight move; ``start``/``target`` in controller units, speed in units/s, accel in units/s^2."""

    start: tuple[float, ...]
    target: tuple[float, ...]
    speed: float
    accel: float
    jog: bool = False
    done: float = 0.0  # distance along the path already covered (units)
    length: float = field(init=False)

    def __post_init__(self) -> None:
        self.length = math.dist(self.start, self.target)

    def point(self, s: float) -> list[float]:
        """Position (units) after covering distance ``s`` along the path."""
        if self.length <= 0.0:
            return list(self.target)
        f = min(max(s / self.length, 0.0), 1.0)
        return [a + (b - a) * f for a, b in zip(self.start, self.target, strict=True)]


def _run_profile(d: float, vmax: float, a: float) -> tuple[float, float, float]:
    """Peak speed, ramp time and cruise time for covering ``d`` units from rest to rest."""
    if d <= 0.0:
        return 0.0, 0.0, 0.0
    vp = min(vmax, math.sqrt(a * d))
    t_ramp = vp / a
    cruise = max(d - vp * vp / a, 0.0)
    return vp, t_ramp, cruise / vp


def _run_state(d: float, vmax: float, a: float, t: float) -> tuple[float, float]:
    """Distance covered and speed ``t`` seconds into a rest-to-rest profile over ``d`` units."""
    vp, tr, tc = _run_profile(d, vmax, a)
    total = 2.0 * tr + tc
    if t <= 0.0 or d <= 0.0:
        return 0.0, 0.0
    if t >= total:
        return d, 0.0
    if t < tr:
        return 0.5 * a * t * t, a * t
    if t < tr + tc:
        return 0.5 * a * tr * tr + vp * (t - tr), vp
    left = total - t
    return d - 0.5 * a * left * left, a * left


class MotionQueue:
    """The planner buffer and the stepper of the virtual GRBL (positions in units, time in seconds).

    ``mode`` is ``"idle"`` (nothing executing), ``"run"`` (executing the head move), ``"hold"`` (decelerating for
    a feed hold) or ``"held"`` (hold complete; moves wait for a resume).
    """

    def __init__(self, n_axes: int, capacity: int) -> None:
        self.capacity = capacity
        self.moves: deque[Move] = deque()
        self.mode = "idle"
        self.stalled = False
        self.cancel_on_stop = False  # a jog cancel / soft-limit hold flushes the queue once at rest
        self._pos = [0.0] * n_axes
        self._t = 0.0
        # The executing profile is anchored at (time, distance, speed) where it (re)started.
        self._t0 = 0.0
        self._s0 = 0.0
        self._v0 = 0.0
        self._speed = 0.0

    # ---- queries -------------------------------------------------------------------------------------------
    @property
    def position(self) -> list[float]:
        """Current position in units (as of the last step)."""
        return list(self._pos)

    @property
    def speed(self) -> float:
        """Current path speed in units/s."""
        return self._speed

    @property
    def full(self) -> bool:
        """Whether the planner buffer has no free block."""
        return len(self.moves) >= self.capacity

    @property
    def busy(self) -> bool:
        """Whether anything is queued or moving (GRBL's buffer-synchronise condition)."""
        return bool(self.moves) or self.mode in ("run", "hold")

    def next_event(self) -> float | None:
        """Clock time (s) of the next move completion or hold stop, or None."""
        if self.stalled or not self.moves:
            return None
        m = self.moves[0]
        if self.mode == "run":
            _, tr, tc = _run_profile(m.length - self._s0, m.speed, m.accel)
            return self._t0 + 2.0 * tr + tc
        if self.mode == "hold":
            return self._t0 + self._v0 / m.accel
        return None

    # ---- commands ------------------------------------------------------------------------------------------
    def set_position(self, pos: list[float]) -> None:
        """Overwrite the position in units (homing, power-up)."""
        self._pos = list(pos)

    def add(self, move: Move, t: float) -> None:
        """Queue ``move`` at clock time ``t``; starts at once when idle (GRBL's auto cycle start)."""
        self.moves.append(move)
        if self.mode == "idle":
            self._start_head(t)

    def hold(self, t: float, cancel: bool = False) -> None:
        """Begin a controlled stop at time ``t`` (feed hold); ``cancel`` flushes the queue once stopped."""
        self.cancel_on_stop = self.cancel_on_stop or cancel
        if self.mode == "run":
            m = self.moves[0]
            self._t0, self._s0, self._v0 = t, m.done, self._speed
            self.mode = "hold"
        elif self.mode == "idle":
            self.mode = "held"
            self._finish_cancel()

    def resume(self, t: float) -> None:
        """Continue after a completed hold (cycle start) at time ``t``."""
        if self.mode != "held":
            return
        self.mode = "idle"
        if self.moves:
            self._start_head(t)

    def kill(self) -> None:
        """Stop dead and forget the queue (reset, hard limit): the position stays where the steps stopped."""
        self.moves.clear()
        self.mode = "idle"
        self.cancel_on_stop = False
        self.stalled = False
        self._speed = 0.0

    def step(self, t: float) -> str | None:
        """Advance to time ``t`` (never past ``next_event()``); returns ``"done"``, ``"stopped"`` or None."""
        if t < self._t:
            t = self._t
        self._t = t
        if self.stalled or not self.moves or self.mode not in ("run", "hold"):
            self._speed = 0.0 if not self.stalled else self._speed
            return None
        m = self.moves[0]
        event = self.next_event()
        at_event = event is not None and t >= event - 1e-12
        if self.mode == "run":
            if at_event:
                self._pos = list(m.target)
                self.moves.popleft()
                self._speed = 0.0
                self.mode = "idle"
                if self.moves:
                    self._start_head(t)
                return "done"
            ds, v = _run_state(m.length - self._s0, m.speed, m.accel, t - self._t0)
            m.done = self._s0 + ds
            self._speed = v
        else:
            tau = min(t - self._t0, self._v0 / m.accel)
            m.done = min(self._s0 + self._v0 * tau - 0.5 * m.accel * tau * tau, m.length)
            self._speed = max(self._v0 - m.accel * tau, 0.0)
            if at_event:
                self._speed = 0.0
                self.mode = "held"
                self._pos = m.point(m.done)
                self._finish_cancel()
                return "stopped"
        self._pos = m.point(m.done)
        return None

    def _start_head(self, t: float) -> None:
        m = self.moves[0]
        self._t0, self._s0, self._v0 = t, m.done, 0.0
        self.mode = "run"

    def _finish_cancel(self) -> None:
        if self.cancel_on_stop:
            self.moves.clear()
            self.mode = "idle"
            self.cancel_on_stop = False
