"""Gear play the encoder cannot see: a one-sided final approach, the load's angle, and what is left uncertain.

A joint with ``backlash_deg`` = b of play between its motor and its load rests with the load b / 2 behind the
motor's last direction of motion; the encoder (or GRBL's step count) reads the motor. Reached from either
side, the load is anywhere b / 2 either side of the reading, and a pose's directions are off by it.

The anti-backlash approach (``[link] backlash_approach_deg`` = a) reaches every pose by first going a past it
and then coming back from one side (from below, or from above where a joint's limit or the arms' separation
leaves no room below), so the final motion takes the play up and the load rests on a known flank: its angle is
the reading less (side x b / 2). Where the approach did not take the play up on a joint (a < b, or a joint
pinned at a limit), the load is known only to lie in a band of width b: a uniform residual, variance b^2 / 12,
which the runner adds to that joint's variance (``rig.instrument.direction_uncertainty``).

The overshoot poses are poses the runner moves to: the motion guard checks their swept paths with the plan's
own check, so they must be in its set of allowed poses (``pre_poses``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

from rig.instrument.axis import Axis
from rig.instrument.kinematics import Joints

#: Sides an approach is tried from, in order: from below (the final leg moves up), then from above.
SIDES = (1, -1)


class Backlash:
    """The rig's gear play per joint and its anti-backlash approach (degrees of joint)."""

    def __init__(self, axes: Sequence[Axis], approach_deg: float) -> None:
        if not approach_deg >= 0:
            raise ValueError(f"backlash_approach_deg = {approach_deg!r}: expected a number of degrees >= 0")
        self.axes = {a.name: a for a in axes}
        self.approach_deg = float(approach_deg)

    @property
    def active(self) -> bool:
        """Whether poses are approached from one side."""
        return self.approach_deg > 0

    def pre_pose(self, target: Mapping[str, float], side: int) -> dict[str, float]:
        """The overshoot pose (deg) before ``target`` when approached from ``side`` (+1 below, -1 above).

        Each joint goes ``approach_deg`` past its target, within its soft limits (joints without an axis stay).
        """
        out = dict(target)
        for name, value in target.items():
            axis = self.axes.get(name)
            if axis is not None:
                out[name] = min(max(float(value) - side * self.approach_deg, axis.min_deg), axis.max_deg)
        return out

    def pre_poses(self, poses: Iterable[Joints]) -> list[Joints]:
        """Every overshoot pose of ``poses`` from both sides: what the motion guard must allow besides them."""
        out = []
        for joints in poses:
            values = {k: float(v) for k, v in joints.as_dict().items()}
            for side in SIDES:
                out.append(Joints.from_dict(self.pre_pose(values, side)))
        return out

    def sides(self, pre: Mapping[str, float], target: Mapping[str, float]) -> dict[str, int]:
        """Per joint whose final leg ``pre`` -> ``target`` took its play up: the side its load rests on."""
        out = {}
        for name, axis in self.axes.items():
            if name in pre and name in target:
                moved = float(target[name]) - float(pre[name])
                if axis.backlash_deg > 0 and abs(moved) >= axis.backlash_deg:
                    out[name] = 1 if moved > 0 else -1
        return out

    def load_angles(self, positions: Mapping[str, float], sides: Mapping[str, int]) -> dict[str, float]:
        """The loads' joint angles (deg) from the encoders' ``positions``: less side x b / 2 where the side is known."""
        return {
            name: float(value) - sides.get(name, 0) * 0.5 * self.axes[name].backlash_deg
            if name in self.axes and name in sides else float(value)
            for name, value in positions.items()
        }  # fmt: skip

    def variance_deg2(self, name: str, sides: Mapping[str, int]) -> float:
        """What is left of joint ``name``'s play (deg^2): 0 on a known side, else a uniform band of width b."""
        axis = self.axes.get(name)
        if axis is None or name in sides:
            return 0.0
        return axis.backlash_deg**2 / 12.0
