"""A plan on a calibrated rig: the joints that make the real rig measure each point's wanted directions.

A geometry calibration (``geometry_calibration.json``) says how the rig is really built
(``rig.instrument.alignment``); the drawn rig's inverse kinematics gives a start, and
``aligned_inverse`` moves it to the joints whose true directions are the wanted ones.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from rig.instrument.alignment import Alignment, aligned_inverse
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Joints, Solution
from rig.run.planning.order import FloatArray

CALIBRATED_MISS = "calibrated_miss"


def calibrated_joints(
    geometry: RigGeometry, sol: Solution, solved: dict[str, FloatArray], reason: npt.NDArray[np.str_],
    detail: dict[int, str], alignment: Alignment,
) -> dict[str, FloatArray]:  # fmt: skip
    """The joints that measure each reachable point's directions on the calibrated rig (see plan_sweep)."""
    ok = np.flatnonzero(reason == "")
    if not len(ok):
        return solved
    wi = np.asarray(sol.wi).reshape(-1, 3)[ok]
    wo = np.asarray(sol.wo).reshape(-1, 3)[ok]
    start = Joints.from_dict({n: solved[n][ok] + alignment.zero_of(n) for n in geometry.joint_names})
    joints, miss = aligned_inverse(geometry, wi, wo, alignment, start)
    out = {n: v.copy() for n, v in solved.items()}
    for n in geometry.joint_names:
        out[n][ok] = np.asarray(getattr(joints, n), dtype=np.float64).reshape(len(ok))
    for i, m in zip(ok, np.atleast_1d(miss), strict=True):
        if m > 0.01:
            reason[i] = CALIBRATED_MISS
            detail[int(i)] = (f"on the calibrated rig the nearest joints measure directions {float(m):.3f} deg off "
                              "the wanted ones (a tilted sample lifts them out of the arms' reach)")  # fmt: skip
    return out
