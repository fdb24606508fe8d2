"""Which capture mode and motion pay for a set of planned points: the rules behind ``mode = "auto"``.

Image or point. Image mode reads the sample's whole footprint and makes every tile_px x tile_px tile a sample,
each at the SNR goal, for about one capture's rig time (its exposure is planned for a tile, which has more
pixels than a point's ROI). It pays when the camera resolves the footprint into many tiles: the rule is image
when the median tile count over up to ``PROBE_POSES`` of the plan's poses is at least ``MIN_IMAGE_TILES``, else
point. The count is image mode's own on a sensor of at most ``GRID`` tiles a side (few tiles: cheap), else the
estimate on cells of tiles (``rig.run.measuring.footprint``: exact to a few cells at the sample's edge). Sixteen
tiles (4 x 4) is the line: below it the "image" is a few samples with footprints a hundred times a point's ROI
(their directions' spread is the angular error the fit then carries), for the cost of reading a window instead
of the ROI.

Stop or continuous. The runner scans only runs of consecutive planned points that differ in one joint,
monotonically (``rig.run.measuring.scan.scan_run``); a run's first point is measured at rest and the scan's
set-up (the speed change, one long move, the wait at its end) costs about one stop. So a run of two or three
points saves little, and the rule is continuous when the plan, in the order the runner measures it, holds a
run of at least ``MIN_SCAN_POINTS`` points (its first included), else stop. The rule is the same in either mode
(in image mode every tile of a moving frame is a sample).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from rig.instrument.alignment import aligned_pose
from rig.instrument.kinematics import Joints
from rig.run.measuring.footprint import cell_side, footprint_cells
from rig.run.measuring.scan import scan_run
from rig.run.measuring.tiles import DEFAULT_TILE_PX, ImageSettings, tile_geometry
from rig.run.planning.result import Plan

#: Image mode when a capture gives at least this many tiles (median over the probed poses).
MIN_IMAGE_TILES = 16
#: Poses of the plan probed for the tile count (evenly spaced in the plan's order).
PROBE_POSES = 5
#: Continuous motion when a scan run covers at least this many points (its first, measured at rest, included).
MIN_SCAN_POINTS = 4


@dataclass(frozen=True)
class ModeChoice:
    """What ``auto`` chose: the mode ("point" or "image"), the motion ("stop" or "continuous"), and why.

    ``tiles``: the median estimated tiles per capture (None where not counted); ``tile_px``: the tile side it
    was counted in (pixels); ``longest_scan``: the longest scan run in points (None where not looked at).
    """

    mode: str
    motion: str
    reason: str
    tiles: float | None = None
    tile_px: int | None = None
    longest_scan: int | None = None

    def as_dict(self) -> dict[str, Any]:
        """Plain JSON (the manifest's and adaptive.json's form)."""
        return asdict(self)

    def describe(self) -> str:
        """One line: the choice and its reason."""
        return f"capture mode {self.mode}, motion {self.motion}: {self.reason}"


def tiles_per_capture(rig: Any, plan: Plan, tile_px: int | None = None) -> float:
    """The median estimated tiles (samples) per capture over up to PROBE_POSES of the plan's poses."""
    if not plan.points:
        return 0.0
    image = ImageSettings(tile_px=tile_px or DEFAULT_TILE_PX, resolution=tuple(rig.file.camera.resolution),
                          shape=rig.sample_shape)  # fmt: skip
    picks = np.unique(np.linspace(0, len(plan.points) - 1, min(PROBE_POSES, len(plan.points))).round().astype(int))
    # A sensor of at most GRID tiles a side is counted exactly (few tiles, cheap, and there the line is near).
    exact = cell_side(image) == 1
    counts = []
    for pos in picks:
        pose = aligned_pose(rig.geometry, plan.points[int(pos)].joints, rig.alignment)
        counts.append(tile_geometry(rig.geometry, pose, image).count if exact else
                      footprint_cells(rig.geometry, pose, image).count)  # fmt: skip
    return float(np.median(counts))


def scan_runs(plan: Plan, with_references: bool = True) -> list[int]:
    """The lengths (points, the first included) of the scan runs the runner would follow through the plan."""
    slots = set(plan.reference_before) if with_references else set()
    driven = frozenset(plan.paths.names if plan.paths is not None else Joints.__dataclass_fields__)
    out, pos = [], 0
    while pos < len(plan.points):
        run = scan_run(plan.points, pos, set(), slots, driven)
        if run is None:
            pos += 1
            continue
        out.append(1 + len(run[1]))
        pos = run[1][-1] + 1
    return out


def choose_image(rig: Any, plan: Plan, tile_px: int | None, motion: str) -> ModeChoice:
    """The sweep file's ``mode = "auto"``: image when the camera resolves the footprint into enough tiles; the
    motion stays the file's."""
    k = tile_px or DEFAULT_TILE_PX
    n = tiles_per_capture(rig, plan, k)
    if n >= MIN_IMAGE_TILES:
        return ModeChoice("image", motion, f"the camera resolves the sample into ~{n:.0f} tiles of {k} px per "
                          f"capture (>= {MIN_IMAGE_TILES})", n, k)  # fmt: skip
    return ModeChoice("point", motion, f"the camera resolves the sample into only ~{n:.0f} tiles of {k} px per "
                      f"capture (< {MIN_IMAGE_TILES})", n, k)  # fmt: skip


def choose_motion(plan: Plan, allowed: bool) -> tuple[str, str, int]:
    """Stop or continuous for a point-mode plan: (motion, reason, longest scan run in points)."""
    longest = max(scan_runs(plan), default=1)
    if not allowed:
        return "stop", "every capture at rest (motion = stop)", longest
    if longest >= MIN_SCAN_POINTS:
        return "continuous", f"a scan run of {longest} points in one joint (>= {MIN_SCAN_POINTS})", longest
    return "stop", f"no scan run of {MIN_SCAN_POINTS} points in one joint (longest {longest})", longest
