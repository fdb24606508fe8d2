"""``mode = "auto"`` (rig/run/measuring/mode_choice.py): image where the camera resolves the sample into many tiles,
continuous where the plan has long scan runs; the estimate of a footprint's tiles it rests on."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from rig.instrument.kinematics import inverse, require, world_pose
from rig.run.config.files import ConfigError, parse
from rig.run.config.schema import SweepFile
from rig.run.measuring.footprint import footprint_cells
from rig.run.measuring.mode_choice import (
    MIN_IMAGE_TILES,
    MIN_SCAN_POINTS,
    choose_motion,
    scan_runs,
    tiles_per_capture,
)
from rig.run.measuring.tiles import DEFAULT_TILE_PX, ImageSettings, tile_geometry
from rig.run.session import make_plan, resolve_mode, resume_run, start_run
from rig.run.storage.store import RunStore
from tests.run_helpers import LAMBERT, in_plane_sweep, read_rows, sim_rig


@pytest.mark.parametrize("resolution", [(64, 64), (128, 96)])
@pytest.mark.parametrize("angles", [(20.0, 0.0, 30.0, 180.0), (50.0, 0.0, 60.0, 180.0)])
def test_the_footprint_estimate_is_near_image_mode_s_own_count(
    resolution: tuple[int, int], angles: tuple[float, ...]
) -> None:
    g = sim_rig().geometry
    pose = world_pose(g, require(inverse(g, *angles)))
    image = ImageSettings(tile_px=4, resolution=resolution)
    exact = tile_geometry(g, pose, image)
    cells = footprint_cells(g, pose, image)
    # Edge cells pass or fail whole: within a cell's tiles per edge of a footprint of some tens of tiles a side.
    assert exact.count > 20
    assert abs(cells.count - exact.count) <= 0.2 * exact.count, (cells.count, exact.count)
    mean = exact.angles_deg.mean(axis=0)
    assert abs(float((cells.angles_deg[:, 2] * cells.tiles).sum() / cells.tiles.sum()) - mean[2]) < 2.0


def _auto(**capture: Any) -> Any:
    return in_plane_sweep([20.0], [-30.0, 30.0], mode="auto", **capture)


@pytest.mark.parametrize(("resolution", "mode"), [((32, 32), "point"), ((128, 128), "image")])
def test_auto_is_image_where_the_camera_resolves_the_sample_into_many_tiles(resolution: Any, mode: str) -> None:
    rig = sim_rig(camera={"resolution": list(resolution)})
    sweep = _auto()
    decided, choice = resolve_mode(rig, sweep, make_plan(rig, sweep))
    assert choice is not None and choice.mode == mode and decided.file.capture.mode == mode
    assert choice.tile_px == DEFAULT_TILE_PX and choice.tiles is not None
    assert (choice.tiles >= MIN_IMAGE_TILES) == (mode == "image")
    assert f"{MIN_IMAGE_TILES}" in choice.reason
    # The motion is the file's, in either mode (image frames scan too).
    scan = _auto(motion="continuous")
    decided_scan, by_motion = resolve_mode(rig, scan, make_plan(rig, scan))
    assert by_motion is not None and (by_motion.mode, by_motion.motion) == (mode, "continuous")
    assert decided_scan.file.capture.motion == "continuous"


def test_a_small_sensor_s_tiles_are_counted_as_image_mode_counts_them() -> None:
    rig = sim_rig(camera={"resolution": [64, 64]})
    plan = make_plan(rig, in_plane_sweep([20.0], [30.0]))
    g = rig.geometry
    exact = tile_geometry(g, world_pose(g, require(inverse(g, 20.0, 0.0, 30.0, 180.0))),
                          ImageSettings(tile_px=8, resolution=(64, 64))).count  # fmt: skip
    assert tiles_per_capture(rig, plan, 8) == exact


def test_a_sweep_file_s_auto_keys_are_checked() -> None:
    doc = {"sweep": {"kind": "in_plane", "theta_i_deg": [20.0], "theta_o_deg": [30.0]}}
    assert parse({**doc, "capture": {"mode": "auto", "tile_px": 4}}, SweepFile, "s.toml").capture.tile_px == 4
    with pytest.raises(ConfigError, match=r"s\.toml.*mode"):
        parse({**doc, "capture": {"mode": "automatic"}}, SweepFile, "s.toml")
    with pytest.raises(ConfigError, match="tile_px = 4 has no meaning in point mode"):
        parse({**doc, "capture": {"tile_px": 4}}, SweepFile, "s.toml")


def test_continuous_only_where_the_plan_has_a_long_scan_run() -> None:
    rig = sim_rig(LAMBERT, reference={"every": 0})
    # theta_o 30..60 by 5: one run in the camera joint of seven points.
    long = make_plan(rig, in_plane_sweep([20.0], [30.0, 35.0, 40.0, 45.0, 50.0, 55.0, 60.0]))
    assert max(scan_runs(long)) == 7
    assert choose_motion(long, True)[0] == "continuous"
    assert choose_motion(long, False)[0] == "stop"  # never unless the settings allow it
    short = make_plan(rig, in_plane_sweep([20.0, 40.0], [30.0, 50.0]))
    assert max(scan_runs(short), default=1) < MIN_SCAN_POINTS
    motion, reason, longest = choose_motion(short, True)
    assert motion == "stop" and str(MIN_SCAN_POINTS) in reason and longest < MIN_SCAN_POINTS
    # A reference reading between points ends a run, as it does in the runner.
    seven = in_plane_sweep([20.0], [30.0, 35.0, 40.0, 45.0, 50.0, 55.0, 60.0])
    with_refs = make_plan(sim_rig(LAMBERT, reference={"every": 3}), seven)
    assert max(scan_runs(with_refs)) <= 3


@pytest.mark.mitsuba
def test_a_sweep_file_s_auto_is_decided_at_start_written_in_the_manifest_and_resumed_as_decided(
    tmp_path: Path,
) -> None:
    rig = sim_rig(LAMBERT, camera={"resolution": [128, 128]}, reference={"every": 0})
    said: list[str] = []
    start_run(rig, in_plane_sweep([20.0], [30.0], mode="auto"), tmp_path / "run", progress=False, log=said.append)
    manifest = json.loads((tmp_path / "run" / "manifest.json").read_text())
    assert manifest["sweep"]["capture"]["mode"] == "image"
    assert manifest["capture_mode"]["asked"] == "auto" and manifest["capture_mode"]["mode"] == "image"
    assert said == [f"capture mode image, motion stop: {manifest['capture_mode']['reason']}"]
    rows = read_rows(tmp_path / "run" / "samples.csv")
    assert len(rows) >= MIN_IMAGE_TILES and all(r["tile"] != "" for r in rows)
    # A resume rebuilds the sweep from the manifest: image mode as decided, without deciding again.
    status = tmp_path / "run" / "status.json"
    status.unlink()
    journal = tmp_path / "run" / "journal.jsonl"
    journal.write_text("".join(line for line in journal.read_text().splitlines(keepends=True)
                               if '"kind":"point"' not in line))  # fmt: skip
    resume_run(tmp_path / "run", progress=False)
    assert [r["tile"] for r in read_rows(tmp_path / "run" / "samples.csv")] == [r["tile"] for r in rows]
    assert sum(r["kind"] == "point" for r in RunStore.read(tmp_path / "run").records()) == 1


@pytest.mark.mitsuba
def test_gonio_plan_and_run_print_what_auto_chose(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from gonio import cli

    rig = tmp_path / "rig.toml"
    rig.write_text('[camera]\nresolution = [128, 128]\n\n[reference]\nevery = 0\n')
    sweep = tmp_path / "sweep.toml"
    sweep.write_text('[sweep]\nkind = "in_plane"\ntheta_i_deg = [20.0]\ntheta_o_deg = [30.0]\n\n'
                     '[capture]\nmode = "auto"\ntile_px = 8\n')  # fmt: skip
    assert cli.main(["plan", str(sweep), "--rig", str(rig), "--quiet"]) == 0
    planned = capsys.readouterr().out
    assert "capture mode image, motion stop: the camera resolves the sample into ~" in planned and "8 px" in planned
    assert cli.main(["run", str(sweep), "--rig", str(rig), "--out", str(tmp_path / "run"), "--quiet"]) == 0
    assert "capture mode image, motion stop" in capsys.readouterr().err
    manifest = json.loads((tmp_path / "run" / "manifest.json").read_text())
    assert manifest["sweep"]["capture"] == {**manifest["sweep"]["capture"], "mode": "image", "tile_px": 8}
