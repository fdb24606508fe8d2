"""``gonio calibrate camera`` end to end on the simulated RAW rig, and the RAW example as a user runs it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from gonio.cli import main

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.mitsuba


def test_calibrate_camera_writes_the_calibration_the_flat_field_and_the_curve(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rig = ROOT / "examples" / "rig_simulated_raw.toml"
    code = main(["calibrate", "camera", "--rig", str(rig), "--out", str(tmp_path), "--steps", "16",
                 "--flat-frames", "8", "--quiet"])  # fmt: skip
    assert code == 0
    doc = json.loads((tmp_path / "camera_calibration.json").read_text())
    gain = doc["parameters"]["e_per_dn"]
    assert abs(gain["value"] - 3.1) < 3 * gain["std_error"]  # the example's hidden sensor
    assert set(doc["noise"]) == {"e_per_dn", "read_noise_e", "dark_current_e_per_s", "black_level_dn",
                                 "white_level_dn", "full_well_e"}  # fmt: skip
    assert (tmp_path / "flat_field.npz").stat().st_size > 0
    assert (tmp_path / "photon_transfer.png").read_bytes()[:4] == b"\x89PNG"
    assert "e_per_dn" in capsys.readouterr().out
    assert main(["calibrate", "camera", "--rig", str(rig), "--steps", "3"]) == 2  # bad input, named


@pytest.mark.slow
def test_the_raw_example_measures_gold_in_colour() -> None:
    done = subprocess.run([sys.executable, str(ROOT / "examples" / "raw_sweep.py")], capture_output=True, text=True,
                          timeout=900, cwd=ROOT, check=False)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert "r > g > b at every point: True" in done.stdout
