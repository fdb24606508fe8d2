"""bench.continuous_scan's scan sweep: runs along the camera joint on whole servo counts, so a continuous run scans."""

import numpy as np

from analysis.batch.tradeoff import MATERIALS, grid_design
from bench._modes import POINT_RESOLUTION, mode_rig
from bench.continuous_scan import COUNT_DEG, LIGHTS_DEG, STEP_DEG, TILTS_DEG, points_in_runs, scan_design
from rig.run.config.files import parse, sweep_config
from rig.run.config.schema import SweepFile
from rig.run.session import make_plan


def test_the_scan_sweep_steps_the_camera_alone_on_whole_counts_and_scans_all_but_each_runs_first_point() -> None:
    rig = mode_rig(MATERIALS[0], 1, POINT_RESOLUTION)
    points = scan_design(rig, STEP_DEG)
    table = {"sweep": {"kind": "list", "points": points.tolist(), "order": False}}
    plan = make_plan(rig, sweep_config(parse(table, SweepFile, "<t>"), "<t>"))
    assert [p.index for p in plan.points] == list(range(len(points)))  # kept in the design's order
    joints = np.array([[float(v) for v in p.joints.as_dict().values()] for p in plan.points])
    assert np.allclose(joints, np.round(joints / COUNT_DEG) * COUNT_DEG, atol=1e-6)
    held = np.all(np.isclose(joints[1:, [0, 2, 3]], joints[:-1, [0, 2, 3]], atol=1e-6), axis=1)
    runs = 1 + int(np.sum(~held))
    assert runs == len(LIGHTS_DEG) * len(TILTS_DEG)
    # Within a run the camera moves one way only: the runner's scan_run takes the whole run.
    for k, run in enumerate(np.split(np.diff(joints[:, 1]), np.flatnonzero(~held))):
        inside = run[1:] if k else run  # after the first, each piece opens with the move to its run's start
        assert np.all(np.isclose(np.abs(inside), STEP_DEG, atol=2 * COUNT_DEG)) and len(set(np.sign(inside))) == 1
    # Every point after a run's first is scanned, but where a reference reading cuts a run in two.
    scanned = points_in_runs(rig, points, order=False)
    assert len(points) - runs - len(plan.reference_before) <= scanned <= len(points) - runs
    # The anchor's grid, in the planner's order, has far fewer points in runs along one joint.
    grid = grid_design(rig, 30)
    assert points_in_runs(rig, grid, order=True) < scanned / 2
