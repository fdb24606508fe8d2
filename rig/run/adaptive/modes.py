"""Each round's capture mode and motion in an adaptive sweep, and what its captures look at.

With ``mode`` "point" or "image" every round is measured that way, with the settings' ``motion``. With "auto"
the planner chooses per round (``rig.run.measuring.mode_choice`` holds the rules and their reasons):

- the first, space-filling round in image mode when the camera resolves the sample into at least
  ``MIN_IMAGE_TILES`` tiles per capture: a frame of samples per capture gives the first fit a picture of the
  whole lobe for a round's rig time; else point mode;
- later rounds in point mode at the directions the design chose: a point's small footprint is where the fit
  is least certain, not a frame's worth of directions around it;
- a round (in either mode) continuous when its plan holds a scan run of at least ``MIN_SCAN_POINTS`` points in
  one joint and ``motion = "continuous"`` allows it. ``motion`` is the most the planner may use: continuous
  motion moves the arm while the camera shoots (motion blur in the directions' uncertainty, a link that can
  scan), so it is never chosen unless asked for. The design's points are scattered over the hemisphere and
  rarely line up in one joint, so most rounds stay at rest even then.

The design step needs each candidate capture's samples: one at its directions in point mode; in image mode
its footprint's tiles, estimated on cells of tiles (``rig.run.measuring.footprint``) from the drawn rig's
pose (a geometry calibration moves a footprint by far less than a cell).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from rig.instrument.kinematics import solve_degrees, world_pose
from rig.instrument.kinematics_types import Joints
from rig.run.adaptive.settings import AdaptiveSettings
from rig.run.measuring.footprint import footprint_cells
from rig.run.measuring.mode_choice import ModeChoice, choose_image, choose_motion
from rig.run.measuring.tiles import DEFAULT_TILE_PX, ImageSettings
from rig.run.planning.result import Plan

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

#: Candidate poses an image-mode round's design considers (a seeded draw from the pool): each is a footprint
#: of cells to evaluate, where a point-mode candidate is one direction pair.
IMAGE_CANDIDATES = 300


def round_choice(rig: Any, s: AdaptiveSettings, index: int, plan: Plan) -> ModeChoice:
    """The mode and motion of round ``index``, whose points the rig plans as ``plan`` (see the module)."""
    k = s.tile_px or DEFAULT_TILE_PX
    if s.mode != "auto":
        why = f"mode = {s.mode}, motion = {s.motion} (the sweep's settings)"
        return ModeChoice(s.mode, s.motion, why, tile_px=k if s.mode == "image" else None)
    if index == 0:
        first = choose_image(rig, plan, s.tile_px, "stop")
        mode, tiles, reason = first.mode, first.tiles, f"first round: {first.reason}; "
    else:
        mode, tiles, reason = "point", None, "later round: point mode at the chosen directions; "
    motion, why, longest = choose_motion(plan, s.motion == "continuous")
    return ModeChoice(mode, motion, reason + why, tiles, k if mode == "image" else None, longest)


def round_capture(s: AdaptiveSettings, choice: ModeChoice) -> dict[str, Any]:
    """The ``[capture]`` table of a round measured as ``choice`` says."""
    cap: dict[str, Any] = {"target_snr": s.target_snr, "mode": choice.mode, "motion": choice.motion}
    if choice.mode == "image" and s.tile_px is not None:
        cap["tile_px"] = s.tile_px
    if choice.motion == "continuous" and s.scan_speed_deg_s is not None:
        cap["scan_speed_deg_s"] = s.scan_speed_deg_s
    return cap


def next_mode(s: AdaptiveSettings) -> str:
    """The mode later rounds are measured in (what their design plans for)."""
    return "point" if s.mode == "auto" else s.mode


@dataclass(frozen=True)
class Footprints:
    """Candidate captures as samples: angles (N, 4) in degrees, the tiles each stands for (N,), and its
    candidate's index (N,) into the candidates given."""

    angles_deg: FloatArray
    tiles: FloatArray
    owner: IntArray


def footprints(rig: Any, s: AdaptiveSettings, candidates: FloatArray) -> Footprints:
    """Each candidate's (M, 4 directions in degrees) image-mode samples (see the module docstring)."""
    g = rig.geometry
    sol = solve_degrees(g, candidates[:, 0], candidates[:, 1], candidates[:, 2], candidates[:, 3])
    image = ImageSettings(tile_px=s.tile_px or DEFAULT_TILE_PX, resolution=tuple(rig.file.camera.resolution),
                          shape=rig.sample_shape)  # fmt: skip
    angles, tiles, owner = [], [], []
    for m in range(len(candidates)):
        joints = sol.at(m)
        if not isinstance(joints, Joints):  # the pool is reachable; a candidate that is not gives nothing
            continue
        cells = footprint_cells(g, world_pose(g, joints), image)
        angles.append(cells.angles_deg)
        tiles.append(cells.tiles)
        owner.append(np.full(len(cells.tiles), m, dtype=np.intp))
    if not angles:
        return Footprints(np.zeros((0, 4)), np.zeros(0), np.zeros(0, dtype=np.intp))
    return Footprints(np.concatenate(angles), np.concatenate(tiles), np.concatenate(owner))


def image_subset(pool_size: int, seed: int, index: int) -> IntArray:
    """The pool indices an image-mode round's design considers (all of a small pool), seeded per round."""
    if pool_size <= IMAGE_CANDIDATES:
        return np.arange(pool_size, dtype=np.intp)
    rng = np.random.default_rng([seed, index])
    return np.sort(rng.choice(pool_size, IMAGE_CANDIDATES, replace=False)).astype(np.intp)
