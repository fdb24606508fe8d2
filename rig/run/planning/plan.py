"""Sweep plans: reachability checked, points ordered for the shortest run, and the run time estimated.

``plan_sweep`` takes the rows of a sweep (``rig.run.config.sweeps``: theta_i, phi_i, theta_o, phi_o in degrees), solves
the kinematics for all of them at once, and splits them into points to measure and points skipped
with the kinematics' reason code and message; nothing is dropped silently (``len(points) +
len(skipped)`` is the number of rows). A point the geometry reaches but an ``Axis`` cannot (its
``min_deg``/``max_deg`` are narrower than the geometry's joint limits, or the joint has no axis at all
and would have to move) is skipped with reason ``joint_limit`` and the axis named in the detail.

Ordering (``order_points``, ``rig.run.planning.order``) minimises the summed move time of the open path from the
start pose through every point: greedy nearest neighbour, then 2-opt and Or-opt (on windows, then on the
whole move-time matrix up to 1000 points) until no move improves it; deterministic, and never worse than
the order the sweep was generated in. Reference captures are placed after ordering and are not
considered by it.

``plan_sweep`` reads as its stages (``PLAN_STAGES``), each a function below. What a plan is (``Plan`` and its
parts) is in result.py, move times in moves.py, the ordering in order.py, the swept paths in paths.py and the
calibrated joints in alignment.py; ``Plan``, ``move_time_s`` and the rest are importable from here too.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from rig.instrument.alignment import Alignment
from rig.instrument.axis import Axis, AxisLimitError
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Branch, Joints, Reason, Solution, solve_degrees
from rig.run.planning.alignment import calibrated_joints
from rig.run.planning.moves import FIXED_JOINT_TOL_DEG, _axis_map, _Moves, move_time_s, order_points
from rig.run.planning.order import FloatArray, order_path, step_times
from rig.run.planning.paths import gap_of, safe_sequence
from rig.run.planning.result import Directions, Plan, PlannedPoint, SkippedPoint, TimeEstimate, format_duration
from rig.run.planning.scans import ScanRunTime, ScanTiming, scan_runs

__all__ = [
    "Plan",
    "PlannedPoint",
    "SkippedPoint",
    "TimeEstimate",
    "format_duration",
    "move_time_s",
    "order_points",
    "plan_sweep",
]

#: Reason code of a point that cannot be reached without the arms passing through each other.
ARMS_CROSS = "arms_cross"


#: What plan_sweep does, in order (its ``on_stage`` hears each name as it begins).
PLAN_STAGES = ("kinematics", "arm sides", "ordering", "swept paths", "time estimate")


def plan_sweep(
    directions_deg: FloatArray,
    geometry: RigGeometry,
    axes: Sequence[Axis],
    *,
    start: Joints | None = None,
    settle_s: float = 0.0,
    exposure_s_per_point: float = 0.0,
    overhead_s_per_point: float = 0.0,
    reference_every: int = 0,
    reference_s: float = 0.0,
    reference_joints: Joints | None = None,
    order: bool = True,
    coordinated: bool = False,
    isotropic: bool = False,
    branch: Branch = "camera_cw",
    alignment: Alignment | None = None,
    on_stage: Callable[[str], None] | None = None,
    scan: ScanTiming | None = None,
) -> Plan:
    """Plan rows (N, 4) of BRDF angles in degrees on a rig: reachability, order, and time estimate in seconds.

    ``start`` defaults to every joint at 0 deg; a joint with no axis in ``axes`` stays at its start angle.
    References: one before the first point, one after every ``reference_every`` points (0: none in
    between) and one after the last, each costing ``reference_s`` plus, if ``reference_joints`` is given,
    the detour there and back and ``settle_s``. ``coordinated`` estimates GRBL-style straight moves.
    ``isotropic`` turns each pair about the normal so the roll joint stays at ``start``'s (in-plane rig:
    into the arm plane), so a rig without a roll axis measures it; skipped details then describe the
    turned pair. ``branch`` picks the four-axis solution (see ``rig.instrument.kinematics``). ``alignment``
    (a geometry calibration's) corrects each reachable point's joints so the real rig measures the wanted
    directions (``rig.instrument.alignment.aligned_inverse``); a point it cannot reach within 0.01 deg is
    skipped as ``calibrated_miss``. ``on_stage`` is told the name of each of the ``PLAN_STAGES`` as it begins
    (a progress bar for a large plan). ``scan`` (continuous motion) times the runs a scan sweeps
    (``rig.run.planning.scans``) at their speed instead of stop by stop.
    """
    stage = on_stage or (lambda _name: None)
    rows = _checked_rows(directions_deg, settle_s, exposure_s_per_point, overhead_s_per_point, reference_s,
                         reference_every)  # fmt: skip
    by_name, start = _checked_rig(geometry, axes, start, reference_joints)

    stage(PLAN_STAGES[0])  # every row's joints, and the rows no axis can reach
    sol = _solve(geometry, rows, start, branch, isotropic)
    verdicts = _Verdicts(np.asarray(sol.reason).reshape(len(rows)).copy(), {})
    placed = _placed_joints(geometry, sol, start, by_name, alignment, verdicts)

    stage(PLAN_STAGES[1])  # one side of the arms for the whole run
    moves = _Moves.of(geometry, by_name, start, coordinated)
    r_row = None if reference_joints is None else moves.row(reference_joints)
    good, xg_all = _one_side(moves, placed, verdicts, r_row)

    stage(PLAN_STAGES[2])
    perm = np.arange(len(good), dtype=np.intp)
    if order:
        perm = np.asarray(order_path(xg_all, moves.start, moves.speed, moves.accel, coordinated), dtype=np.intp)
    stage(PLAN_STAGES[3])  # the moves in that order, split into legs that keep the arms apart
    perm, x, via = _safe_walk(moves, xg_all[perm], perm, good, verdicts)
    points = tuple(
        PlannedPoint(int(good[k]), _directions(rows, int(good[k])), moves.as_joints(x[pos]),
                     tuple(map(moves.as_joints, via.get(pos, ()))))
        for pos, k in enumerate(perm)
    )  # fmt: skip
    skipped = verdicts.skipped(rows, sol)

    stage(PLAN_STAGES[4])
    path, steps = _walk_times(moves, x, via)
    refs = _reference_positions(len(points), int(reference_every))
    ref_total, ref_split = _reference_time(moves, path, steps, refs, r_row, points, reference_s, settle_s)
    unordered = None
    if order:  # the same walk (legs included) in the sweep's own order
        kept_g, via_g = safe_sequence(moves.paths, moves.start, xg_all)
        unordered = float(_walk_times(moves, xg_all[kept_g], _kept_via(kept_g, via_g))[1].sum())
    if scan is not None:
        scan = replace(scan, stop_point_s=settle_s + exposure_s_per_point + overhead_s_per_point)
    runs = _scan_runs(moves, by_name, points, x, set(refs) if r_row is not None else set(), scan)
    swept = [p for r in runs for p in r.swept]
    n = len(points) - len(swept)  # measured at rest
    estimate = TimeEstimate(
        motion_s=float(sum(steps)) - float(sum(steps[p] for p in swept)),
        settle_s=n * settle_s,
        exposure_s=n * exposure_s_per_point,
        reference_s=float(ref_total),
        overhead_s=n * overhead_s_per_point,
        reference_captures=len(refs),
        scan_s=sum(r.time_s for r in runs),
        scanned=len(swept),
        scan_speeds_deg_s=(min(r.speed_deg_s for r in runs), max(r.speed_deg_s for r in runs)) if runs else None,
    )
    n = len(points)
    n_moves = n + (2 * len(refs) - (1 if refs and refs[-1] == n else 0) if r_row is not None else 0)
    return Plan(points, skipped, estimate, start, refs, reference_joints, unordered, len(via) + ref_split, n_moves,
                moves.paths)  # fmt: skip


def _checked_rows(
    directions_deg: FloatArray, settle_s: float, exposure_s_per_point: float, overhead_s_per_point: float,
    reference_s: float, reference_every: int,
) -> FloatArray:
    """The sweep's rows (N, 4) in degrees as floats; a ValueError names a bad shape, a bad time or reference_every."""
    rows = np.asarray(directions_deg, dtype=np.float64)
    if rows.ndim != 2 or rows.shape[1] != 4:
        raise ValueError(f"directions_deg must have shape (N, 4) (theta_i, phi_i, theta_o, phi_o), got {rows.shape}")
    for key, value in (("settle_s", settle_s), ("exposure_s_per_point", exposure_s_per_point),
                       ("overhead_s_per_point", overhead_s_per_point), ("reference_s", reference_s)):  # fmt: skip
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{key} = {value!r}, expected a finite number of seconds >= 0")
    if isinstance(reference_every, bool) or not (
        isinstance(reference_every, int | np.integer) and reference_every >= 0
    ):
        raise ValueError(f"reference_every = {reference_every!r}, expected a whole number of points >= 0")
    return rows


def _checked_rig(
    geometry: RigGeometry, axes: Sequence[Axis], start: Joints | None, reference_joints: Joints | None
) -> tuple[dict[str, Axis], Joints]:
    """The axes by joint name and the start pose (every joint at 0 deg if None), checked against the geometry.

    Raises ValueError for an axis that is no joint of the rig, a pose with other joints, and AxisLimitError
    for a reference pose outside its axes' limits.
    """
    names = geometry.joint_names
    by_name = _axis_map(axes)
    stray = sorted(set(by_name) - set(names))
    if stray:
        raise ValueError(f"axes {stray} are not joints of a {geometry.layout} rig ({', '.join(names)})")
    start = start if start is not None else Joints.from_dict(dict.fromkeys(names, 0.0))
    for what, j in (("start", start), ("reference_joints", reference_joints)):
        if j is not None and set(j.as_dict()) != set(names):
            raise ValueError(f"{what} has joints {sorted(j.as_dict())}, a {geometry.layout} rig has {list(names)}")
    if reference_joints is not None:
        for name, angle in reference_joints.as_dict().items():
            if name in by_name:
                by_name[name].check(float(np.asarray(angle)))
    return by_name, start


@dataclass(frozen=True)
class _Verdicts:
    """Why each sweep row is skipped, filled in as the planner finds out: its ``Reason`` code ("" while it is
    to be measured) and, where the planner rather than the kinematics decided, the words."""

    reason: npt.NDArray[np.str_]
    detail: dict[int, str]

    def skip(self, i: int, reason: str, detail: str) -> None:
        """Skip row ``i`` for this reason."""
        self.reason[i] = reason
        self.detail[i] = detail

    def skipped(self, rows: FloatArray, sol: Solution) -> tuple[SkippedPoint, ...]:
        """The skipped rows in sweep order; the kinematics' own message where the planner left no words."""
        out = []
        for i in np.flatnonzero(self.reason != ""):
            text = self.detail.get(int(i))
            if text is None:
                unreachable = sol.at(int(i))
                text = getattr(unreachable, "message", str(self.reason[i]))
            out.append(SkippedPoint(int(i), _directions(rows, int(i)), str(self.reason[i]), text))
        return tuple(out)


def _directions(rows: FloatArray, i: int) -> Directions:
    r = rows[i]
    return float(r[0]), float(r[1]), float(r[2]), float(r[3])


def _solve(geometry: RigGeometry, rows: FloatArray, start: Joints, branch: Branch, isotropic: bool) -> Solution:
    """The kinematics of every row; isotropic rows turned about the normal to keep roll (or the plane) fixed."""
    sol = solve_degrees(geometry, rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3], branch=branch, near=start)
    if not isotropic:
        return sol
    if geometry.layout == "in_plane":
        # Turn the light's azimuth (the camera's at normal incidence) into the arm plane.
        psi = geometry.plane_azimuth_deg - np.where(rows[:, 0] == 0.0, rows[:, 3], rows[:, 1])
    else:
        # Turning both directions by psi about the normal turns the roll joint by -psi.
        psi = np.asarray(sol.joints.roll, dtype=np.float64) - float(np.asarray(start.roll))
    psi = np.where(np.isfinite(psi), psi, 0.0)
    t = rows + np.stack([0.0 * psi, psi, 0.0 * psi, psi], axis=-1)
    return solve_degrees(geometry, t[:, 0], t[:, 1], t[:, 2], t[:, 3], branch=branch, near=start)


def _axis_check(
    geometry: RigGeometry, name: str, values: FloatArray, start_deg: float, axis: Axis | None
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:
    """Joint angles moved to a whole-turn equivalent inside the axis's and the geometry's limits; and the fit mask."""
    if axis is None:
        return values, np.abs(values - start_deg) <= FIXED_JOINT_TOL_DEG
    g_lo, g_hi = geometry.limits.of(name)
    lo, hi = max(axis.min_deg, g_lo), min(axis.max_deg, g_hi)
    cand = values[:, None] + 360.0 * np.array([0.0, -1.0, 1.0, -2.0, 2.0])
    inside = (cand >= lo) & (cand <= hi)
    score = np.where(inside, np.abs(cand - start_deg), np.inf)
    best = cand[np.arange(len(values)), np.argmin(score, axis=1)]
    ok: npt.NDArray[np.bool_] = np.asarray(inside.any(axis=1))
    return np.where(ok, best, values), ok


def _axis_detail(name: str, value: float, start_deg: float, axis: Axis | None) -> str:
    if axis is None:
        return (
            f"joint {name!r} has no axis (fixed at {start_deg:g} deg), but this point needs {value:.6g} deg; "
            f"plan with isotropic=True for an isotropic sample"
        )
    try:
        axis.check(value)
    except AxisLimitError as exc:
        return f"{exc} (Axis.min_deg/max_deg)"
    return f"axis {name!r}: {value:.6g} deg fits the axis but not the geometry's limits.{name}"


def _placed_joints(
    geometry: RigGeometry, sol: Solution, start: Joints, by_name: dict[str, Axis], alignment: Alignment | None,
    verdicts: _Verdicts,
) -> dict[str, FloatArray]:
    """Every row's joint angles (degrees): calibrated by the alignment, then moved to a whole-turn equivalent
    inside each axis's limits; a row some axis cannot reach is skipped as ``joint_limit``."""
    n = len(verdicts.reason)
    solved = {name: np.asarray(getattr(sol.joints, name), dtype=np.float64).reshape(n) for name in geometry.joint_names}
    if alignment is not None and not alignment.is_zero:
        solved = calibrated_joints(geometry, sol, solved, verdicts.reason, verdicts.detail, alignment)
    placed: dict[str, FloatArray] = {}
    for name in geometry.joint_names:
        values = solved[name]
        s0 = float(np.asarray(getattr(start, name)))
        placed[name], fits = _axis_check(geometry, name, values, s0, by_name.get(name))
        for i in np.flatnonzero((verdicts.reason == "") & ~fits):
            verdicts.skip(int(i), Reason.JOINT_LIMIT.value, _axis_detail(name, float(values[i]), s0, by_name.get(name)))
    return placed


def _one_side(
    moves: _Moves, placed: dict[str, FloatArray], verdicts: _Verdicts, r_row: FloatArray | None
) -> tuple[npt.NDArray[np.intp], FloatArray]:
    """The rows still to measure and their moving joints (degrees), the arms on one side of each other.

    One side for the whole run (the reference pose's, else the most points'): the others cannot be reached
    without the arms passing through each other, and are skipped.
    """
    good = np.flatnonzero(verdicts.reason == "")
    xg_all = np.stack([placed[n][good] for n in moves.moving], axis=1) if moves.moving else np.zeros((len(good), 0))
    if not (moves.paths.active and len(good)):
        return good, xg_all
    gaps = gap_of(moves.paths, xg_all)
    common = int(np.bincount(gaps - gaps.min()).argmax() + gaps.min())
    side = int(gap_of(moves.paths, r_row)[0]) if r_row is not None else common
    other = gaps != side
    for i in good[other]:
        verdicts.skip(int(i), ARMS_CROSS,
                      f"the light and camera arms are on the other side of each other here than at "
                      f"{'the reference pose' if r_row is not None else 'most points'}: reaching it "
                      "would pass the arms through each other (min_separation_deg)")  # fmt: skip
    return good[~other], xg_all[~other]


def _safe_walk(
    moves: _Moves, x: FloatArray, perm: npt.NDArray[np.intp], good: npt.NDArray[np.intp], verdicts: _Verdicts
) -> tuple[npt.NDArray[np.intp], FloatArray, dict[int, list[FloatArray]]]:
    """The walk through the ordered points ``x`` (rows ``good[perm]``) that keeps the arms apart: (perm, x) of
    the points kept, and the legs of the moves split by position; a point no move reaches safely is skipped."""
    kept, via = safe_sequence(moves.paths, moves.start, x)
    for dropped in np.flatnonzero(~kept):
        verdicts.skip(int(good[perm[dropped]]), ARMS_CROSS,
                      "no move from the point before keeps the arms min_separation_deg apart, even split into legs")
    return perm[kept], x[kept], _kept_via(kept, via)


def _kept_via(kept: npt.NDArray[np.bool_], via: dict[int, list[FloatArray]]) -> dict[int, list[FloatArray]]:
    """The legs of split moves keyed by position among the kept points (``via`` counts the dropped ones too)."""
    return {int(np.count_nonzero(kept[:k])): legs for k, legs in via.items()}


def _walk_times(moves: _Moves, x: FloatArray, via: dict[int, list[FloatArray]]) -> tuple[FloatArray, FloatArray]:
    """The walk's poses (start, then ``x``, degrees) and each move's seconds, a split move timed leg by leg."""
    path = np.vstack([moves.start[None, :], x])
    steps = step_times(path[:-1], path[1:], moves.speed, moves.accel, moves.coordinated)
    for pos, legs in via.items():
        steps[pos] = moves.leg_time(path[pos], path[pos + 1], [*legs, path[pos + 1]])
    return path, steps


def _scan_runs(moves: _Moves, by_name: dict[str, Axis], points: Sequence[PlannedPoint], x: FloatArray,
               slots: set[int], scan: ScanTiming | None) -> tuple[ScanRunTime, ...]:  # fmt: skip
    """The runs a continuous run sweeps (none in stop and go), timed under the axes' limits; only where the straight
    sweep keeps the arms apart, as the runner scans."""
    if scan is None:
        return ()

    def straight(a: int, b: int) -> bool:
        legs = moves.paths.legs(x[a], x[b])
        return legs is not None and len(legs) == 1

    tops = {n: by_name[n].max_speed_deg_s for n in moves.moving}
    accels = {n: by_name[n].max_accel_deg_s2 for n in moves.moving}
    return scan_runs(points, slots, frozenset(moves.moving), tops, accels, scan, straight)


def _reference_positions(n: int, every: int) -> tuple[int, ...]:
    if n == 0:
        return ()
    if every == 0:
        return (0, n)
    return tuple(sorted({0, *range(every, n, every), n}))


def _reference_time(
    moves: _Moves, path: FloatArray, steps: FloatArray, refs: tuple[int, ...], r_row: FloatArray | None,
    points: Sequence[PlannedPoint], reference_s: float, settle_s: float,
) -> tuple[float, int]:
    """Seconds of the reference captures (``reference_s`` each, plus with a reference pose the detour there and
    back and ``settle_s``), and how many of the detours' moves are split into legs."""
    total = len(refs) * reference_s
    split = 0
    if r_row is not None and refs:
        for k in map(int, refs):
            out_legs = moves.paths.legs(path[k], r_row)
            back_legs = moves.paths.legs(r_row, path[k + 1]) if k < len(points) else [r_row]
            if out_legs is None or back_legs is None:
                where = f"point #{points[k - 1].index}" if k else "the start pose"
                raise ValueError(f"the reference pose cannot be reached from {where} (or back) without the arms "
                                 "passing through each other; move [reference] theta_i_deg/theta_o_deg")  # fmt: skip
            split += (len(out_legs) > 1) + (len(back_legs) > 1)
            back = moves.leg_time(r_row, path[k + 1], back_legs) - steps[k] if k < len(points) else 0.0
            total += moves.leg_time(path[k], r_row, out_legs) + back + settle_s
    return total, split
