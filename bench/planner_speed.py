"""What one exposure plan costs: the planner against the original one (the anchor), on a run's kind of levels.

Plans for three-channel ROI levels like a run's (peak, per-channel means, the 1st-percentile dark level, a
16-pixel ROI) from 10 to 10^7 counts/s, at the run's settings (target SNR 200, up to 5 frames, one dark frame),
on the continuous camera of the simulated rig. CPU seconds per plan (``time.process_time``, which a loaded
machine inflates far less than wall time) for the planner and for the original one kept in
``tests/acquisition/test_exposure_oracle.py`` (a fixed 100-step bisection of numpy ``roi_snr`` calls),
whose plans the test requires to be identical. Goal: at most 2 ms a plan.

Run: ``.venv/bin/python -m bench.planner_speed [--reps N] [--no-docs]``.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from acquisition.exposure.plan import plan_exposure
from acquisition.exposure.spec import CameraTiming, RoiLevel
from acquisition.noise import SensorNoise
from bench._common import bench_parser, format_table, load_average, machine_description, markdown_table, record
from tests.acquisition.test_exposure_oracle import oracle_plan

GOAL_MS = 2.0


def run_levels(n: int) -> list[list[RoiLevel]]:
    """``n`` three-channel ROI levels spread log-uniformly over 10..1e7 counts/s."""
    out = []
    for peak in np.geomspace(10.0, 1e7, n):
        p = float(peak)
        out.append([RoiLevel(p, 0.8 * p, 16, 0.5 * p), RoiLevel(p, 0.5 * p, 16, 0.3 * p),
                    RoiLevel(p, 0.2 * p, 16, 0.1 * p)])  # fmt: skip
    return out


def cpu_per_plan(plan: object, levels: list[list[RoiLevel]], reps: int) -> float:
    """CPU seconds per call of ``plan(levels)`` over every level, best of ``reps`` passes."""
    best = float("inf")
    for _ in range(reps):
        t0 = time.process_time()
        for lv in levels:
            plan(lv)  # type: ignore[operator]
        best = min(best, (time.process_time() - t0) / len(levels))
    return best


def main() -> None:
    """Time both planners, print and record."""
    parser = bench_parser(__doc__)
    parser.add_argument("--reps", type=int, default=3, help="passes over the levels; the best counts (default 3)")
    args = parser.parse_args()
    machine = machine_description()
    noise = SensorNoise(e_per_dn=4.0, read_noise_e=3.0, full_well_e=60000.0)
    cam = CameraTiming(1e-5, 30.0)
    levels = run_levels(40)
    settings = {"max_frames": 5, "dark_frames": 1}

    def new(lv: list[RoiLevel]) -> object:
        return plan_exposure(lv, noise, 200.0, cam, **settings)

    with pytest.MonkeyPatch.context() as mp:

        def old(lv: list[RoiLevel]) -> object:
            return oracle_plan(mp, lv, noise, 200.0, cam, **settings)

        same = all(new(lv) == old(lv) for lv in levels)
        t_old = cpu_per_plan(old, levels, args.reps)
    t_new = cpu_per_plan(new, levels, args.reps)
    load = load_average()
    head = ["planner", "CPU ms per plan", "ratio to original", f"ratio to {GOAL_MS:g} ms goal", "plans identical"]
    rows = [["original (100-step bisection, numpy roi_snr)", f"{t_old * 1e3:.2f}", "1", f"{t_old * 1e3 / GOAL_MS:.2f}",
             "-"],
            ["now (stalled bisection from the closed form, float roi_snr)", f"{t_new * 1e3:.2f}",
             f"{t_new / t_old:.3f}", f"{t_new * 1e3 / GOAL_MS:.2f}", "yes" if same else "NO"]]  # fmt: skip
    print(f"{machine}; {load}")
    print(format_table(head, rows))
    if args.no_docs:
        return
    record(
        "planner_speed", "Exposure planner speed", f" --reps {args.reps}",
        f"{machine}, shared with other work ({load}).",
        f"{len(levels)} plans of three-channel, 16-pixel ROI levels from 10 to 1e7 counts/s at target SNR 200, up "
        "to 5 frames, one dark frame, on the simulated rig's continuous camera; CPU time, best pass. Anchor: the "
        "original planner, kept as the oracle of `tests/acquisition/test_exposure_oracle.py`.",
        markdown_table(head, rows),
    )  # fmt: skip


if __name__ == "__main__":
    main()
