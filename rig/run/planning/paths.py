"""Swept-path safety of moves: the light and camera arms never come closer than ``min_separation_deg`` in motion.

Both arms (or the light arm and a fixed camera) turn about the same vertical axis, so they touch when their
arm angles differ by less than the minimum separation modulo 360 deg. Checking the poses at the ends of a
move is not enough: between light 20 / camera 60 and light 60 / camera 20 the arms pass through each other.

Motion profiles (angles in degrees, times in seconds):

- independent axes (Dynamixel): every axis starts together and runs its own rest-to-rest trapezoid under its
  speed and acceleration limits, so a fast axis may catch up with a slow one. Between the phase changes of
  both arms' trapezoids the arm difference is a quadratic in time, so its range over each piece (its ends and
  its vertex) is exact: the least separation over the whole move is computed, not sampled;
- coordinated (GRBL): all axes run one trapezoid along the straight joint-space segment, so the arm difference
  moves linearly from start to end and the check is exact.

``MARGIN_DEG`` (0 by default) can demand clearance beyond the model. A move that starts closer than the minimum
(a parked rest pose) must never get closer than it started. An unsafe move is split into legs that move one
arm at a time (the stage joints with the first), in the order that keeps the arms apart; a move that no such
split makes safe needs the arms to cross and is refused.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from rig.instrument.geometry import RigGeometry

FloatArray = npt.NDArray[np.float64]

MARGIN_DEG = 0.0


def _profile(a: FloatArray, b: FloatArray, speed: float, accel: float) -> tuple[FloatArray, ...]:
    """Rest-to-rest trapezoids a -> b (deg): start, direction, peak speed; accel end, decel start, end (s)."""
    d = np.abs(b - a)
    tri = d * accel <= speed * speed
    peak = np.where(tri, np.sqrt(d * accel), speed)
    ta = peak / accel
    total = np.where(tri, 2.0 * ta, d / speed + ta)
    return a, np.sign(b - a), peak, ta, total - ta, total


def _state(prof: tuple[FloatArray, ...], t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Position (deg), velocity (deg/s) and acceleration (deg/s^2) of trapezoids at times ``t`` (s)."""
    a, sgn, peak, ta, td, total = prof
    acc_mag = np.where(ta > 0, peak / np.where(ta > 0, ta, 1.0), 0.0)
    tc = np.clip(t, 0.0, total)
    up = tc < ta
    down = tc >= td
    cruise = 0.5 * acc_mag * ta**2 + peak * (tc - ta)
    braking = 0.5 * acc_mag * ta**2 + peak * (tc - ta) - 0.5 * acc_mag * (tc - td) ** 2
    x = np.where(up, 0.5 * acc_mag * tc**2, np.where(down, braking, cruise))
    v = np.where(up, acc_mag * tc, np.where(down, peak - acc_mag * (tc - td), peak))
    acc = np.where(t >= total, 0.0, np.where(up, acc_mag, np.where(down, -acc_mag, 0.0)))
    return a + sgn * x, sgn * np.where(t >= total, 0.0, v), sgn * acc


def _wrapped(d: FloatArray) -> FloatArray:
    """Angular distance in [0, 180] deg of an arm difference ``d`` in degrees."""
    out: FloatArray = np.abs((d + 180.0) % 360.0 - 180.0)
    return out


# One move at a time (the runtime guard, the planner's splits) the same arithmetic runs on Python floats:
# numpy's per-call cost on one-element arrays is most of the work, and a move's check is hundreds of them.
# Every operation is the one numpy does, in the same order (x * x for numpy's x**2; Python's % and
# numpy's remainder agree), so the result is the same float; tests/rig/run/planning/test_plan_paths.py pins it.
Trapezoid = tuple[float, float, float, float, float, float]


def _profile_one(a: float, b: float, speed: float, accel: float) -> Trapezoid:
    """``_profile`` of one axis: start, direction, peak speed; accel end, decel start, end (deg, s)."""
    d = abs(b - a)
    tri = d * accel <= speed * speed
    peak = math.sqrt(d * accel) if tri else speed
    ta = peak / accel
    total = 2.0 * ta if tri else d / speed + ta
    return a, float((b > a) - (b < a)), peak, ta, total - ta, total


def _state_one(prof: Trapezoid, t: float) -> tuple[float, float, float]:
    """``_state`` of one axis at time ``t`` (s): position (deg), velocity (deg/s), acceleration (deg/s^2)."""
    a, sgn, peak, ta, td, total = prof
    acc_mag = peak / ta if ta > 0 else 0.0
    tc = min(max(t, 0.0), total)
    if tc < ta:
        x, v, acc = 0.5 * acc_mag * (tc * tc), acc_mag * tc, acc_mag
    elif tc >= td:
        x = 0.5 * acc_mag * (ta * ta) + peak * (tc - ta) - 0.5 * acc_mag * ((tc - td) * (tc - td))
        v, acc = peak - acc_mag * (tc - td), -acc_mag
    else:
        x, v, acc = 0.5 * acc_mag * (ta * ta) + peak * (tc - ta), peak, 0.0
    if t >= total:
        v = acc = 0.0
    return a + sgn * x, sgn * v, sgn * acc


def _wrapped_one(d: float) -> float:
    return abs((d + 180.0) % 360.0 - 180.0)


class ArmPaths:
    """Swept-path clearance of moves between joint rows of one rig (columns ``names``, degrees)."""

    def __init__(
        self,
        geometry: RigGeometry,
        names: Sequence[str],
        speed: FloatArray,
        accel: FloatArray,
        coordinated: bool,
        held: dict[str, float] | None = None,
    ) -> None:
        """``names``: the joints that move (columns); ``held``: the angles (deg) of arm joints without an axis."""
        self.geometry, self.names = geometry, list(names)
        held = held or {}
        self.held_light = float(held.get("light", 0.0))
        self.held_camera = float(held.get("camera", 0.0))
        self.speed, self.accel, self.coordinated = speed, accel, coordinated
        self.sep = float(geometry.min_separation_deg)
        self.light = self.names.index("light") if "light" in self.names else None
        self.camera = self.names.index("camera") if "camera" in self.names else None
        # A fixed camera (fixed_camera layout) sits at camera_azimuth_deg; the light arm moves.
        self.fixed = float(geometry.camera_azimuth_deg) if geometry.layout == "fixed_camera" else None

    @property
    def active(self) -> bool:
        """Whether any arm moves (else no move can collide)."""
        return self.sep > 0 and (self.light is not None or self.camera is not None)

    def _difference(self, x: FloatArray) -> FloatArray:
        """Light minus camera arm angle (deg) for joint rows ``x`` (..., k)."""
        light = x[..., self.light] if self.light is not None else self.held_light
        if self.fixed is not None:
            return np.asarray(light - self.fixed, dtype=np.float64)
        camera = x[..., self.camera] if self.camera is not None else self.held_camera
        return np.asarray(light - camera, dtype=np.float64)

    def clearance(self, src: FloatArray, dst: FloatArray) -> FloatArray:
        """Least arm separation (deg) over each move src[i] -> dst[i], minus the margins (conservative)."""
        src, dst = np.atleast_2d(src), np.atleast_2d(dst)
        n = len(src)
        d0, d1 = self._difference(src), self._difference(dst)
        if self.coordinated:
            lo, hi = np.minimum(d0, d1), np.maximum(d0, d1)
            crosses = np.floor(hi / 360.0) * 360.0 >= lo  # a multiple of 360 inside [lo, hi]
            least = np.where(crosses, 0.0, np.minimum(_wrapped(d0), _wrapped(d1)))
            return least - MARGIN_DEG
        if self.light is None and self.camera is None:
            return np.minimum(_wrapped(d0), _wrapped(d1))
        # Each arm's trapezoid is quadratic between its phase changes, so their difference is quadratic on
        # the pieces between all phase changes: its range there comes from the piece's ends and vertex.
        arms = [i for i in (self.light, self.camera) if i is not None]
        sign = {i: (1.0 if i == self.light else -1.0) for i in arms}  # d = light - camera
        prof = {i: _profile(src[:, i], dst[:, i], float(self.speed[i]), float(self.accel[i])) for i in arms}
        phases = [np.stack(prof[i][3:], axis=1) for i in arms] + [np.zeros((n, 1))]
        breaks = np.sort(np.concatenate(phases, axis=1), axis=1)
        lo = np.minimum(d0, d1)
        hi = np.maximum(d0, d1)
        for j in range(breaks.shape[1] - 1):
            t0, t1 = breaks[:, j], breaks[:, j + 1]
            span = t1 - t0
            mid = t0 + 0.5 * span
            x0 = np.sum([sign[i] * _state(prof[i], t0)[0] for i in arms], axis=0)
            v0 = np.sum([sign[i] * _state(prof[i], t0)[1] for i in arms], axis=0)
            acc = np.sum([sign[i] * _state(prof[i], mid)[2] for i in arms], axis=0)
            if self.fixed is None and self.camera is None:
                x0 = x0 - self.held_camera
            elif self.fixed is not None:
                x0 = x0 - self.fixed
            elif self.light is None:
                x0 = x0 + self.held_light
            with np.errstate(divide="ignore", invalid="ignore"):
                tau = np.where(acc != 0, -v0 / acc, 0.0)
            tau = np.clip(np.where(np.isfinite(tau), tau, 0.0), 0.0, span)
            for t in (span, tau):
                x = x0 + v0 * t + 0.5 * acc * t * t
                lo, hi = np.minimum(lo, x), np.maximum(hi, x)
        crossing = np.floor(hi / 360.0) * 360.0 >= lo
        swept: FloatArray = np.where(crossing, 0.0, np.minimum(_wrapped(lo), _wrapped(hi)))
        return swept - MARGIN_DEG

    def _difference_one(self, x: Sequence[float] | FloatArray) -> float:
        light = x[self.light] if self.light is not None else self.held_light
        if self.fixed is not None:
            return light - self.fixed
        return light - (x[self.camera] if self.camera is not None else self.held_camera)

    def clearance_one(self, src: Sequence[float] | FloatArray, dst: Sequence[float] | FloatArray) -> float:
        """``clearance`` of the one move src -> dst (joint angles in deg), in Python floats: the same number."""
        src, dst = [float(v) for v in src], [float(v) for v in dst]
        d0, d1 = self._difference_one(src), self._difference_one(dst)
        if self.coordinated:
            lo, hi = min(d0, d1), max(d0, d1)
            crosses = math.floor(hi / 360.0) * 360.0 >= lo
            return (0.0 if crosses else min(_wrapped_one(d0), _wrapped_one(d1))) - MARGIN_DEG
        if self.light is None and self.camera is None:
            return min(_wrapped_one(d0), _wrapped_one(d1))
        arms = [(i, 1.0 if i == self.light else -1.0) for i in (self.light, self.camera) if i is not None]
        prof = [(sgn, _profile_one(src[i], dst[i], float(self.speed[i]), float(self.accel[i]))) for i, sgn in arms]
        breaks = sorted([0.0, *(t for _, p in prof for t in p[3:])])
        offset = 0.0  # what the difference adds for an arm without an axis (or the fixed camera)
        if self.fixed is None and self.camera is None:
            offset = -self.held_camera
        elif self.fixed is not None:
            offset = -self.fixed
        elif self.light is None:
            offset = self.held_light
        lo, hi = min(d0, d1), max(d0, d1)
        for t0, t1 in itertools.pairwise(breaks):
            span = t1 - t0
            mid = t0 + 0.5 * span
            start = [(sgn, _state_one(p, t0)) for sgn, p in prof]
            x0, v0 = start[0][0] * start[0][1][0], start[0][0] * start[0][1][1]
            acc = prof[0][0] * _state_one(prof[0][1], mid)[2]
            if len(prof) == 2:
                x0 = x0 + start[1][0] * start[1][1][0]
                v0 = v0 + start[1][0] * start[1][1][1]
                acc = acc + prof[1][0] * _state_one(prof[1][1], mid)[2]
            if offset:
                x0 = x0 + offset
            tau = -v0 / acc if acc != 0 else 0.0
            tau = min(max(tau if math.isfinite(tau) else 0.0, 0.0), span)
            for t in (span, tau):
                x = x0 + v0 * t + 0.5 * acc * t * t
                lo, hi = min(lo, x), max(hi, x)
        crossing = math.floor(hi / 360.0) * 360.0 >= lo
        return (0.0 if crossing else min(_wrapped_one(lo), _wrapped_one(hi))) - MARGIN_DEG

    def safe_one(self, src: Sequence[float] | FloatArray, dst: Sequence[float] | FloatArray) -> bool:
        """``safe`` of the one move src -> dst (joint angles in deg), the same decision at a fraction of the cost."""
        if not self.active:
            return True
        start = _wrapped_one(self._difference_one([float(v) for v in src]))
        return self.clearance_one(src, dst) >= min(self.sep, start - MARGIN_DEG)

    def safe(self, src: FloatArray, dst: FloatArray) -> npt.NDArray[np.bool_]:
        """Which moves keep the arms ``min_separation_deg`` apart throughout (or never closer than at the start)."""
        if not self.active:
            return np.ones(len(np.atleast_2d(src)), dtype=bool)
        src = np.atleast_2d(src)
        start = _wrapped(self._difference(src))
        need = np.minimum(self.sep, start - MARGIN_DEG)  # a parked start: never closer than it began
        ok: npt.NDArray[np.bool_] = self.clearance(src, dst) >= need
        return ok

    def legs(self, src: FloatArray, dst: FloatArray) -> list[FloatArray] | None:
        """Poses (each (k,)) a move src -> dst goes through, ending at dst; None when no split is safe."""
        src, dst = np.asarray(src, dtype=np.float64), np.asarray(dst, dtype=np.float64)
        if self.safe_one(src, dst):
            return [dst]
        arms = [i for i in (self.light, self.camera) if i is not None]
        for first in arms:
            # One arm (with the stage joints) first, then the other arm.
            mid = dst.copy()
            for other in arms:
                if other != first:
                    mid[other] = src[other]
            if self.safe_one(src, mid) and self.safe_one(mid, dst):
                return [mid, dst]
        return None


def gap_of(paths: ArmPaths, rows: FloatArray) -> npt.NDArray[np.int64]:
    """Which side of the other arm each pose is on, in joint space: floor((light - camera) / 360).

    Two poses on different sides can only be joined by a move that passes the arms through each other (or
    beyond a joint limit), so a run keeps to one side.
    """
    d = paths._difference(np.atleast_2d(rows))
    return np.floor(d / 360.0).astype(np.int64)


def safe_sequence(
    paths: ArmPaths, start: FloatArray, rows: FloatArray
) -> tuple[npt.NDArray[np.bool_], dict[int, list[FloatArray]]]:
    """Walk from ``start`` through ``rows`` (n, k) in order: which rows are kept, and the waypoints before each.

    A move whose swept path is unsafe is split (``ArmPaths.legs``); a row no split reaches safely from the
    previous kept pose is dropped. Every direct move is checked at once; only the unsafe ones are revisited.
    """
    n = len(rows)
    kept = np.ones(n, dtype=bool)
    via: dict[int, list[FloatArray]] = {}
    if n == 0 or not paths.active:
        return kept, via
    prev_rows = np.vstack([start[None, :], rows[:-1]])
    direct = paths.safe(prev_rows, rows)
    here = start
    chained = True  # whether `here` is rows[i - 1], so that direct[i] applies
    for i in range(n):
        if chained and direct[i]:
            here = rows[i]
            continue
        legs = paths.legs(here, rows[i])
        if legs is None:
            kept[i] = False
            chained = False
            continue
        if len(legs) > 1:
            via[i] = legs[:-1]
        here = rows[i]
        chained = True
    return kept, via
