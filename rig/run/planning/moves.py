"""How the rig moves between poses: move times under each axis's speed and acceleration limits, and the order
of least total move time, for poses given as ``Joints`` (degrees) and limits as ``Axis``; times in seconds.

Move time model (``move_time_s``): every move starts and ends at rest. Independent axes (the Dynamixel
link: one synchronous write, each servo runs its own trapezoid) take the slowest axis's time;
``coordinated=True`` models GRBL's straight G1 moves, where all axes share one trapezoid along the
path and arrive together. ``Axis`` requires positive, finite speed and acceleration limits, so there is
no "unlimited" case. Links quantise these limits (a Dynamixel's Profile Velocity/Acceleration units,
its 46 rpm no-load speed), so a servo may run slightly faster or slower than the estimate.

The arrays behind these (move-time matrices, the ordering itself) are in ``rig.run.planning.order``;
``_Moves`` is a plan's view of the same: the joints that move, as the columns of its arrays.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rig.instrument.axis import Axis
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Joints
from rig.run.planning.order import FloatArray, order_path, pairwise_times, step_times
from rig.run.planning.paths import ArmPaths

#: A joint without an axis is fixed; a point may differ from its fixed value by this much (degrees).
FIXED_JOINT_TOL_DEG = 1e-6


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


@dataclass(frozen=True, eq=False)
class _Moves:
    """How the rig moves between poses: the joints that have axes (the columns of the plan's arrays, in
    degrees), their speed and acceleration limits, the start, the joints held still, the swept-path check."""

    moving: list[str]
    speed: FloatArray
    accel: FloatArray
    start: FloatArray
    held: dict[str, float]
    coordinated: bool
    paths: ArmPaths

    @classmethod
    def of(cls, geometry: RigGeometry, by_name: dict[str, Axis], start: Joints, coordinated: bool) -> _Moves:
        """The moves of a rig with these axes, from ``start``; a joint without an axis is held at its start angle."""
        names = geometry.joint_names
        moving = [n for n in names if n in by_name]
        speed, accel = _limits(by_name, moving)
        s = np.array([float(np.asarray(getattr(start, n))) for n in moving], dtype=np.float64)
        held = {n: float(np.asarray(getattr(start, n))) for n in names if n not in by_name}
        return cls(moving, speed, accel, s, held, coordinated,
                   ArmPaths(geometry, moving, speed, accel, coordinated, held))  # fmt: skip

    def row(self, joints: Joints) -> FloatArray:
        """The moving joints of a pose, in degrees."""
        return np.array([float(np.asarray(getattr(joints, n))) for n in self.moving], dtype=np.float64)

    def as_joints(self, x: FloatArray) -> Joints:
        """The pose with moving joints ``x`` (degrees) and the held ones at their start."""
        return Joints.from_dict({**self.held, **{n: float(v) for n, v in zip(self.moving, x, strict=True)}})

    def leg_time(self, a: FloatArray, b: FloatArray, legs: Sequence[FloatArray]) -> float:
        """Seconds from ``a`` through ``legs`` (ending at ``b``; empty: straight to ``b``), rest to rest each leg."""
        nodes = np.vstack([a[None, :], *[leg[None, :] for leg in (legs or [b])]])
        return float(step_times(nodes[:-1], nodes[1:], self.speed, self.accel, self.coordinated).sum())
