"""A geometry calibration is stale when the rig's geometry changed, not when its file did (config/fitted_for.py).

The documented workflow calibrates examples/rig_misaligned.toml, then uncomments its calibration line: the file is
newer than the calibration, and gonio warned that it "changed after its geometry calibration", with clock times.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from rig.instrument.calibration_file import write_geometry_calibration
from rig.run.config.files import load_rig
from rig.run.config.fitted_for import changes, fitted_for

EXAMPLE = Path(__file__).resolve().parents[4] / "examples" / "rig_misaligned.toml"
LINE = '# calibration = "../calib/geometry_calibration.json"'


def _calibrated(tmp: Path) -> Path:
    """The example copied to tmp/examples, a calibration of it in tmp/calib (as `gonio calibrate geometry` writes
    it, but for the fit), then its calibration line uncommented, as its comment says: the rig file's path."""
    (tmp / "examples").mkdir()
    rig = Path(shutil.copy(EXAMPLE, tmp / "examples"))
    doc = {"light_zero_deg": {"value": 0.5, "std_error": 0.01}, "rig": {"geometry": fitted_for(load_rig(rig).file)}}
    write_geometry_calibration(tmp / "calib" / "geometry_calibration.json", doc)
    rig.write_text(rig.read_text().replace(LINE, LINE.removeprefix("# ")))
    return rig


def _edited(rig: Path, old: str, new: str) -> list[str]:
    text = rig.read_text()
    assert text.count(old) == 1, old
    rig.write_text(text.replace(old, new))
    return load_rig(rig).calibration_warnings()


def test_pointing_the_rig_file_at_its_calibration_is_not_a_change(tmp_path: Path) -> None:
    rig = _calibrated(tmp_path)
    loaded = load_rig(rig)
    assert loaded.calibration is not None and loaded.calibration.rig_geometry is not None
    assert loaded.calibration_warnings() == []
    # Neither is a default written out, nor a key of the simulated lamp (not geometry).
    assert _edited(rig, "[geometry]\n", "[geometry]\nlight_radius_m = 0.5\n") == []
    assert _edited(rig, "stray_light = 20.0", "stray_light = 40.0") == []


@pytest.mark.parametrize(("old", "new", "named"), [
    ("[geometry]\n", "[geometry]\nlight_radius_m = 0.45\n", "geometry.light_radius_m = 0.45 (was default)"),
    ("sample_tilt_deg = 0.6", "sample_tilt_deg = 0.9", "simulation.misalignment.sample_tilt_deg = 0.9 (was 0.6)"),
    ("[simulation]\n", "[simulation]\nlink = \"grbl\"\n", "simulation.link = grbl (was default)"),
])  # fmt: skip
def test_a_changed_geometry_is_warned_of_naming_what_changed(tmp_path: Path, old: str, new: str, named: str) -> None:
    warnings = _edited(_calibrated(tmp_path), old, new)
    assert len(warnings) == 1 and named in warnings[0] and "calibrate it again" in warnings[0], warnings
    assert "UTC" not in warnings[0]


def test_changes_lists_each_differing_key_with_both_values() -> None:
    then = {"geometry": {"limits": {"tilt": [-90.0, 90.0]}}, "axes": {}}
    now = {"geometry": {"limits": {"tilt": [-80.0, 90.0]}}, "axes": {"light": {"gear_ratio": 2.0}}}
    assert changes(then, now) == ["axes.light.gear_ratio = 2.0 (was default)",
                                  "geometry.limits.tilt = [-80.0, 90.0] (was [-90.0, 90.0])"]  # fmt: skip
    assert changes(now, now) == []


def test_a_calibration_without_the_record_still_compares_the_files_time(tmp_path: Path) -> None:
    # Written before calibrations recorded their geometry: the rig file newer than it is all there is to go on.
    (tmp_path / "examples").mkdir()
    rig = Path(shutil.copy(EXAMPLE, tmp_path / "examples"))
    write_geometry_calibration(tmp_path / "calib" / "geometry_calibration.json", {})
    os.utime(tmp_path / "calib" / "geometry_calibration.json", (0, 0))
    rig.write_text(rig.read_text().replace(LINE, LINE.removeprefix("# ")))
    os.utime(rig, (0, 0))  # the file's time, not the calibration file's, is compared with created_utc
    assert load_rig(rig).calibration_warnings() == []
    rig.touch()
    assert "after its geometry calibration" in load_rig(rig).calibration_warnings()[0]
