"""A sample off the arms' axis is nearer or further from the lamp at every pose: its irradiance follows."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rig.instrument.calibration_file import write_geometry_calibration
from rig.run.session import start_run
from rig.run.storage.store import RunStore
from rig.run.tables.samples import build_rows
from tests.run_helpers import in_plane_sweep, read_rows, sim_rig

pytestmark = pytest.mark.mitsuba

OFFSET_MM = [0.0, 0.0, 8.0]  # a sample seated 8 mm proud of the stage: the lamp is ~1-2 % nearer or further


def test_a_calibrated_sample_offset_scales_each_reading_by_its_light_distance(tmp_path: Path) -> None:
    # The calibration states the offset exactly (what `gonio calibrate geometry` finds to a few micrometres).
    exact = {"sample_offset_mm": {"value": OFFSET_MM, "std_error": [0.0, 0.0, 0.0]}}
    cal = write_geometry_calibration(tmp_path / "geometry_calibration.json", exact)
    # A 4 x 4 px ROI of a 512 px frame: the footprint of a wider one, stretched on the raised plane, would
    # average the lamp's fall-off across it, a bias of its own.
    rig = sim_rig({"model": "Lambert", "rho_d": 0.5}, simulation={"misalignment": {"sample_offset_mm": OFFSET_MM}},
                  geometry={"calibration": str(cal)}, camera={"resolution": [512, 512], "roi": [254, 254, 258, 258]})
    sweep = in_plane_sweep([10.0, 50.0], [-60.0, -20.0, 30.0, 60.0], target_snr=400.0)
    summary = start_run(rig, sweep, tmp_path / "run", progress=False)
    rows = read_rows(summary.table)
    records = RunStore.read(tmp_path / "run").records()
    distances = [r["light_distance_m"] for r in records if r["kind"] in ("point", "reference")]
    assert len(distances) == len(records) - sum(r["kind"] not in ("point", "reference") for r in records)
    radius = rig.geometry.light_radius_m
    assert max(abs(d / radius - 1) for d in distances) > 0.005  # the premise: the offset moves the lamp
    truth = 0.5 / np.pi
    got = np.array([float(r["brdf_g"]) for r in rows])
    se = np.array([float(r["brdf_se_readings_g"]) for r in rows])
    assert np.all(np.abs(got - truth) < 4 * se + 2e-3 * truth), (got / truth - 1, se / truth)
    # The same journal without the distances: the inverse-square law is what brought the readings back.
    flat = build_rows([{k: v for k, v in r.items() if k != "light_distance_m"} for r in records],
                      rig.geometry.joint_names, albedo=rig.file.reference.albedo,
                      albedo_std_error=rig.file.reference.albedo_std_error)  # fmt: skip
    off = np.array([float(r["brdf_g"]) for r in flat])
    assert np.sqrt(np.mean((off / truth - 1) ** 2)) > 2 * np.sqrt(np.mean((got / truth - 1) ** 2))


def test_an_uncalibrated_rig_journals_no_distance(tmp_path: Path) -> None:
    rig = sim_rig({"model": "Lambert", "rho_d": 0.5})
    start_run(rig, in_plane_sweep([20.0], [-30.0, 40.0]), tmp_path / "run", progress=False)
    assert not any("light_distance_m" in r for r in RunStore.read(tmp_path / "run").records())
