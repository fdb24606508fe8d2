"""examples/rig_misaligned.toml runs a sweep, as drawn and with its geometry calibration applied as its comment says.

Its 512 px frame (for the calibration board) gives runs a 156 x 180 px ROI, whose mean reaches its SNR goal in
frames too short for the merge to detect its pixels: the first reference reading, a lit tile, was dark and the
run stopped on a camera fault (exit 4). The calibration is written from the simulation's truth (what `gonio
calibrate geometry` finds to a few hundredths of a degree), not fitted: that takes thirty whole-frame captures.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from gonio.cli import main
from rig.instrument.calibration_file import SCALARS, write_geometry_calibration
from rig.run.config.files import load_rig
from simulator.from_config import alignment_from

pytestmark = pytest.mark.mitsuba

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
CALIBRATION_LINE = '# calibration = "../calib/geometry_calibration.json"'
#: A few points of examples/sweep_in_plane.toml, with its [capture] table.
SWEEP = """name = "a few points of the in-plane slice"
[sweep]
kind = "in_plane"
theta_i_deg = [30.0]
theta_o_deg = [-50.0, 10.0, 50.0]
[capture]
target_snr = 200.0
max_frames = 5
dark_frames = 1
"""


def _truth_calibration(rig_path: Path, out: Path) -> Path:
    """A geometry calibration holding the simulated rig's true alignment, exactly."""
    truth = alignment_from(load_rig(rig_path).file.simulation.misalignment)
    doc = {name: {"value": getattr(truth, name), "std_error": 0.0} for name in SCALARS if name != "yaw_zero_deg"}
    doc["sample_offset_mm"] = {"value": list(truth.sample_offset_mm), "std_error": [0.0, 0.0, 0.0]}
    return write_geometry_calibration(out, doc)


@pytest.mark.parametrize("calibrated", [False, True], ids=["as-drawn", "calibrated"])
def test_the_misaligned_example_runs_a_sweep_with_every_reading_lit(tmp_path: Path, calibrated: bool) -> None:
    examples = tmp_path / "examples"
    examples.mkdir()
    rig = Path(shutil.copy(EXAMPLES / "rig_misaligned.toml", examples))
    if calibrated:  # the workflow of the file's comment: calibrate into calib/, then uncomment the line
        _truth_calibration(rig, tmp_path / "calib" / "geometry_calibration.json")
        text = rig.read_text()
        assert text.count(CALIBRATION_LINE) == 1
        rig.write_text(text.replace(CALIBRATION_LINE, CALIBRATION_LINE.removeprefix("# ")))
        assert load_rig(rig).calibration is not None
    sweep = examples / "sweep.toml"
    sweep.write_text(SWEEP)
    out = tmp_path / "run"
    assert main(["run", str(sweep), "--rig", str(rig), "--out", str(out), "--quiet"]) == 0
    records = [json.loads(line) for line in (out / "journal.jsonl").read_text().splitlines()]
    readings = [r for r in records if r["kind"] in ("point", "reference")]
    assert sorted(r["kind"] for r in readings) == ["point"] * 3 + ["reference"] * 2
    assert not any(r["dark"] for r in readings), [(r["kind"], r["n_dark"], r["notes"]) for r in readings]
    assert all(min(r["reading"]) > 0 for r in readings)
    assert ("light_distance_m" in readings[0]) == calibrated  # the calibration is in force
