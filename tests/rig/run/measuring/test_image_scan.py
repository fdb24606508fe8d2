"""Continuous scans in image mode: the arm sweeps while whole frames stream; every tile of every frame a sample."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from model.fit.angular import angular_variance
from model.fit.samples import Samples
from rig.instrument.kinematics import Joints, world_pose
from rig.instrument.links.dynamixel_table import X_SERIES
from rig.run.config.files import material_from, parse
from rig.run.config.schema import SweepFile
from rig.run.measuring.tiles import ImageSettings, TileGeometry, tile_geometry
from rig.run.session import capture_settings
from rig.run.storage.store import RunStore
from tests.run_helpers import LAMBERT, in_plane_sweep, read_rows, run_recording_renders, sim_rig, truth_and_measured

#: Two scan runs, as in test_continuous_scan: 10 -> 0 -> -10 and -50 -> -40 -> -30 (-20 is the light's direction).
THETA_O = [-50.0, -40.0, -30.0, -20.0, -10.0, 0.0, 10.0]
SPEED = 5.0
#: One encoder count of an XM430 (deg): the read-backs' quantum, and so the interpolation's.
COUNT_DEG = 360.0 / 4096
#: A 64 px frame sees the 50 mm sample over ~46 px: with 4 px tiles, ~100 samples per frame.
IMAGE = ImageSettings(tile_px=4, resolution=(64, 64))
#: A highlight sharp enough that the frame after a dim one clips where it crosses the sample.
SHARP = {"model": "CookTorrance", "alpha": 0.05, "eta": [0.18, 0.42, 1.37], "k": [3.42, 2.35, 1.77]}


def test_continuous_motion_with_image_mode_is_accepted() -> None:
    doc = {"sweep": {"kind": "in_plane", "theta_i_deg": [20.0], "theta_o_deg": [30.0]},
           "capture": {"mode": "image", "motion": "continuous", "tile_px": 4}}  # fmt: skip
    capture = parse(doc, SweepFile, "s.toml").capture
    assert (capture.mode, capture.motion) == ("image", "continuous")
    settings = capture_settings(sim_rig(LAMBERT, camera={"resolution": [64, 64]}),
                                in_plane_sweep([20.0], [30.0], mode="image", motion="continuous"))  # fmt: skip
    assert settings.image is not None and settings.motion == "continuous"


def _run(run: Path, material: dict[str, Any], theta_o: list[float], resolution: int,
         speed: float) -> tuple[list[dict[str, Any]], Any, Any, list[tuple[float, float]]]:  # fmt: skip
    """An image-mode continuous in-plane scan: its journal, the table, the rig and (clock, camera joint) per render."""
    rig = sim_rig(material, reference={"every": 0}, camera={"resolution": [resolution, resolution]})
    sweep = in_plane_sweep([20.0], theta_o, mode="image", tile_px=4, motion="continuous", scan_speed_deg_s=speed)
    outcome, renders = run_recording_renders(rig, sweep, run)
    assert not isinstance(outcome, Exception), outcome
    return RunStore.read(run).records(), outcome, rig, renders


@pytest.fixture(scope="module")
def lambert_scan(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[dict[str, Any]], Any, Any, list[Any]]:
    return _run(tmp_path_factory.mktemp("scan") / "run", LAMBERT, THETA_O, 64, SPEED)


def _true_tiles(record: dict[str, Any], renders: list[tuple[float, float]], g: Any) -> TileGeometry:
    """The tiles as the servos really stood at the frame's mid-exposure (its sub-exposures' mean camera angle)."""
    t0, t1 = record["scan"]["exposure_start_s"], record["scan"]["exposure_end_s"]
    inside = [j for t, j in renders if t0 - 1e-9 <= t <= t1 + 1e-9]
    assert len(inside) >= 4 and abs(inside[-1] - inside[0]) > 0  # the arm moved during the frame
    # Sub-exposures sit symmetrically about the middle: their mean is the true angle at mid-exposure, which the
    # record's joints, interpolated between time-stamped read-backs, hold to within an encoder count.
    assert record["joints_deg"]["camera"] == pytest.approx(np.mean(inside), abs=COUNT_DEG)
    joints = Joints.from_dict({**record["joints_deg"], "camera": float(np.mean(inside))})
    return tile_geometry(g, world_pose(g, joints), IMAGE)


def _tiles(record: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A record's tile numbers, angles (T, 4) in deg and angle covariances (T, 4, 4) with the pose's added."""
    t = record["tiles"]
    angles = np.array([t[k] for k in ("theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg")]).T
    cov = np.asarray(t["angle_cov_deg2"]).reshape(-1, 4, 4) + np.asarray(record["angle_cov_deg2"])
    return np.asarray(t["tile"]), angles, cov


@pytest.mark.mitsuba
def test_every_tile_of_a_scanned_frame_is_a_sample_at_its_mid_exposure_directions(
    lambert_scan: tuple[list[dict[str, Any]], Any, Any, list[Any]],
) -> None:
    records, outcome, rig, renders = lambert_scan
    points = [r for r in records if r["kind"] == "point"]
    scanned = [p for p in points if "scan" in p]
    assert len(points) == 6 and len(scanned) == 4
    rows = read_rows(outcome.table)
    assert len(rows) == sum(len(p["tiles"]["tile"]) for p in points)
    g = rig.geometry
    for p in scanned:
        numbers, angles, cov = _tiles(p)
        assert len(numbers) >= 50
        assert [int(r["tile"]) for r in rows if int(r["index"]) == p["index"]] == numbers.tolist()
        true = _true_tiles(p, renders, g)
        at = {int(n): k for k, n in enumerate(true.tile)}
        assert sum(int(n) in at for n in numbers) >= 0.95 * len(numbers)
        for k, n in enumerate(numbers):
            if int(n) not in at:
                continue  # a tile at the sample's edge that the true pose no longer sees whole
            delta = angles[k] - true.angles_deg[at[int(n)]]
            delta[[1, 3]] = (delta[[1, 3]] + 180.0) % 360.0 - 180.0
            sd = np.sqrt(np.diag(cov[k]))
            assert np.all(np.abs(delta)[[0, 2]] <= 3 * sd[[0, 2]]), (p["index"], n, delta, sd)


@pytest.mark.mitsuba
def test_a_scanned_frames_readings_are_honest_and_its_blur_is_in_every_tile(
    lambert_scan: tuple[list[dict[str, Any]], Any, Any, list[Any]],
) -> None:
    records, outcome, rig, _ = lambert_scan
    rows = read_rows(outcome.table)
    scanned_index = {r["index"] for r in records if r["kind"] == "point" and "scan" in r}
    scanned = [r for r in rows if int(r["index"]) in scanned_index]
    truth, got, _ = truth_and_measured(scanned, rig)
    se = np.array([[float(r[f"brdf_se_readings_{c}"]) for c in "rgb"] for r in scanned])
    var = angular_variance(material_from(rig), Samples.from_table_rows(scanned, errors="readings"))
    z = np.asarray((got - truth) / np.sqrt(se**2 + var))
    within = [float(np.mean(np.abs(z) < n)) for n in (1, 2, 3)]
    assert within[0] > 0.55 and within[1] > 0.92 and within[2] > 0.985, within
    g = rig.geometry
    # The servo runs at the nearest step of its Profile Velocity register (and the scan takes that speed).
    speed = X_SERIES.velocity_units(SPEED) * X_SERIES.velocity_unit_rpm * 6.0
    for p in (r for r in records if r["kind"] == "point"):
        numbers, angles, _ = _tiles(p)
        footprint = tile_geometry(g, world_pose(g, Joints.from_dict(p["joints_deg"])), IMAGE)
        at = [{int(n): k for k, n in enumerate(footprint.tile)}[int(n)] for n in numbers]
        cov = np.asarray(p["tiles"]["direction_cov"]).reshape(-1, 4, 4)
        # What the tiles carry beyond their footprint, in the tangent components of wo (x: along the sweep).
        extra = cov[:, 2:, 2:] - footprint.direction_cov[at, 2:, 2:]
        if "scan" not in p:  # at rest: the footprint alone
            assert np.allclose(extra, 0.0, atol=1e-12)
            continue
        # The camera joint's blur, (speed x exposure)^2 / 12, turns wo about the sweep's axis: on a flat sample
        # each tile's wo_x moves by cos(theta_o) per radian, wherever the tile lies (near the pole too).
        blur = np.radians(speed * p["exposures_s"][0]) ** 2 / 12 * np.cos(np.radians(angles[:, 2])) ** 2
        assert extra[:, 0, 0] == pytest.approx(blur, rel=0.02)
        assert np.all(np.abs(extra[:, 1, 1]) < 0.01 * blur)


@pytest.mark.mitsuba
def test_a_highlight_clipping_tiles_of_a_scanned_frame_leaves_them_lower_bounds_and_the_scan_going(
    tmp_path: Path,
) -> None:
    # 0 deg at rest, then the scan towards the mirror direction (20 deg): the frame at 16 deg, planned from 10 deg
    # where the highlight is far dimmer, clips where the highlight crosses the sample.
    records, outcome, _, _ = _run(tmp_path / "run", SHARP, [0.0, 10.0, 16.0, 20.0], 48, SPEED)
    points = [r for r in records if r["kind"] == "point"]
    assert [("scan" in p) for p in points] == [False, True, True, True]  # the scan went on past the clipped frame
    clipped = [p for p in points if any(p["tiles"]["lower_bound"])]
    assert clipped and all("scan" in p for p in clipped)
    for p in clipped:
        assert 0 < sum(p["tiles"]["lower_bound"]) < len(p["tiles"]["tile"])  # only the tiles that clipped
    events = [r for r in records if r["kind"] == "event" and r["event"] == "scan_clipped_tiles"]
    assert len(events) == len(clipped)
    # The next frame is planned from the clipped one's brightest tile: shorter.
    after = points[points.index(clipped[0]) + 1]
    assert after["exposures_s"][0] < clipped[0]["exposures_s"][0]
    rows = read_rows(outcome.table)
    lower = [r["lower_bound"].lower() == "true" for r in rows]
    assert sum(lower) == sum(sum(p["tiles"]["lower_bound"]) for p in points)
