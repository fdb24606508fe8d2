"""Continuous scans ([capture] motion = "continuous"): frames while the arm moves, directions at mid-exposure."""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from acquisition.frame import Frame
from model.fit.angular import angular_variance
from model.fit.samples import Samples
from rig.run.config.files import GRBL_STEPS_PER_DEGREE, ConfigError, material_from, parse
from rig.run.config.schema import SweepFile
from rig.run.measuring.scan import ScanTooFast, Stamp, exposure_window, interpolate
from rig.run.session import capture_settings
from rig.run.storage.store import RunStore
from tests.run_helpers import LAMBERT, in_plane_sweep, read_rows, run_recording_renders, sim_rig, truth_and_measured

GLOSSY = {"model": "CookTorrance", "alpha": 0.15, "eta": [0.18, 0.42, 1.37], "k": [3.42, 2.35, 1.77]}
#: Two scan runs: 10 -> 0 -> -10 and -50 -> -40 -> -30 (-20 is the light's own direction, unreachable).
THETA_O = [-50.0, -40.0, -30.0, -20.0, -10.0, 0.0, 10.0]
MEASURED, SCANNED = 6, 4
#: The read-backs' quantum (deg), and so the interpolation's: an XM430's encoder count, a default GRBL axis's step.
COUNT_DEG = {"dynamixel": 360.0 / 4096, "grbl": 1 / GRBL_STEPS_PER_DEGREE}


def _sweep(**capture: Any) -> SweepFile:
    return parse({"sweep": {"kind": "in_plane", "theta_i_deg": [20.0], "theta_o_deg": [30.0]}, "capture": capture},
                 SweepFile, "s.toml")  # fmt: skip


def test_motion_defaults_to_stop_and_its_keys_are_checked() -> None:
    assert _sweep().capture.motion == "stop" and _sweep().capture.scan_speed_deg_s is None
    rig = sim_rig(LAMBERT)
    assert capture_settings(rig, in_plane_sweep([20.0], [30.0])).scan_speed_deg_s is None
    on = capture_settings(rig, in_plane_sweep([20.0], [30.0], motion="continuous"))
    assert on.motion == "continuous" and on.scan_speed_deg_s is None  # chosen per scan run
    with pytest.raises(ConfigError, match=r'scan_speed_deg_s = 3 has no meaning with motion = "stop"'):
        _sweep(scan_speed_deg_s=3.0)
    with pytest.raises(ConfigError, match=r"s\.toml.*scan_speed_deg_s"):
        _sweep(motion="continuous", scan_speed_deg_s=0.0)
    with pytest.raises(ConfigError, match="motion"):
        _sweep(motion="sweeping")


def test_interpolation_is_linear_between_time_stamped_read_backs() -> None:
    a, b = Stamp(1.0, {"camera": 10.0}), Stamp(3.0, {"camera": 14.0})
    assert interpolate(a, b, 2.5) == {"camera": 13.0}
    assert interpolate(b, b, 9.0) == {"camera": 14.0}


def test_a_tethered_frames_exposure_is_placed_where_the_camera_fired_it_not_where_its_file_arrived() -> None:
    before = Stamp(10.0, {"camera": 0.0})
    frame = Frame(np.zeros((4, 4)), "linear", 0.1)
    assert exposure_window(before, 12.0, frame) == (pytest.approx(11.9), 12.0)  # a camera that says nothing
    fired = dataclasses.replace(frame, extra={"triggered_s": 10.05})
    assert exposure_window(before, 12.0, fired) == (pytest.approx(10.05), pytest.approx(10.15))
    # Never before the read-back that preceded the call, nor ending after its return.
    early = dataclasses.replace(frame, extra={"triggered_s": 9.0})
    late = dataclasses.replace(frame, extra={"triggered_s": 11.99})
    assert exposure_window(before, 12.0, early)[0] == 10.0 and exposure_window(before, 12.0, late)[1] == 12.0


def _run(tmp_path: Path, material: dict[str, Any], light_w_sr: float = 1.0, on: str = "dynamixel",
         **capture: Any) -> tuple[list[dict[str, Any]], Any, list[Any]]:  # fmt: skip
    """A continuous in-plane scan: its journal's points, the rig config, and (clock, camera joint) of every render."""
    rig = sim_rig(material, on=on, reference={"every": 0}, simulation={"light_intensity_w_sr": light_w_sr})
    outcome, renders = run_recording_renders(rig, in_plane_sweep([20.0], THETA_O, **capture), tmp_path / "run")
    assert not isinstance(outcome, Exception), outcome
    points = [r for r in RunStore.read(tmp_path / "run").records() if r["kind"] == "point"]
    return points, (rig, outcome), renders


def _check_mid_exposure(points: list[dict[str, Any]], renders: list[tuple[float, float]],
                        on: str = "dynamixel") -> int:  # fmt: skip
    """Every scanned point's camera joint is the arm's true angle at its exposure's middle; how many were scanned."""
    scanned = [p for p in points if "scan" in p]
    for p in scanned:
        t0, t1 = p["scan"]["exposure_start_s"], p["scan"]["exposure_end_s"]
        inside = [j for t, j in renders if t0 - 1e-9 <= t <= t1 + 1e-9]
        assert len(inside) >= 4  # the frame's sub-exposures, rendered where the arm stood then
        # Sub-exposures sit symmetrically about the middle: their mean is the true angle at mid-exposure.
        assert p["joints_deg"]["camera"] == pytest.approx(np.mean(inside), abs=COUNT_DEG[on])
        assert abs(inside[-1] - inside[0]) > 0  # the arm moved during the frame
    return len(scanned)


def _z(rows: list[dict[str, str]], rig: Any) -> np.ndarray:
    truth, got, se = truth_and_measured(rows, rig)
    return np.asarray((got - truth) / se)


@pytest.mark.parametrize("link", ["dynamixel", "grbl"])
def test_a_lambertian_scan_records_mid_exposure_directions_and_honest_readings(tmp_path: Path, link: str) -> None:
    points, (rig, outcome), renders = _run(tmp_path, LAMBERT, on=link, motion="continuous", scan_speed_deg_s=5.0)
    assert len(points) == MEASURED and _check_mid_exposure(points, renders, link) == SCANNED
    assert outcome.measured == len(points)  # what `gonio run` prints counts the scanned points too
    # Frame follows frame at the scan's pace, the last of a run too (where the arm rests on the device's whole
    # count or step nearest the run's end, which may fall short of it): never a wait for a move's timeout.
    frames = {p["index"]: (p["scan"]["exposure_start_s"], p["scan"]["exposure_end_s"]) for p in points if "scan" in p}
    gaps = [frames[i + 1][0] - frames[i][1] for i in frames if i + 1 in frames]  # within a run: 1 -> 2, 5 -> 6
    assert len(gaps) == 2 and max(gaps) < 1.5 * 10.0 / 5.0, gaps  # a 10 deg step at 5 deg/s
    blur_var = [p["angle_cov_deg2"] for p in points if "scan" in p]
    assert all(np.all(np.isfinite(v)) for v in blur_var)
    z = _z(read_rows(outcome.table), rig)
    assert np.mean(np.abs(z) < 2) >= 0.6 and np.max(np.abs(z)) < 5


def test_a_too_fast_scan_warns_with_its_blur_and_a_speed_that_keeps_it_in_bounds(tmp_path: Path) -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        # A dim lamp: frames of ~1 s, which at 30 deg/s blur over far more than half the 10 deg step.
        _run(tmp_path, LAMBERT, 1e-4, motion="continuous", scan_speed_deg_s=30.0, target_snr=50.0)
    too_fast = [w for w in caught if issubclass(w.category, ScanTooFast)]
    assert too_fast, [str(w.message) for w in caught]
    assert "blurs each frame over" in str(too_fast[0].message) and "scan_speed_deg_s <=" in str(too_fast[0].message)


def test_a_glossy_scan_agrees_with_its_truth_within_errors_that_hold_the_blur(tmp_path: Path) -> None:
    points, (rig, outcome), renders = _run(tmp_path, GLOSSY, motion="continuous", scan_speed_deg_s=20.0)
    assert _check_mid_exposure(points, renders) == SCANNED
    rows = read_rows(outcome.table)
    truth, got, se = truth_and_measured(rows, rig)
    var = angular_variance(material_from(rig), Samples.from_table_rows(rows, errors="readings"))
    z = np.asarray((got - truth) / np.sqrt(se**2 + var))
    assert np.mean(np.abs(z) < 2) >= 0.6 and np.max(np.abs(z)) < 5, z
    # The moving joint's blur, (speed x exposure)^2 / 12, is in every scanned point's covariance.
    for p in (p for p in points if "scan" in p):
        assert np.trace(np.asarray(p["angle_cov_deg2"])) >= (20.0 * p["exposures_s"][0]) ** 2 / 12 * 0.5
