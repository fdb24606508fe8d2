"""The runtime guard: the runner moves only to poses the plan checked, along paths checked from where the arms are.

The plan checks every move from the pose before it; at run time the arms may stand elsewhere (a resumed run
starts wherever the last one stopped, a stop may have left a move half done). Before each move the guard
reads the joints back (a link that must first find its position, GRBL after a reset, homes before that),
checks the swept path from there with the plan's own check (:class:`rig.run.planning.paths.ArmPaths`), splits it
into safe legs where needed, and refuses (``UnsafeMove``, a hardware stop) a target the plan never checked
or a move no split makes safe.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import cast

import numpy as np

from rig.instrument.kinematics import Joints
from rig.instrument.links.base import HomingLink, LinkError, MotionLink
from rig.run.planning.paths import ArmPaths


class UnsafeMove(LinkError):
    """A move the plan did not check, or one whose path would bring the arms closer than allowed."""


def _key(values: Iterable[float]) -> tuple[float, ...]:
    return tuple(round(float(v), 6) for v in values)


class MotionGuard:
    """Checks and splits every move of one run against the plan's arm paths (joint angles in degrees)."""

    def __init__(self, paths: ArmPaths | None, allowed: Iterable[Joints]) -> None:
        self.paths = paths
        names = paths.names if paths is not None else []
        self._names = names
        self._allowed = {_key(float(np.asarray(getattr(j, n))) for n in names) for j in allowed}

    def _homing(self, link: MotionLink) -> HomingLink | None:
        """``link`` if it homes (GRBL), else None."""
        return cast(HomingLink, link) if isinstance(link, HomingLink) else None

    def legs(self, link: MotionLink, target: Mapping[str, float]) -> list[dict[str, float]]:
        """The poses to send, in order, to reach ``target`` safely from where the link reads the joints now."""
        if self.paths is None or not self.paths.active:
            return [dict(target)]
        row = np.array([float(target[n]) for n in self._names])
        if _key(row) not in self._allowed:
            raise UnsafeMove(f"refused a move to {dict(target)}: not a pose the plan checked")
        homing = self._homing(link)
        if homing is not None:
            homing.ensure_position_known()  # a read-back is only "where the arms are" once the controller knows
        here = link.read_positions()
        src = np.array([float(here[n]) for n in self._names])
        legs = self.paths.legs(src, row)
        if legs is None:
            now = ", ".join(f"{n} {v:.2f}" for n, v in zip(self._names, src, strict=True))
            raise UnsafeMove(
                f"refused a move from ({now}) deg to {dict(target)}: the light and camera arms would pass closer "
                f"than {self.paths.sep:g} deg (min_separation_deg) on the way, however it is split"
            )
        out = []
        for leg in legs:
            pose = dict(target)
            pose.update({n: float(v) for n, v in zip(self._names, leg, strict=True)})
            out.append(pose)
        return out
