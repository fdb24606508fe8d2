"""A warming lamp and points unevenly spaced in time: references are interpolated by time, not by position."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rig.run.session import start_run
from rig.run.storage.store import RunStore
from rig.run.tables.samples import build_rows
from tests.run_helpers import in_plane_sweep, read_rows, sim_rig

pytestmark = pytest.mark.mitsuba

WARMING = {"lamp_drift": 5.0, "lamp_warmup_s": 2000.0}  # 0.25 % per second at first


def _relative_errors(rows: list[dict], rho: float) -> np.ndarray:
    got = np.array([float(r["brdf_g"]) for r in rows])
    return got / (rho / np.pi) - 1.0


def test_time_interpolation_follows_a_warming_lamp_where_position_cannot(tmp_path: Path) -> None:
    # Slow arms make the moves between points of very different length: a point's share of the time
    # between two references is not its share of the points between them.
    axes = {j: {"id": i, "max_speed_deg_s": 5.0, "max_accel_deg_s2": 20.0, "tolerance_deg": 0.2}
            for i, j in enumerate(("light", "camera", "tilt", "roll"), 1)}  # fmt: skip
    rig = sim_rig({"model": "Lambert", "rho_d": 0.5}, reference={"every": 8},
                  simulation={"misalignment": WARMING, "seed": 5}, axes=axes)  # fmt: skip
    sweep = in_plane_sweep([10.0, 60.0], [-70.0, -60.0, -50.0, 0.0, 5.0, 50.0, 60.0, 70.0], target_snr=400.0)
    summary = start_run(rig, sweep, tmp_path / "run", progress=False)
    rows = read_rows(summary.table)
    records = RunStore.read(tmp_path / "run").records()
    times = [r["reading_time_s"] for r in records if r["kind"] == "point"]
    gaps = np.diff(sorted(times))
    assert gaps.max() > 3 * np.median(gaps)  # the premise: uneven spacing in time
    by_position = build_rows(
        [{k: v for k, v in r.items() if k != "reading_time_s"} for r in records], rig.geometry.joint_names,
        albedo=rig.file.reference.albedo, albedo_std_error=rig.file.reference.albedo_std_error,
    )  # fmt: skip
    se = np.array([float(r["brdf_se_readings_g"]) for r in rows]) / (0.5 / np.pi)
    timed, positional = _relative_errors(rows, 0.5), _relative_errors(by_position, 0.5)
    # Over the run the lamp warms almost linearly in time (its curvature is small at this time scale).
    assert np.sqrt(np.mean(timed**2)) < 0.5 * np.sqrt(np.mean(positional**2)), (timed, positional)
    assert np.sqrt(np.mean(timed**2)) < 0.01 + 2 * float(np.median(se))
