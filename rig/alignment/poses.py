"""The poses of a geometry calibration: where the board is seen from, and where the lamp's mirror is.

Two kinds of capture, taken in two rounds:

1. Board poses: the stage tilted by up to ``BOARD_TILT_DEG`` both ways and turned through a whole roll,
   the arms on either side at moderate angles; the board's corners (seen from many directions) fix the
   camera's zero, the stage's zeros, the wedge and the offset, but the lamp's highlight is rarely in view.
2. Mirror poses: the lamp and the camera symmetric about the sample's normal at a few incidences and rolls,
   solved with the first round's estimate (``rig.instrument.alignment.aligned_inverse``) so that the
   highlight lands near the image centre even on a rig misaligned by degrees; the highlights fix the
   light's zero (their corners are not used: the coat's reflection of the lamp spreads over the board).

Layouts whose stage cannot tilt or roll see the board from the arms' angles only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from model.errors import InputError
from model.geometry import degrees_to_vector
from rig.instrument.alignment import Alignment, aligned_inverse
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Joints, forward, solve

FloatArray = npt.NDArray[np.float64]

BOARD_TILT_DEG = 20.0
#: The arms' mean angles in the board poses (deg): the camera well off the normal, where the board's
#: foreshortening tells the camera's own angle best.
BOARD_LIGHT_DEG = 20.0
BOARD_CAMERA_DEG = 40.0
#: How far the board poses' arm and tilt angles move over the round (deg), so that no two captures share one.
BOARD_SPREAD_DEG = 3.0
MIRROR_INCIDENCES_DEG = (20.0, 30.0, 40.0)
#: Fewest captures a calibration can fit with: a handful of each kind.
MIN_CAPTURES = 8


class PoseError(InputError, ValueError):
    """The rig cannot take the calibration's poses (limits, separation); the message names the pose."""


@dataclass(frozen=True)
class CalibrationPoses:
    """The board poses (joints, degrees) and the wanted mirror directions (local unit vectors) of a calibration."""

    board: tuple[Joints, ...]
    mirror_wi: FloatArray
    mirror_wo: FloatArray


def split(captures: int) -> tuple[int, int]:
    """How many board and mirror captures a calibration of ``captures`` takes (half each)."""
    if captures < MIN_CAPTURES:
        raise PoseError(f"--captures {captures}: a geometry calibration needs at least {MIN_CAPTURES} captures")
    board = max(4, captures // 2)
    return board, captures - board


def plan_poses(geometry: RigGeometry, captures: int) -> CalibrationPoses:
    """The board and mirror poses of a calibration with ``captures`` captures on ``geometry``'s layout."""
    n_board, n_mirror = split(captures)
    k = np.arange(n_board)
    # A servo comes to rest the same way at the same goal, so a joint's error is shared by the captures that
    # repeat its angle, which averages out over none of them and which no spread between captures shows: the
    # camera at three angles over 15 captures put its zero 0.03 deg (3 standard errors) off. A spread of
    # BOARD_SPREAD_DEG over the round gives every capture angles of its own.
    spread = BOARD_SPREAD_DEG * ((k + 0.5) / n_board - 0.5)
    light = BOARD_LIGHT_DEG + 6.0 * np.cos(2 * np.pi * k / 3) + spread
    camera = -(BOARD_CAMERA_DEG + 6.0 * np.sin(2 * np.pi * k / 4) + spread)
    values: dict[str, FloatArray] = {"light": light, "camera": camera}
    if "tilt" in geometry.joint_names:
        values["tilt"] = BOARD_TILT_DEG * np.cos(2 * np.pi * (k + 0.5) / n_board * 2) + spread
        values["roll"] = -180.0 + 360.0 * (k + 0.5) / n_board
    if geometry.layout == "fixed_camera":
        values["yaw"] = geometry.camera_azimuth_deg - values.pop("camera")
        values["light"] = values["light"] + values["yaw"]
    board = tuple(Joints.from_dict({n: float(values[n][i]) for n in geometry.joint_names}) for i in range(n_board))
    for i, j in enumerate(board):
        d = forward(geometry, j)
        check = solve(geometry, d.wi, d.wo).at(())
        if not isinstance(check, Joints):
            raise PoseError(f"board pose {i} ({j}) is not reachable on this rig: {check.message}")
    m = np.arange(n_mirror)
    theta = np.asarray(MIRROR_INCIDENCES_DEG)[m % len(MIRROR_INCIDENCES_DEG)]
    if "roll" in geometry.joint_names:
        # The drawn four-axis rig puts a mirror pair at azimuth phi at roll -phi: spread the rolls evenly.
        phi = 180.0 - 360.0 * (m + 0.5) / n_mirror
    else:
        phi = np.full(n_mirror, geometry.plane_azimuth_deg)
    wi = np.asarray(degrees_to_vector(theta, phi), dtype=np.float64)
    wo = np.asarray(degrees_to_vector(theta, phi + 180.0), dtype=np.float64)
    return CalibrationPoses(board, wi, wo)


def wrapped(value: float, lo: float, hi: float) -> float:
    """A joint angle (deg) turned by whole turns into [lo, hi], the turn nearest ``value`` if several fit.

    A revolute joint stands the same at a and a + 360 k: the solver's angle is a solution wherever it lands, but
    the axis can only go where its limits allow. Unchanged where no turn brings it inside.
    """
    turns = np.arange(math.ceil((lo - value) / 360.0), math.floor((hi - value) / 360.0) + 1)
    if not turns.size:
        return value
    return float(value + 360.0 * turns[np.argmin(np.abs(turns))])


def mirror_joints(geometry: RigGeometry, poses: CalibrationPoses, estimate: Alignment) -> tuple[Joints, ...]:
    """Joints (degrees) that put the lamp's mirror image near the image centre on the rig ``estimate`` describes."""
    joints, miss = aligned_inverse(geometry, poses.mirror_wi, poses.mirror_wo, estimate)
    values = joints.as_dict()
    out = []
    for i in range(len(poses.mirror_wi)):
        # Gauss-Newton from the drawn rig's roll may step past +-180 deg (roll -307 for 53 was seen): same pose.
        j = Joints.from_dict({n: wrapped(float(np.asarray(values[n])[i]), *geometry.limits.of(n)) for n in values})
        for name, value in j.as_dict().items():
            lo, hi = geometry.limits.of(name)
            if not lo <= float(value) <= hi:
                raise PoseError(f"mirror pose {i}: {name} = {float(value):.2f} deg is outside its limits "
                                f"[{lo:g}, {hi:g}]")  # fmt: skip
        out.append(j)
    del miss  # an in-plane rig with a wedge cannot centre every mirror exactly; the highlight is still in view
    return tuple(out)
