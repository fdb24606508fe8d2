"""Continuous scans as a plan sees them: which points one sweep measures moving, how fast, and in what time.

A *scan run* (``scan_run``) is a stretch of consecutive planned points that differ in one driven joint only,
monotonic in it, with no reference reading or via pose between them; the runner measures its first point at rest
and the rest in one constant-speed sweep (``rig.run.measuring.scan``). Both the runner and the plan's time
estimate find runs with this one rule, and choose a run's speed with ``chosen_speed_deg_s`` when the sweep file
leaves ``scan_speed_deg_s`` out.

The chosen speed is the fastest of three bounds, each in deg/s of the scanning joint:

- the axis's top speed (``max_speed_deg_s`` of the rig file's axis, the limit the plan's move times use);
- the blur: a frame of exposure ``t`` at speed ``v`` smears over ``v t``, which must stay within ``BLUR_FRACTION``
  of the run's smallest step;
- the camera's pace: a frame and its darks, each with the camera's overhead, must be done before the arm reaches
  the next point, or the frames fall behind the points they were meant for.

Within these bounds a scan of long exposures can be slower than stopping: each step then takes about
``SPEED_HEADROOM / BLUR_FRACTION`` exposures of travel, a stop one reading and a short move. A run whose scan at the
chosen speed would take longer than stopping at each of its points (``run_time_s`` against ``stops_time_s``) is
measured stop and go instead; a speed the sweep gives is always scanned at.

The blur and pace bounds use the exposure planned for the run's first frame, divided by ``SPEED_HEADROOM``: the
speed is set once per run (a servo's Profile Velocity, a GRBL feed), while each later frame is planned from the
frame before and may need a longer exposure. A frame's exposure for a fixed SNR grows as its level falls, so the
headroom is the fall in level a run absorbs before a frame blurs past the bound (then the scan warns,
``ScanTooFast``, with the blur it costs). Two: a run's frames are planned at a quarter of saturation
(``SCAN_SAFETY``) so a brighter next point never clips, and a dimmer one within a factor of two keeps its blur
within bounds; a larger headroom slows every scan in proportion (the sweep's rig time with it) to cover the
steep flanks of a specular lobe, which a lab can still do by giving ``scan_speed_deg_s``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from rig.run.planning.order import trapezoid_time_s
from rig.run.planning.result import PlannedPoint

#: Motion blur (deg) a frame may have, as a fraction of the smallest step of its scan run, before ScanTooFast.
BLUR_FRACTION = 0.5
#: How much longer than the run's first frame a later frame's exposure may grow before the chosen speed blurs it
#: past BLUR_FRACTION of the step (or the camera falls behind the points); see the module docstring.
SPEED_HEADROOM = 2.0


def scan_run(points: Sequence[PlannedPoint], start: int, done: set[int], slots: set[int],
             driven: frozenset[str]) -> tuple[str, list[int]] | None:  # fmt: skip
    """The joint a scan from plan position ``start`` moves and the positions it reaches (None: no scan)."""
    prev = points[start].joints.as_dict()
    joint, direction, out = "", 0, []
    for pos in range(start + 1, len(points)):
        p = points[pos]
        if p.index in done or pos in slots or p.via:
            break
        cur = p.joints.as_dict()
        changed = [k for k in cur if abs(float(cur[k]) - float(prev[k])) > 1e-9]
        if len(changed) != 1 or changed[0] not in driven or (joint and changed[0] != joint):
            break
        step = 1 if float(cur[changed[0]]) > float(prev[changed[0]]) else -1
        if direction and step != direction:
            break
        joint, direction = changed[0], step
        out.append(pos)
        prev = cur
    return (joint, out) if out else None


def run_angles(points: Sequence[PlannedPoint], start: int, rest: Sequence[int], joint: str) -> list[float]:
    """The scanning joint's angles (deg) at the run's points, its first (at rest) included."""
    return [float(points[p].joints.as_dict()[joint]) for p in (start, *rest)]


def smallest_step_deg(angles: Sequence[float]) -> float:
    """The smallest step (deg) between consecutive angles of a run."""
    return min(abs(b - a) for a, b in itertools.pairwise(angles))


def frame_time_s(exposure_s: float, dark_frames: int, overhead_s: float) -> float:
    """Camera seconds one scanned frame takes: the light frame and its darks, each exposure plus overhead (s)."""
    return (1 + dark_frames) * (exposure_s + overhead_s)


@dataclass(frozen=True)
class SpeedChoice:
    """A scan run's speed (deg/s) and what set it: "given" (the sweep file), "axis", "blur" or "camera"."""

    speed_deg_s: float
    bound: str


def chosen_speed_deg_s(step_deg: float, exposure_s: float, top_deg_s: float, *, dark_frames: int = 0,
                       overhead_s: float = 0.0) -> SpeedChoice:  # fmt: skip
    """The fastest speed (deg/s) within the axis's ``top_deg_s``, the blur bound and the camera's pace for a run of
    smallest step ``step_deg`` (deg) whose first frame is exposed ``exposure_s`` (s); see the module docstring."""
    grown = SPEED_HEADROOM * exposure_s
    bounds = {
        "axis": top_deg_s,
        "blur": BLUR_FRACTION * step_deg / grown if grown > 0 else math.inf,
        "camera": step_deg / frame_time_s(grown, dark_frames, SPEED_HEADROOM * overhead_s) if grown > 0 else math.inf,
    }
    bound = min(bounds, key=lambda k: bounds[k])
    return SpeedChoice(float(bounds[bound]), bound)


def run_time_s(angles: Sequence[float], speed_deg_s: float, accel_deg_s2: float, frame_s: float) -> float:
    """Seconds a scan run over ``angles`` (deg) takes from its first point, at rest, to rest at its last: the joint's
    trapezoid at ``speed_deg_s``, or its frames' camera time (``frame_s`` each) if longer."""
    travel = float(trapezoid_time_s(abs(angles[-1] - angles[0]), speed_deg_s, accel_deg_s2))
    return max(travel, (len(angles) - 1) * frame_s)


def stops_time_s(angles: Sequence[float], top_deg_s: float, accel_deg_s2: float, point_s: float) -> float:
    """Seconds stopping at each point of a run after its first takes: each step's move at the axis's limits, and
    ``point_s`` at each point (settling and the reading at rest)."""
    steps = np.abs(np.diff(np.asarray(angles, dtype=np.float64)))
    return float(np.sum(trapezoid_time_s(steps, top_deg_s, accel_deg_s2))) + len(steps) * point_s


@dataclass(frozen=True)
class ScanTiming:
    """What a plan's estimate of continuous scans needs: the speed the sweep gives (None: chosen per run), and each
    frame's exposure, darks and camera overhead (s) as the estimate guesses them."""

    speed_deg_s: float | None
    exposure_s: float
    dark_frames: int = 0
    overhead_s: float = 0.0
    #: Seconds a point measured at rest costs beyond its move (settling, the reading): with the speed chosen, a run
    #: that stopping at each point would measure sooner is left to stop and go, as the runner leaves it.
    stop_point_s: float = 0.0

    def speed(self, step_deg: float, top_deg_s: float) -> float:
        """A run's speed (deg/s): the given one up to the axis's top speed (as the links cap it), else chosen."""
        if self.speed_deg_s is not None:
            return min(self.speed_deg_s, top_deg_s)
        return chosen_speed_deg_s(step_deg, self.exposure_s, top_deg_s, dark_frames=self.dark_frames,
                                  overhead_s=self.overhead_s).speed_deg_s  # fmt: skip


@dataclass(frozen=True)
class ScanRunTime:
    """One scan run in a plan: its first point's position (measured at rest), the positions swept, the joint,
    its speed (deg/s) and the run's seconds from the first point to rest at the last (travel or frames, the longer).
    """

    start: int
    swept: tuple[int, ...]
    joint: str
    speed_deg_s: float
    time_s: float


def scan_runs(points: Sequence[PlannedPoint], slots: set[int], driven: frozenset[str], tops: dict[str, float],
              accels: dict[str, float], timing: ScanTiming,
              straight: Callable[[int, int], bool] | None = None) -> tuple[ScanRunTime, ...]:  # fmt: skip
    """The scan runs a continuous run of ``points`` would sweep, each timed: the joint's trapezoid over the run's
    travel at its speed (``tops``, ``accels``: each driven joint's limits, deg/s and deg/s^2), or the frames'
    camera time if longer. ``straight(a, b)``, if given, says whether the sweep from plan position a to b is a
    safe straight move (the runner scans only those)."""
    out: list[ScanRunTime] = []
    pos = 0
    while pos < len(points):
        run = scan_run(points, pos, set(), slots, driven)
        if run is None or (straight is not None and not straight(pos, run[1][-1])):
            pos += 1
            continue
        joint, rest = run
        angles = run_angles(points, pos, rest, joint)
        speed = timing.speed(smallest_step_deg(angles), tops[joint])
        took = run_time_s(angles, speed, accels[joint], frame_time_s(timing.exposure_s, timing.dark_frames,
                                                                     timing.overhead_s))  # fmt: skip
        stopping = stops_time_s(angles, tops[joint], accels[joint], timing.stop_point_s)
        if timing.speed_deg_s is None and stopping < took:
            pos = rest[-1]  # measured at rest, as the runner measures such a run
            continue
        out.append(ScanRunTime(pos, tuple(rest), joint, speed, took))
        pos = rest[-1] + 1
    return tuple(out)
