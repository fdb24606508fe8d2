"""What a sweep plan is: the points in execution order, the rows skipped with reasons, the time estimate.

``rig.run.planning.plan.plan_sweep`` makes a :class:`Plan`; its ``summary`` is the text ``gonio plan`` prints
and its ``_repr_html_`` what a notebook shows. Angles in degrees, times in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rig.instrument.kinematics import Joints
from rig.run.planning.paths import ArmPaths

#: A sweep row's (theta_i, phi_i, theta_o, phi_o) in degrees.
Directions = tuple[float, float, float, float]


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
    #: Continuous motion: the scan runs' seconds (each from its first point, measured at rest, to rest at its last),
    #: the points they sweep (their moves, settling, exposures and overhead are in it, not in the other causes),
    #: and the slowest and fastest run's speed in deg/s.
    scan_s: float = 0.0
    scanned: int = 0
    scan_speeds_deg_s: tuple[float, float] | None = None

    @property
    def total_s(self) -> float:
        """The whole run in seconds."""
        return self.motion_s + self.settle_s + self.exposure_s + self.reference_s + self.overhead_s + self.scan_s


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
        if e.scanned and e.scan_speeds_deg_s is not None:
            lo, hi = e.scan_speeds_deg_s
            speeds = f"{lo:.3g} deg/s" if round(lo, 2) == round(hi, 2) else f"{lo:.3g}-{hi:.3g} deg/s"
            parts.append(("scans", e.scan_s, f" ({e.scanned} points measured moving, at {speeds})"))
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
