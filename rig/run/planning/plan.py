"""Sweep plans: reachability checked, points ordered for the shortest run, and the run time estimated.

``plan_sweep`` takes the rows of a sweep (``rig.run.config.sweeps``: theta_i, phi_i, theta_o, phi_o in degrees), solves
the kinematics for all of them at once, and splits them into points to measure and points skipped
with the kinematics' reason code and message; nothing is dropped silently (``len(points) +
len(skipped)`` is the number of rows). A point the geometry reaches but an ``Axis`` cannot (its
``min_deg``/``max_deg`` are narrower than the geometry's joint limits, or the joint has no axis at all
and would have to move) is skipped with reason ``joint_limit`` and the axis named in the detail.

Move time model (``move_time_s``): every move starts and ends at rest. Independent axes (the Dynamixel
link: one synchronous write, each servo runs its own trapezoid) take the slowest axis's time;
``coordinated=True`` models GRBL's straight G1 moves, where all axes share one trapezoid along the
path and arrive together. ``Axis`` requires positive, finite speed and acceleration limits, so there is
no "unlimited" case. Links quantise these limits (a Dynamixel's Profile Velocity/Acceleration units,
its 46 rpm no-load speed), so a servo may run slightly faster or slower than the estimate.

Ordering (``order_points``, ``rig.run.planning.order``) minimises the summed move time of the open path from the
start pose through every point: greedy nearest neighbour, then 2-opt and Or-opt (on windows, then on the
whole move-time matrix up to 1000 points) until no move improves it; deterministic, and never worse than
the order the sweep was generated in. Reference captures are placed after ordering and are not
considered by it.

One file past 400 lines on purpose: reachability, ordering and the estimate share the plan's arrays;
what stands alone (ordering, swept paths, the calibrated joints) is in order.py, paths.py and
alignment.py.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from rig.instrument.alignment import Alignment
from rig.instrument.axis import Axis, AxisLimitError
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Branch, Joints, Reason, Solution, solve_degrees
from rig.run.planning.alignment import calibrated_joints
from rig.run.planning.order import FloatArray, order_path, pairwise_times, step_times
from rig.run.planning.paths import ArmPaths, gap_of, safe_sequence

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

Directions = tuple[float, float, float, float]
#: A joint without an axis is fixed; a point may differ from its fixed value by this much (degrees).
FIXED_JOINT_TOL_DEG = 1e-6
#: Reason code of a point that cannot be reached without the arms passing through each other.
ARMS_CROSS = "arms_cross"


@dataclass(frozen=True)
class PlannedPoint:
    """A point to measure: its row in the sweep as generated (``index``), its directions and joints in degrees.

    ``directions_deg`` is the sweep's row. With ``plan_sweep(isotropic=True)`` the joints measure it
    turned about the sample normal (equivalent for an isotropic sample); ``forward(joints)`` gives the
    directions actually measured.
    """

    index: int
    directions_deg: Directions
    joints: Joints
    #: Poses the move here passes through first: a direct move from the point before would bring the arms
    #: closer than the minimum separation on the way (``rig.run.planning.paths``).
    via: tuple[Joints, ...] = ()


@dataclass(frozen=True)
class SkippedPoint:
    """A row the rig cannot measure: its ``index`` and directions in degrees, a ``Reason`` code and why."""

    index: int
    directions_deg: Directions
    reason: str
    detail: str


@dataclass(frozen=True)
class TimeEstimate:
    """Estimated run time in seconds, by cause; ``reference_s`` includes the detours to the reference pose."""

    motion_s: float
    settle_s: float
    exposure_s: float
    reference_s: float
    overhead_s: float
    reference_captures: int = 0

    @property
    def total_s(self) -> float:
        """The whole run in seconds."""
        return self.motion_s + self.settle_s + self.exposure_s + self.reference_s + self.overhead_s


def format_duration(seconds: float) -> str:
    """A duration in seconds as text: "4.2 s", "42 s", "12 min 05 s", "1 h 02 min"."""
    if not np.isfinite(seconds):
        return "unknown"
    s = max(float(seconds), 0.0)
    if s < 9.95:
        return f"{s:.1f} s"
    if round(s) < 60:
        return f"{round(s)} s"
    if round(s) < 3600:
        m, sec = divmod(round(s), 60)
        return f"{m} min {sec:02d} s"
    h, m = divmod(round(s / 60.0), 60)
    return f"{h} h {m:02d} min"


def _fmt_row(d: Directions) -> str:
    return "(" + ", ".join(f"{v:g}" for v in d) + ") deg"


@dataclass(frozen=True)
class Plan:
    """A sweep ready to run: points in execution order, skipped points with reasons, the time estimate.

    ``reference_before`` lists positions k in ``points`` before which a reference is captured
    (k = len(points) means after the last point); ``reference_joints`` is where (None: where it stands).
    ``motion_as_generated_s`` is the motion time (seconds) in the sweep's own order, when it was reordered.
    """

    points: tuple[PlannedPoint, ...]
    skipped: tuple[SkippedPoint, ...]
    estimate: TimeEstimate
    start: Joints
    reference_before: tuple[int, ...] = ()
    reference_joints: Joints | None = None
    motion_as_generated_s: float | None = None
    #: Moves (to points and to and from the reference pose) split into safe legs, of ``moves`` in all.
    split_moves: int = 0
    moves: int = 0
    #: The swept-path check the plan used; the runner's guard checks every move at run time with it.
    paths: ArmPaths | None = field(default=None, compare=False, repr=False)

    def summary(self, examples: int = 3) -> str:
        """Human-readable plan: counts, unreachable points grouped by reason with examples, time by cause."""
        total = len(self.points) + len(self.skipped)
        lines = [f"Sweep of {total} points: {len(self.points)} to measure, {len(self.skipped)} unreachable"]
        groups: dict[str, list[SkippedPoint]] = {}
        for s in self.skipped:
            groups.setdefault(s.reason, []).append(s)
        for reason, items in sorted(groups.items(), key=lambda kv: (-len(kv[1]), kv[0])):
            lines.append(f"  {reason}: {len(items)} point{'s' if len(items) != 1 else ''}")
            lines.extend(f"    #{s.index} {_fmt_row(s.directions_deg)}: {s.detail}" for s in items[:examples])
            if len(items) > examples:
                lines.append(f"    ... and {len(items) - examples} more")
        e = self.estimate
        lines.append(
            f"Moves split into safe legs: {self.split_moves} of {self.moves} (a direct move would bring the arms "
            "closer than the minimum separation on the way)"
        )
        lines.append(f"Estimated run time: {format_duration(e.total_s)}")
        parts = [
            ("motion", e.motion_s, ""),
            ("settling", e.settle_s, ""),
            ("exposures", e.exposure_s, ""),
            ("references", e.reference_s, f" ({e.reference_captures} captures)"),
            ("overhead", e.overhead_s, ""),
        ]
        if self.motion_as_generated_s is not None:
            parts[0] = ("motion", e.motion_s, f" (ordered; {format_duration(self.motion_as_generated_s)} as generated)")
        lines.extend(f"  {name:<11}{format_duration(value):>14}{note}" for name, value, note in parts)
        return "\n".join(lines)

    def _repr_html_(self) -> str:
        """Jupyter's display: the summary, and the outgoing directions to measure and those unreachable."""
        from html import escape

        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        from model.notebook import figure_img

        fig = Figure(figsize=(4.0, 4.0), layout="tight")
        FigureCanvasAgg(fig)
        ax = fig.add_subplot(aspect="equal")
        for rows, marker, colour, label in (([p.directions_deg for p in self.points], "o", "#0072B2", "to measure"),
                                            ([s.directions_deg for s in self.skipped], "x", "#D55E00",
                                             "unreachable")):  # fmt: skip
            if rows:
                d = np.radians(np.asarray(rows, dtype=np.float64).reshape(len(rows), -1))
                rho, phi = np.sin(d[:, 2]), d[:, 3] - d[:, 1]  # theta_o, phi_o relative to the light's azimuth
                ax.scatter(rho * np.cos(phi), rho * np.sin(phi), s=14, marker=marker, color=colour, label=label)
        ax.set(xlim=(-1.05, 1.05), ylim=(-1.05, 1.05), xlabel="sin θo cos(φo − φi)", ylabel="sin θo sin(φo − φi)",
               title="outgoing directions")  # fmt: skip
        ax.legend(fontsize=7, loc="upper right")
        return f"<div><pre>{escape(self.summary())}</pre>{figure_img(fig)}</div>"


# ----------------------------------------------------------------------------------------------------------
# Move times


def _axis_map(axes: Sequence[Axis]) -> dict[str, Axis]:
    out: dict[str, Axis] = {}
    for axis in axes:
        if axis.name in out:
            raise ValueError(f"two axes are named {axis.name!r}")
        out[axis.name] = axis
    return out


def _limits(axes: dict[str, Axis], names: Sequence[str]) -> tuple[FloatArray, FloatArray]:
    """Speed (deg/s) and acceleration (deg/s^2) limits of the named axes, as arrays."""
    return (
        np.array([axes[n].max_speed_deg_s for n in names], dtype=np.float64),
        np.array([axes[n].max_accel_deg_s2 for n in names], dtype=np.float64),
    )


def move_time_s(a: Joints, b: Joints, axes: Sequence[Axis], *, coordinated: bool = False) -> float:
    """Seconds to move from joints ``a`` to ``b`` (degrees), rest to rest, under each axis's speed and accel limits.

    Independent axes take the slowest axis's trapezoid (triangle when too short to reach full speed);
    ``coordinated`` shares one trapezoid along the straight path (GRBL). A joint with no axis must not move.
    """
    by_name = _axis_map(axes)
    da, db = a.as_dict(), b.as_dict()
    if set(da) != set(db):
        raise ValueError(f"joints differ: {sorted(da)} and {sorted(db)}")
    moving = []
    for name in da:
        va, vb = float(np.asarray(da[name])), float(np.asarray(db[name]))
        if name in by_name:
            moving.append((name, va, vb))
        elif abs(va - vb) > FIXED_JOINT_TOL_DEG:
            raise ValueError(f"joint {name!r} moves from {va:g} to {vb:g} deg but no axis drives it")
    names = [m[0] for m in moving]
    speed, accel = _limits(by_name, names)
    src = np.array([[m[1] for m in moving]], dtype=np.float64)
    dst = np.array([[m[2] for m in moving]], dtype=np.float64)
    return float(pairwise_times(src, dst, speed, accel, coordinated)[0, 0])


def _moving_matrix(
    joints: Sequence[Joints], axes: dict[str, Axis], start: Joints
) -> tuple[FloatArray, FloatArray, list[str]]:
    """Joint angles (n, k) and start (k,) in degrees of the joints that have axes; fixed joints must not move."""
    names = list(start.as_dict())
    moving = [n for n in names if n in axes]
    x = np.array([[float(np.asarray(getattr(j, n))) for n in names] for j in joints], dtype=np.float64)
    s = np.array([float(np.asarray(getattr(start, n))) for n in names], dtype=np.float64)
    x = x.reshape(len(joints), len(names))
    for c, name in enumerate(names):
        if name not in axes and len(x) and np.max(np.abs(x[:, c] - s[c])) > FIXED_JOINT_TOL_DEG:
            raise ValueError(f"joint {name!r} has no axis but its angle changes between points")
    keep = [names.index(n) for n in moving]
    return x[:, keep], s[keep], moving


def order_points(
    joints: Sequence[Joints], axes: Sequence[Axis], start: Joints, *, coordinated: bool = False
) -> list[int]:
    """Order (indices into ``joints``) minimising the total move time in seconds from ``start`` through all points.

    Greedy nearest neighbour, then 2-opt and Or-opt on the symmetric move-time matrix; deterministic, and
    never worse than the given order.
    """
    by_name = _axis_map(axes)
    x, s, names = _moving_matrix(joints, by_name, start)
    speed, accel = _limits(by_name, names)
    return [int(i) for i in order_path(x, s, speed, accel, coordinated)]


# ----------------------------------------------------------------------------------------------------------
# Plans


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


def _reference_positions(n: int, every: int) -> tuple[int, ...]:
    if n == 0:
        return ()
    if every == 0:
        return (0, n)
    return tuple(sorted({0, *range(every, n, every), n}))


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
    (a progress bar for a large plan).
    """
    stage = on_stage or (lambda _name: None)
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

    stage(PLAN_STAGES[0])
    sol = _solve(geometry, rows, start, branch, isotropic)
    reason = np.asarray(sol.reason).reshape(len(rows)).copy()
    detail: dict[int, str] = {}
    solved = {n: np.asarray(getattr(sol.joints, n), dtype=np.float64).reshape(len(rows)) for n in names}
    if alignment is not None and not alignment.is_zero:
        solved = calibrated_joints(geometry, sol, solved, reason, detail, alignment)
    placed: dict[str, FloatArray] = {}
    for name in names:
        values = solved[name]
        s0 = float(np.asarray(getattr(start, name)))
        placed[name], fits = _axis_check(geometry, name, values, s0, by_name.get(name))
        for i in np.flatnonzero((reason == "") & ~fits):
            reason[i] = Reason.JOINT_LIMIT.value
            detail[int(i)] = _axis_detail(name, float(values[i]), s0, by_name.get(name))

    stage(PLAN_STAGES[1])
    good = np.flatnonzero(reason == "")
    moving = [n for n in names if n in by_name]
    speed, accel = _limits(by_name, moving)
    s = np.array([float(np.asarray(getattr(start, n))) for n in moving], dtype=np.float64)
    held = {n: float(np.asarray(getattr(start, n))) for n in names if n not in by_name}
    paths = ArmPaths(geometry, moving, speed, accel, coordinated, held)
    r_row = None
    if reference_joints is not None:
        r_row = np.array([float(np.asarray(getattr(reference_joints, n))) for n in moving], dtype=np.float64)
    xg_all = np.stack([placed[n][good] for n in moving], axis=1) if moving else np.zeros((len(good), 0))
    if paths.active and len(good):
        # One side of the arms for the whole run (the reference pose's, else the most points'): the others
        # cannot be reached without the arms passing through each other.
        gaps = gap_of(paths, xg_all)
        common = int(np.bincount(gaps - gaps.min()).argmax() + gaps.min())
        side = int(gap_of(paths, r_row)[0]) if r_row is not None else common
        other = gaps != side
        for i in good[other]:
            reason[i] = ARMS_CROSS
            detail[int(i)] = (f"the light and camera arms are on the other side of each other here than at "
                              f"{'the reference pose' if r_row is not None else 'most points'}: reaching it "
                              "would pass the arms through each other (min_separation_deg)")  # fmt: skip
        good, xg_all = good[~other], xg_all[~other]

    def row(i: int) -> Directions:
        r = rows[i]
        return float(r[0]), float(r[1]), float(r[2]), float(r[3])

    def as_joints(x: FloatArray) -> Joints:
        return Joints.from_dict({**held, **{n: float(v) for n, v in zip(moving, x, strict=True)}})

    stage(PLAN_STAGES[2])
    perm = np.arange(len(good), dtype=np.intp)
    if order:
        perm = np.asarray(order_path(xg_all, s, speed, accel, coordinated), dtype=np.intp)
    x = xg_all[perm]
    stage(PLAN_STAGES[3])
    kept, via = safe_sequence(paths, s, x)
    for dropped in np.flatnonzero(~kept):
        at = int(good[perm[dropped]])
        reason[at] = ARMS_CROSS
        detail[at] = "no move from the point before keeps the arms min_separation_deg apart, even split into legs"
    via_kept = {int(np.count_nonzero(kept[:k])): legs for k, legs in via.items()}
    perm, x = perm[kept], x[kept]
    points = tuple(
        PlannedPoint(int(good[k]), row(int(good[k])), as_joints(x[pos]), tuple(map(as_joints, via_kept.get(pos, ()))))
        for pos, k in enumerate(perm)
    )
    skipped = []
    for i in np.flatnonzero(reason != ""):
        text = detail.get(int(i))
        if text is None:
            unreachable = sol.at(int(i))
            text = getattr(unreachable, "message", str(reason[i]))
        skipped.append(SkippedPoint(int(i), row(int(i)), str(reason[i]), text))

    def leg_time(a: FloatArray, b: FloatArray, legs: Sequence[FloatArray]) -> float:
        nodes = np.vstack([a[None, :], *[leg[None, :] for leg in (legs or [b])]])
        return float(step_times(nodes[:-1], nodes[1:], speed, accel, coordinated).sum())

    stage(PLAN_STAGES[4])
    path = np.vstack([s[None, :], x])
    steps = step_times(path[:-1], path[1:], speed, accel, coordinated)
    for pos, legs in via_kept.items():
        steps[pos] = leg_time(path[pos], path[pos + 1], [*legs, path[pos + 1]])
    split = len(via_kept)
    refs = _reference_positions(len(points), int(reference_every))
    ref_total = len(refs) * reference_s
    if r_row is not None and refs:
        for k in map(int, refs):
            out_legs = paths.legs(path[k], r_row)
            back_legs = paths.legs(r_row, path[k + 1]) if k < len(points) else [r_row]
            if out_legs is None or back_legs is None:
                where = f"point #{points[k - 1].index}" if k else "the start pose"
                raise ValueError(f"the reference pose cannot be reached from {where} (or back) without the arms "
                                 "passing through each other; move [reference] theta_i_deg/theta_o_deg")  # fmt: skip
            split += (len(out_legs) > 1) + (len(back_legs) > 1)
            back = leg_time(r_row, path[k + 1], back_legs) - steps[k] if k < len(points) else 0.0
            ref_total += leg_time(path[k], r_row, out_legs) + back + settle_s
    n = len(points)
    unordered = None
    if order:  # the same walk (legs included) in the sweep's own order
        kept_g, via_g = safe_sequence(paths, s, xg_all)
        generated = np.vstack([s[None, :], xg_all[kept_g]])
        times_g = step_times(generated[:-1], generated[1:], speed, accel, coordinated)
        for pos, legs in {int(np.count_nonzero(kept_g[:k])): v for k, v in via_g.items()}.items():
            times_g[pos] = leg_time(generated[pos], generated[pos + 1], [*legs, generated[pos + 1]])
        unordered = float(times_g.sum())
    estimate = TimeEstimate(
        motion_s=float(sum(steps)),
        settle_s=n * settle_s,
        exposure_s=n * exposure_s_per_point,
        reference_s=float(ref_total),
        overhead_s=n * overhead_s_per_point,
        reference_captures=len(refs),
    )
    moves = n + (2 * len(refs) - (1 if refs and refs[-1] == n else 0) if r_row is not None else 0)
    return Plan(points, tuple(skipped), estimate, start, refs, reference_joints, unordered, split, moves, paths)

