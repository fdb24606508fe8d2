"""A whole RAW sweep on the simulated rig: rendered, through the sensor model, written as DNG, read back
through rawpy, reduced per CFA colour; and the camera calibrated on the same rig, used by a run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from acquisition.exposure.spec import CameraTiming
from rig.run.calibrate import CalibrationSettings, calibrate_camera, camera_noise, write_calibration
from rig.run.config.files import ConfigError
from rig.run.session import capture_settings, instruments, start_run
from rig.run.storage.store import RunStore
from tests.run_helpers import GOLD, in_plane_sweep, read_rows, sim_rig, truth_and_measured

pytestmark = pytest.mark.mitsuba


def test_a_raw_sweep_through_dng_keeps_the_colour_of_gold(tmp_path: Path) -> None:
    rig = sim_rig(GOLD, simulation={"camera_output": "dng"})
    summary = start_run(rig, in_plane_sweep([30.0], [-40.0, 0.0, 30.0, 60.0]), tmp_path / "run", progress=False)
    rows = read_rows(summary.table)
    truth, got, se = truth_and_measured(rows, rig)
    assert np.all(got[:, 0] > got[:, 1]) and np.all(got[:, 1] > got[:, 2])  # gold: r > g > b
    assert np.all(np.abs(got - truth) < 4 * se), (got, truth, se)
    # The journal holds three different readings per point, not one number copied into r, g and b.
    points = [r for r in RunStore.read(tmp_path / "run").records() if r["kind"] == "point"]
    assert all(len(set(p["reading"])) == 3 for p in points)
    assert all(len(p["level"]["channel_means"]) == 3 for p in points)


def test_a_run_with_a_flat_field_divides_out_the_vignetting_it_measured(tmp_path: Path) -> None:
    sensor = {"vignetting": 0.35, "prnu_rms": 0.01}
    tables = {"camera": {"resolution": [48, 48]}, "simulation": {"camera_output": "raw", "sensor": sensor}}
    rig = sim_rig(**tables)
    with instruments(rig) as inst:
        c = rig.file.camera
        cal = calibrate_camera(inst.camera, inst.flat_source, inst.clock, CameraTiming(c.min_exposure_s,
                               c.max_exposure_s), CalibrationSettings(steps=16, flat_frames=8))  # fmt: skip
    write_calibration(cal, CalibrationSettings(steps=16, flat_frames=8), tmp_path)
    sweep = in_plane_sweep([20.0], [-60.0, 50.0, 65.0])
    plain = read_rows(start_run(rig, sweep, tmp_path / "plain", progress=False).table)
    with_flat = {**tables["camera"], "flat_field": str(tmp_path / "flat_field.npz")}
    corrected_rig = sim_rig(**{**tables, "camera": with_flat})
    assert capture_settings(corrected_rig, sweep).flat_field is not None
    flat = read_rows(start_run(corrected_rig, sweep, tmp_path / "flat", progress=False).table)
    t, got_plain, se_plain = truth_and_measured(plain, rig)
    _, got_flat, se_flat = truth_and_measured(flat, rig)
    # The ROI sits near the sensor's centre, brighter than the sensor's mean response the map is normalised
    # to: corrected readings are lower by that factor, and the BRDF (a ratio to the reference) agrees with
    # the truth either way, since reference and sample share the ROI's place.
    ratio = np.array([[float(b[f"reading_{c}"]) / float(a[f"reading_{c}"]) for c in "rgb"]
                      for a, b in zip(plain, flat, strict=True)])  # fmt: skip
    assert np.all(ratio < 0.97) and np.all(ratio > 0.8), ratio
    assert np.all(np.abs(got_flat - t) < 4 * se_flat), (got_flat, t, se_flat)
    assert np.all(np.abs(got_plain - t) < 4 * se_plain)


def test_the_calibration_a_rig_file_names_is_what_the_run_assumes(tmp_path: Path) -> None:
    rig = sim_rig(camera={"resolution": [40, 32]}, simulation={"sensor": {"e_per_dn": 2.2, "read_noise_e": 5.0}})
    settings = CalibrationSettings(steps=20, flat_frames=0)
    with instruments(rig) as inst:
        c = rig.file.camera
        cal = calibrate_camera(inst.camera, inst.flat_source, inst.clock,
                               CameraTiming(c.min_exposure_s, c.max_exposure_s), settings)  # fmt: skip
    assert abs(cal.ptc.e_per_dn.value - 2.2) < 3 * cal.ptc.e_per_dn.std_error
    assert abs(cal.ptc.read_noise_e.value - 5.0) < 3 * cal.ptc.read_noise_e.std_error
    # 20 exposures of two flats and two darks, after the frames that found the saturation exposure.
    assert 80 + 2 <= cal.frames <= 80 + 12
    assert cal.capture_time_s > 2 * sum(p.exposure_s for p in cal.ptc.points if p.plane == "c0")
    (path,) = write_calibration(cal, settings, tmp_path)
    doc = json.loads(path.read_text())
    assert doc["parameters"]["e_per_dn"]["std_error"] > 0 and "linearity_error_percent" in doc
    calibrated = sim_rig(camera={"resolution": [40, 32], "calibration": str(path)})
    assert camera_noise(calibrated).e_per_dn == pytest.approx(cal.ptc.e_per_dn.value)
    with pytest.raises(ConfigError, match=r"camera\.calibration = .*no such file"):
        camera_noise(sim_rig(camera={"calibration": str(tmp_path / "missing.json")}))
    with pytest.raises(ConfigError, match=r"\[camera\.noise\] both given"):
        camera_noise(sim_rig(camera={"calibration": str(path), "noise": {"e_per_dn": 3.0}}))
