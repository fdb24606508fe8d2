"""Image mode: every k x k tile of the sample's footprint is a sample, with honest errors and its own directions."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from analysis.analyze import load_and_fit
from analysis.ladder import parse_models
from model.fit.angular import angular_variance
from model.fit.samples import Samples
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import inverse, require, world_pose
from rig.run.config.files import ConfigError, material_from, parse
from rig.run.config.schema import SweepFile
from rig.run.measuring.tiles import DEFAULT_TILE_PX, ImageSettings, tile_geometry
from rig.run.session import capture_settings, start_run
from rig.run.storage.store import RunStore
from rig.run.tables.parquet import schema_doc
from tests.run_helpers import LAMBERT, in_plane_sweep, read_rows, sim_rig, truth_and_measured

GLOSSY = {"model": "CookTorrance", "alpha": 0.08, "distribution": "ggx", "fresnel": "conductor",
          "eta": [0.18, 0.42, 1.37], "k": [3.42, 2.35, 1.77]}  # fmt: skip
#: A 64 px frame sees the 50 mm sample over ~46 px: with 4 px tiles, ~100 samples per capture.
CAMERA = {"resolution": [64, 64]}


def _sweep(**capture: Any) -> SweepFile:
    return parse({"sweep": {"kind": "in_plane", "theta_i_deg": [20.0], "theta_o_deg": [30.0]}, "capture": capture},
                 SweepFile, "s.toml")  # fmt: skip


def test_tile_px_without_image_mode_is_refused_and_the_defaults_stay_point_mode() -> None:
    with pytest.raises(ConfigError, match=r'tile_px = 4 has no meaning in point mode.*mode = "image"'):
        _sweep(tile_px=4)
    assert _sweep().capture.mode == "point"
    rig = sim_rig(LAMBERT, camera=CAMERA)
    assert capture_settings(rig, in_plane_sweep([20.0], [30.0])).image is None
    image = capture_settings(rig, in_plane_sweep([20.0], [30.0], mode="image")).image
    assert image is not None and image.tile_px == DEFAULT_TILE_PX and image.resolution == (64, 64)
    with pytest.raises(ConfigError, match="tile_px"):
        _sweep(mode="image", tile_px=0)


def test_grazing_tiles_are_left_out_beyond_the_limit_and_none_is_nan() -> None:
    g = RigGeometry()
    pose = world_pose(g, require(inverse(g, 20.0, 0.0, 70.0, 180.0)))
    every = tile_geometry(g, pose, ImageSettings(tile_px=2, resolution=(64, 64)))
    limited = tile_geometry(g, pose, ImageSettings(tile_px=2, resolution=(64, 64), grazing_limit_deg=70.0))
    assert every.count > 0 and every.grazing == 0
    assert 0 < limited.grazing and limited.count + limited.grazing == every.count
    for t in (every, limited):
        assert np.all(np.isfinite(t.angles_deg)) and np.all(np.isfinite(t.direction_cov))
    assert limited.angles_deg[:, 2].max() <= 70.0
    # Looking along the sample's plane: nothing is a sample, and nothing breaks.
    edge = tile_geometry(g, world_pose(g, require(inverse(g, 20.0, 0.0, 84.9, 180.0))),
                         ImageSettings(tile_px=8, resolution=(64, 64)))  # fmt: skip
    assert edge.count == 0


def _z(rows: list[dict[str, str]], rig: Any, angular: bool) -> np.ndarray:
    """(value - truth) / error per row and channel; the simulated tile's albedo is exact: readings' errors."""
    truth, got, _ = truth_and_measured(rows, rig)
    se = np.array([[float(r[f"brdf_se_readings_{c}"]) for c in "rgb"] for r in rows])
    var = angular_variance(material_from(rig), Samples.from_table_rows(rows, errors="readings")) if angular else 0.0
    return np.asarray((got - truth) / np.sqrt(se**2 + var))


def _within(z: np.ndarray) -> list[float]:
    return [float(np.mean(np.abs(z) < n)) for n in (1, 2, 3)]


@pytest.fixture(scope="module")
def lambert_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Any]:
    rig = sim_rig(LAMBERT, camera=CAMERA)
    run = tmp_path_factory.mktemp("image") / "run"
    start_run(rig, in_plane_sweep([10.0, 40.0], [-50.0, -25.0, 20.0], mode="image", tile_px=4), run, progress=False)
    return run, rig


@pytest.mark.mitsuba
def test_a_lambertian_image_run_gives_many_honest_samples_per_capture(lambert_run: tuple[Path, Any]) -> None:
    run, rig = lambert_run
    records = [r for r in RunStore.read(run).records() if r["kind"] == "point"]
    rows = read_rows(run / "samples.csv")
    assert len(rows) == sum(len(r["tiles"]["tile"]) for r in records)
    g = rig.geometry
    for rec in records:
        pose = world_pose(g, require(inverse(g, *rec["target_deg"])))
        # Pixels whose centre sees the sample: whole tiles of them are the samples (the edge's are not).
        on = tile_geometry(g, pose, ImageSettings(tile_px=1, resolution=(64, 64))).count
        assert 0.6 * on / 16 < len(rec["tiles"]["tile"]) <= on / 16
        assert len(rec["tiles"]["tile"]) >= 50
    for row in rows:
        assert row["tile"] != "" and all(row[k] not in ("", "nan") for k in ("brdf_g", "brdf_se_g", "theta_i_deg"))
    # One point's tiles see different directions (the camera's rays fan out over the sample).
    first = [r for r in rows if r["index"] == rows[0]["index"]]
    assert np.ptp([float(r["theta_o_deg"]) for r in first]) > 2.0
    within = _within(_z(rows, rig, angular=False))
    assert 0.58 < within[0] < 0.85 and within[1] > 0.92 and within[2] > 0.985, within
    schema = schema_doc(rows, None)
    assert "image mode" in json.dumps(schema["columns"]["tile"])


@pytest.mark.mitsuba
def test_gonio_analyze_fits_an_image_run(lambert_run: tuple[Path, Any]) -> None:
    run, _ = lambert_run
    fit = load_and_fit(run, models=parse_models("lambert")).selection.chosen
    got = dict(zip(fit.names, fit.values, strict=True))
    se = dict(zip(fit.names, fit.std_errors, strict=True))
    key = next(k for k in got if k.startswith("rho"))
    assert abs(got[key] - 0.5) < 3 * se[key] + 0.005, (got, se)


@pytest.mark.mitsuba
def test_a_highlight_crossing_tiles_is_covered_by_their_footprint(tmp_path: Path) -> None:
    rig = sim_rig(GLOSSY, camera=CAMERA)
    sweep = in_plane_sweep([30.0], [-40.0, -30.0, 25.0, 30.0], mode="image", tile_px=8)
    summary = start_run(rig, sweep, tmp_path / "run", progress=False)
    rows = [r for r in read_rows(summary.table) if r["lower_bound"].lower() != "true"]
    assert len(rows) >= 40
    # The photometric error alone misses the BRDF's change across a tile near the highlight ...
    assert _within(_z(rows, rig, angular=False))[2] < 0.95
    # ... the tile's footprint (its directions' spread) carries it: no sample is further than its errors allow.
    within = _within(_z(rows, rig, angular=True))
    assert within[1] > 0.95 and within[2] > 0.997, within


@pytest.mark.mitsuba
def test_point_mode_records_and_columns_are_unchanged(tmp_path: Path) -> None:
    rig = sim_rig(LAMBERT, camera=CAMERA)
    summary = start_run(rig, in_plane_sweep([20.0], [-30.0, 40.0]), tmp_path / "run", progress=False)
    rows = read_rows(summary.table)
    assert len(rows) == 2 and "tile" not in rows[0]
    records = RunStore.read(tmp_path / "run").records()
    assert not any("tiles" in r or "light_distance_m" in r for r in records)
    manifest = json.loads((tmp_path / "run" / "manifest.json").read_text())
    assert "mode" not in json.dumps(manifest.get("sweep", {}).get("capture", {}))


@pytest.mark.mitsuba
def test_an_image_run_of_a_sphere_sees_many_directions_in_one_capture_with_honest_errors(tmp_path: Path) -> None:
    # A 20 mm Lambertian sphere: each tile sees its own normal, so one capture spans a wide range of theta_i,
    # and each tile's reading is still the material's BRDF at its own directions within its error.
    rig = sim_rig(LAMBERT, camera=CAMERA, sample={"shape": "sphere", "radius_mm": 20.0})
    start_run(rig, in_plane_sweep([20.0], [-30.0], mode="image", tile_px=4), tmp_path / "run", progress=False)
    rows = read_rows(tmp_path / "run" / "samples.csv")
    assert len(rows) >= 30
    theta_i = [float(r["theta_i_deg"]) for r in rows]
    assert np.ptp(theta_i) > 30.0  # a flat sample's tiles span a few degrees; the sphere's, tens
    # Across a tile of a curved sample cos(theta_i) / d^2 varies far more than the noise: calibrated with the
    # footprint's mean irradiance (the tile's effective light distance), a Lambertian tile reads rho / pi.
    within = _within(_z(rows, rig, angular=False))
    assert 0.5 < within[0] and within[1] > 0.9 and within[2] > 0.98, within
