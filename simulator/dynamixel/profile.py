"""Closed-form motion profiles: trapezoid, triangle or rectangle from any start position and velocity.

Positions are encoder ticks, velocities ticks/s, accelerations ticks/s^2, times seconds from the start of
the profile. A profile is a short list of constant-acceleration segments, so the state at any time is
evaluated exactly (no integration step), and a servo can compute it lazily whenever it is read.

A new goal during a move starts a new profile from the present position *and velocity* (the e-Manual's
"velocity override"): moving away from the new goal first brakes to rest, and a goal too close to stop in
time is overshot, braked and approached from the other side.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass


class ProfileType(enum.IntEnum):
    """Moving Status (123) bits 4-5: which profile shape the move uses."""

    NONE = 0x00
    RECTANGULAR = 0x10
    TRIANGULAR = 0x20
    TRAPEZOIDAL = 0x30


@dataclass(frozen=True)
class Segment:
    """Constant acceleration ``a`` (ticks/s^2) for ``duration`` s from ``t0``, starting at ``x0``, ``v0``."""

    t0: float
    x0: float
    v0: float
    a: float
    duration: float

    def at(self, t: float) -> tuple[float, float]:
        """Position (ticks) and velocity (ticks/s) at profile time ``t`` inside this segment."""
        tau = t - self.t0
        return self.x0 + self.v0 * tau + 0.5 * self.a * tau * tau, self.v0 + self.a * tau

    @property
    def end(self) -> tuple[float, float]:
        """Position (ticks) and velocity (ticks/s) when the segment ends."""
        return self.at(self.t0 + self.duration)


@dataclass(frozen=True)
class Profile:
    """A planned move from ``start`` to ``target`` (ticks) made of constant-acceleration segments."""

    start: float
    start_velocity: float
    target: float
    segments: tuple[Segment, ...]
    kind: ProfileType

    @property
    def duration(self) -> float:
        """Seconds from the start of the profile until it reaches the target at rest."""
        if not self.segments:
            return 0.0
        last = self.segments[-1]
        return last.t0 + last.duration

    def at(self, t: float) -> tuple[float, float, float]:
        """Position (ticks), velocity (ticks/s) and acceleration (ticks/s^2) at ``t`` s after the start."""
        if t <= 0.0 or not self.segments:
            return (self.start, self.start_velocity, 0.0) if self.segments else (self.target, 0.0, 0.0)
        for seg in self.segments:
            if t < seg.t0 + seg.duration:
                x, v = seg.at(t)
                return x, v, seg.a
        return self.target, 0.0, 0.0


def plan(start: float, velocity: float, target: float, v_max: float, a_max: float) -> Profile:
    """Time-optimal profile from ``start`` moving at ``velocity`` to rest at ``target``.

    ``v_max`` (ticks/s) caps the cruise speed and must be positive; ``a_max`` (ticks/s^2) may be
    ``math.inf`` for a rectangular profile, where velocity changes instantly.
    """
    if not (v_max > 0 and math.isfinite(v_max)):
        raise ValueError(f"v_max = {v_max!r} ticks/s: expected a positive finite speed")
    if not a_max > 0:
        raise ValueError(f"a_max = {a_max!r} ticks/s^2: expected a positive acceleration (inf allowed)")
    segments: list[Segment] = []
    _plan_into(segments, 0.0, float(start), float(velocity), float(target), v_max, a_max)
    if math.isinf(a_max):
        kind = ProfileType.RECTANGULAR
    elif any(s.a == 0.0 for s in segments):
        kind = ProfileType.TRAPEZOIDAL
    else:
        kind = ProfileType.TRIANGULAR
    return Profile(float(start), float(velocity), float(target), tuple(segments), kind)


def _plan_into(out: list[Segment], t: float, x: float, v: float, target: float, v_max: float, a: float) -> None:
    """Append segments taking (x, v) at time t to rest at target."""
    if math.isinf(a):
        if target != x:
            speed = math.copysign(v_max, target - x)
            out.append(Segment(t, x, speed, 0.0, abs(target - x) / v_max))
        return

    # Work in a frame where the target lies ahead (direction s), then map each segment back.
    s = 1.0 if target >= x else -1.0
    d = abs(target - x)
    u = s * v
    pos = 0.0

    def push(acc: float, duration: float) -> None:
        nonlocal t, pos, u
        if duration <= 0.0:
            return
        out.append(Segment(t, x + s * pos, s * u, s * acc, duration))
        pos += u * duration + 0.5 * acc * duration * duration
        u += acc * duration
        t += duration

    if u < 0.0:
        push(a, -u / a)  # moving away from the target: brake to rest first
        u = 0.0
    remaining = d - pos
    if u * u / (2.0 * a) > remaining:
        push(-a, u / a)  # too fast to stop in time: stop beyond the target, then come back
        x_now, _ = out[-1].end
        _plan_into(out, t, x_now, 0.0, target, v_max, a)
        return

    peak = math.sqrt((2.0 * a * remaining + u * u) / 2.0)
    if peak <= v_max:
        push(a, (peak - u) / a)
        push(-a, peak / a)
    else:
        ramp = abs(v_max * v_max - u * u) / (2.0 * a)
        push(a if u <= v_max else -a, abs(v_max - u) / a)
        u = v_max  # exact, so rounding in the ramp cannot leave a sliver of speed
        push(0.0, max(remaining - ramp - v_max * v_max / (2.0 * a), 0.0) / v_max)
        push(-a, v_max / a)
