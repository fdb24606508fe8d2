"""Angular uncertainty from the journal to the report: table columns, effective errors, z-scores, the figure."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from analysis.analyze import analyze
from analysis.ladder import parse_models
from rig.instrument.alignment import PARAMETERS, Alignment, parameters_of
from rig.instrument.calibration_file import write_geometry_calibration
from rig.run.session import start_run
from tests.run_helpers import in_plane_sweep, read_rows, sim_rig

pytestmark = pytest.mark.mitsuba

GLOSSY = {"model": "CookTorrance", "alpha": 0.08, "eta": [0.18, 0.42, 1.37], "k": [3.42, 2.35, 1.77]}
SWEEP = in_plane_sweep([30.0], [-60.0, -30.0, 0.0, 20.0, 26.0, 30.0, 34.0, 40.0, 60.0], target_snr=200.0)


def _calibration(tmp: Path, std_deg: float) -> Path:
    """A geometry calibration of the perfect rig whose joint zeros are uncertain by ``std_deg``."""
    names = PARAMETERS["four_axis"]
    cov = np.diag([std_deg**2 if n.endswith("zero_deg") else 1e-12 for n in names])
    values = parameters_of(names, Alignment())
    doc = {n: {"value": float(v), "std_error": float(np.sqrt(cov[i, i]))}
           for i, (n, v) in enumerate(zip(names, values, strict=True)) if n.endswith("_deg")}  # fmt: skip
    doc["sample_offset_mm"] = {"value": [0.0, 0.0, 0.0], "std_error": [0.0, 0.0, 0.0]}
    doc["covariance"] = {"names": list(names), "matrix": cov.tolist()}
    return write_geometry_calibration(tmp / "geometry_calibration.json", doc)


def test_every_row_carries_its_directions_uncertainty_and_a_calibration_widens_it(tmp_path: Path) -> None:
    plain = start_run(sim_rig(GLOSSY), SWEEP, tmp_path / "plain", progress=False)
    rows = read_rows(plain.table)
    encoder = 360.0 / 4096 / np.sqrt(12)  # one XM430 count, uniform
    stds = np.array([float(r["theta_o_std_deg"]) for r in rows])
    assert np.all(stds > 0.5 * encoder) and np.all(stds < 3 * encoder)
    cov = np.array([json.loads(r["direction_cov"]) for r in rows])
    assert cov.shape == (len(rows), 4, 4) and np.allclose(cov, np.swapaxes(cov, 1, 2))
    cal = _calibration(tmp_path, 0.05)
    rig = sim_rig(GLOSSY, geometry={"calibration": str(cal)})
    wide = read_rows(start_run(rig, SWEEP, tmp_path / "calibrated", progress=False).table)
    wide_stds = np.array([float(r["theta_o_std_deg"]) for r in wide])
    assert np.all(wide_stds > 0.04) and np.all(wide_stds < 0.1)  # the camera's zero, 0.05 deg


def test_the_analysis_weights_by_effective_errors_and_reports_how_honest_they_are(tmp_path: Path) -> None:
    cal = _calibration(tmp_path, 0.05)
    rig = sim_rig(GLOSSY, geometry={"calibration": str(cal)})
    start_run(rig, SWEEP, tmp_path / "run", progress=False)
    page = analyze(tmp_path / "run", models=parse_models("ggx_conductor"), log=lambda _: None)
    doc = json.loads((page.parent / "fit.json").read_text())
    u = doc["uncertainty"]
    assert u["angular"]["included"] and 0 < u["angular"]["share_total"] < 1
    share = np.asarray(u["angular"]["share_per_sample"])
    assert share.max() > 0.2 and share.max() > 5 * share.min()  # a lobe's flank against its peak
    assert set(u["z_fit"]["within"]) == {"1", "2", "3"} and u["z_truth"]["n"] == u["z_fit"]["n"]
    assert (page.parent / "figures" / "uncertainty.png").is_file()
    assert "uncertainty.png" in page.read_text()
