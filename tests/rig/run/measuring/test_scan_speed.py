"""A continuous scan's speed: the sweep's as given, else chosen per scan run (rig.run.planning.scans), and the plan's
time estimate timing scans with the same rule."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rig.instrument.links.dynamixel_table import X_SERIES
from rig.run.planning.scans import (
    BLUR_FRACTION,
    SPEED_HEADROOM,
    SpeedChoice,
    chosen_speed_deg_s,
    frame_time_s,
)
from rig.run.session import make_plan
from rig.run.storage.store import RunStore
from tests.rig.run.measuring.test_continuous_scan import MEASURED, SCANNED, THETA_O, _check_mid_exposure, _run, _z
from tests.run_helpers import LAMBERT, in_plane_sweep, read_rows, sim_rig

#: The speed the sweeps of test_continuous_scan left out until scans chose their own (deg/s).
OLD_DEFAULT_DEG_S = 2.0
#: A dim lamp (W/sr): frames long enough that the blur, not the axis's top speed, bounds the scan over 10 deg steps.
DIM_W_SR = 0.01


def test_the_chosen_speed_is_the_fastest_the_axis_the_blur_and_the_camera_allow() -> None:
    blur = chosen_speed_deg_s(2.0, 0.01, 1000.0)
    assert blur.bound == "blur"
    # A frame whose exposure grew by the headroom blurs over exactly the fraction of the step allowed.
    assert blur.speed_deg_s * SPEED_HEADROOM * 0.01 == pytest.approx(BLUR_FRACTION * 2.0)
    assert chosen_speed_deg_s(2.0, 0.01, 0.5 * blur.speed_deg_s) == SpeedChoice(0.5 * blur.speed_deg_s, "axis")
    # A slow camera (overhead, darks): the arm must not reach the next point before a frame and its darks are done.
    slow = chosen_speed_deg_s(2.0, 0.01, 1000.0, dark_frames=2, overhead_s=0.1)
    assert slow.bound == "camera" and slow.speed_deg_s < blur.speed_deg_s
    assert 2.0 / slow.speed_deg_s == pytest.approx(SPEED_HEADROOM * frame_time_s(0.01, 2, 0.1))


def _events(run: Path, what: str) -> list[dict[str, Any]]:
    return [r for r in RunStore.read(run).records() if r["kind"] == "event" and r["event"] == what]


def test_a_scan_without_a_speed_runs_at_its_blur_bound_faster_than_stop_and_go(tmp_path: Path) -> None:
    points, (rig, outcome), renders = _run(tmp_path / "scan", LAMBERT, DIM_W_SR, on="grbl", motion="continuous")
    assert len(points) == outcome.measured == MEASURED and _check_mid_exposure(points, renders, "grbl") == SCANNED
    speeds = _events(tmp_path / "scan" / "run", "scan_speed")
    assert len(speeds) == 2  # one per scan run, each read from its first frame's exposure
    position = {p["index"]: p["position"] for p in points}
    for event in speeds:  # the run's first frame: the plan position after its point measured at rest
        first = next(p for p in points if p["position"] == position[event["first_index"]] + 1)
        assert "scan" in first
        assert event["bound"] == "blur" and event["speed_deg_s"] > OLD_DEFAULT_DEG_S
        top = next(a.max_speed_deg_s for a in rig.axes if a.name == event["joint"])
        assert event["speed_deg_s"] < top
        blur = event["speed_deg_s"] * first["exposures_s"][0]
        assert blur * SPEED_HEADROOM == pytest.approx(BLUR_FRACTION * event["step_deg"], rel=1e-6)
        assert first["scan"]["speed_deg_s"] == event["speed_deg_s"]  # every scanned record carries its speed
    assert not _events(tmp_path / "scan" / "run", "scan_too_fast")  # a Lambertian run's exposures barely change
    z = _z(read_rows(outcome.table), rig)
    assert np.mean(np.abs(z) < 2) >= 0.6 and np.max(np.abs(z)) < 5, z
    # The same sweep stop and go, timed by the same simulated clock: scanning is faster.
    stop_points, (_, stop), _ = _run(tmp_path / "stop", LAMBERT, DIM_W_SR, on="grbl")
    assert len(stop_points) == stop.measured == MEASURED
    assert outcome.rig_time_s < stop.rig_time_s, (outcome.rig_time_s, stop.rig_time_s)


@pytest.mark.parametrize("link", ["dynamixel", "grbl"])
def test_a_given_speed_is_kept_as_given(tmp_path: Path, link: str) -> None:
    points, _, _ = _run(tmp_path, LAMBERT, DIM_W_SR, on=link, motion="continuous", scan_speed_deg_s=3.0)
    events = _events(tmp_path / "run", "scan_speed")
    assert events and all(e["bound"] == "given" for e in events)
    # Sent as given; a servo runs at its Profile Velocity's nearest step, GRBL at the feed itself.
    quantum = X_SERIES.velocity_unit_rpm * 6.0 if link == "dynamixel" else 0.0
    for speed in [e["speed_deg_s"] for e in events] + [p["scan"]["speed_deg_s"] for p in points if "scan" in p]:
        assert abs(speed - 3.0) <= 0.5 * quantum + 1e-9


def test_the_plan_times_scans_at_the_speed_the_runner_would_choose() -> None:
    rig = sim_rig(LAMBERT, reference={"every": 0})
    stop = make_plan(rig, in_plane_sweep([20.0], THETA_O)).estimate
    auto = make_plan(rig, in_plane_sweep([20.0], THETA_O, motion="continuous"))
    slow = make_plan(rig, in_plane_sweep([20.0], THETA_O, motion="continuous", scan_speed_deg_s=3.0)).estimate
    e = auto.estimate
    assert (stop.scanned, stop.scan_s, stop.scan_speeds_deg_s) == (0, 0.0, None)
    assert e.scanned == slow.scanned == SCANNED
    # The rule the runner uses, with the plan's guess at a frame's exposure (first_exposure_s, no darks' overhead).
    top = next(a.max_speed_deg_s for a in rig.axes if a.name == "camera")
    want = chosen_speed_deg_s(10.0, 0.01, top, dark_frames=1).speed_deg_s
    assert e.scan_speeds_deg_s == (pytest.approx(want), pytest.approx(want))
    assert slow.scan_speeds_deg_s == (3.0, 3.0)
    # Points swept no longer stop: less settling, fewer exposures and a shorter run than stop and go or 3 deg/s.
    assert e.exposure_s < stop.exposure_s and e.total_s < stop.total_s < slow.total_s
    assert "measured moving" in auto.summary()


def test_a_run_that_stopping_measures_sooner_is_measured_at_rest(tmp_path: Path) -> None:
    # A very dim lamp: frames so long that within the blur bound a scan takes longer than stopping at each point.
    dim: dict[str, Any] = {"target_snr": 50.0}
    points, (_, outcome), _ = _run(tmp_path / "auto", LAMBERT, 1e-4, motion="continuous", **dim)
    stopped = _events(tmp_path / "auto" / "run", "scan_stopped")
    assert stopped and not _events(tmp_path / "auto" / "run", "scan_speed")
    assert len(points) == outcome.measured == MEASURED and not any("scan" in p for p in points)
    _, (_, stop), _ = _run(tmp_path / "stop", LAMBERT, 1e-4, **dim)
    assert outcome.rig_time_s <= stop.rig_time_s * (1 + 1e-9)  # no slower than the stop and go it fell back to
    # A given speed is scanned at, however slow.
    given, _, _ = _run(tmp_path / "given", LAMBERT, 1e-4, motion="continuous", scan_speed_deg_s=1.0, **dim)
    assert any("scan" in p for p in given)


def test_the_plan_leaves_a_run_to_stop_and_go_as_the_runner_would() -> None:
    rig = sim_rig(LAMBERT, reference={"every": 0})
    # Frames of a second: the blur bound's scan of a 10 deg step takes longer than a move and one frame at rest.
    slow = {"first_exposure_s": 1.0, "max_frames": 1}
    stop = make_plan(rig, in_plane_sweep([20.0], THETA_O, **slow)).estimate
    auto = make_plan(rig, in_plane_sweep([20.0], THETA_O, motion="continuous", **slow)).estimate
    assert (auto.scanned, auto.total_s) == (0, pytest.approx(stop.total_s))
    given = make_plan(rig, in_plane_sweep([20.0], THETA_O, motion="continuous", scan_speed_deg_s=2.0, **slow))
    assert given.estimate.scanned == SCANNED
