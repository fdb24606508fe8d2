"""Image mode on a real camera's frames: the sensor's size learnt from a whole frame and checked; RAW mosaic tiles."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from acquisition.frame import ExposureSettings, Frame, FrameKind
from rig.instrument.alignment import Alignment
from rig.instrument.calibration_file import (
    CalibrationFileError,
    GeometryCalibration,
    read_geometry_calibration,
    write_geometry_calibration,
)
from rig.run.config.files import parse, rig_config
from rig.run.config.schema import RigFile
from rig.run.measuring.image_capture import ImageModeError
from rig.run.measuring.sensor_size import learn_sensor
from rig.run.session import capture_settings, start_run
from tests.run_helpers import in_plane_sweep, read_rows, sim_rig, truth_and_measured


class FrameCamera:
    """A camera delivering (H, W) frames of ``kind`` at ``origin``; counts its captures."""

    def __init__(self, shape: tuple[int, int], kind: FrameKind = "raw", origin: tuple[int, int] = (0, 0)) -> None:
        self.shape, self.kind, self.origin = shape, kind, origin
        self.exposure_s = 0.01
        self.captures = 0

    identity = "test camera"

    def set_exposure(self, exposure_s: float, gain: float | None = None) -> ExposureSettings:
        self.exposure_s = exposure_s
        return ExposureSettings(exposure_s, gain or 1.0)

    def close(self) -> None:
        """Nothing to release."""

    def capture(self) -> Frame:
        self.captures += 1
        return Frame(np.full(self.shape, 600, dtype=np.uint16), self.kind, self.exposure_s, black_level=512.0,
                     cfa_pattern="RGGB" if self.kind == "raw" else None, origin_xy=self.origin)  # fmt: skip


def _hardware_rig(calibration: GeometryCalibration | None = None) -> Any:
    doc = {"link": {"kind": "dynamixel", "port": "/dev/null"}, "camera": {"backend": "folder", "folder": "/tmp/in"},
           "axes": {name: {"id": i} for i, name in enumerate(("light", "camera", "tilt", "roll"), 1)},
           "reference": {"kind": "manual"}}  # fmt: skip
    return rig_config(parse(doc, RigFile, "lab.toml"), "lab.toml", calibration=calibration)


def _calibration(sensor: tuple[int, int] | None) -> GeometryCalibration:
    return GeometryCalibration(Alignment(), path=Path("calib/geometry_calibration.json"), sensor_px=sensor)


def test_a_folder_cameras_sensor_is_learnt_from_its_first_whole_frame() -> None:
    capture = capture_settings(_hardware_rig(), in_plane_sweep([20.0], [30.0], mode="image", tile_px=4))
    assert capture.image is not None and capture.image.resolution is None  # a folder camera's file states none
    camera = FrameCamera((48, 64))
    learnt = learn_sensor(camera, capture)
    assert learnt.image is not None and learnt.image.sensor == (64, 48) and camera.captures == 1
    assert learn_sensor(camera, learnt) is learnt and camera.captures == 1  # known: no frame taken
    # A resumed run's points were measured on that sensor: the same size passes, another is refused.
    records = [{"kind": "point", "sensor_px": [64, 48]}]
    assert learn_sensor(FrameCamera((48, 64)), capture, records).image == learnt.image
    with pytest.raises(ImageModeError, match=r"80 x 48 px, but the run's journal .* says 64 x 48 px"):
        learn_sensor(FrameCamera((48, 80)), capture, records)


def test_a_sensor_other_than_the_geometry_calibrations_is_refused_naming_both_sizes() -> None:
    rig = _hardware_rig(_calibration((64, 48)))
    capture = capture_settings(rig, in_plane_sweep([20.0], [30.0], mode="image", tile_px=4))
    assert capture.image is not None
    assert learn_sensor(FrameCamera((48, 64)), capture).image is not None
    with pytest.raises(ImageModeError, match=r"96 x 48 px, but the geometry calibration "
                       r"calib/geometry_calibration.json says 64 x 48 px"):  # fmt: skip
        learn_sensor(FrameCamera((48, 96)), capture)
    # A calibration older than the record states no sensor: nothing to check against.
    old = capture_settings(_hardware_rig(_calibration(None)), in_plane_sweep([20.0], [30.0], mode="image"))
    assert learn_sensor(FrameCamera((48, 96)), old).image is not None
    # The simulated camera's resolution is checked when the settings are made, before a run directory exists.
    sim = dataclasses.replace(sim_rig(camera={"resolution": [64, 64]}), calibration=_calibration((64, 48)))
    with pytest.raises(ImageModeError, match=r"test-rig.toml: camera.resolution: 64 x 64 px, but .* says 64 x 48"):
        capture_settings(sim, in_plane_sweep([20.0], [30.0], mode="image"))


def test_a_crop_and_an_odd_tile_on_a_mosaic_are_refused_before_anything_moves() -> None:
    capture = capture_settings(_hardware_rig(), in_plane_sweep([20.0], [30.0], mode="image", tile_px=4))
    with pytest.raises(ImageModeError, match=r"a 64 x 48 px crop at \(8, 0\).*deliver whole frames"):
        learn_sensor(FrameCamera((48, 64), origin=(8, 0)), capture)
    odd = capture_settings(_hardware_rig(), in_plane_sweep([20.0], [30.0], mode="image", tile_px=5))
    with pytest.raises(ImageModeError, match=r"tile_px = 5 on a raw .*even tile_px"):
        learn_sensor(FrameCamera((48, 64)), odd)
    assert learn_sensor(FrameCamera((48, 64), kind="linear"), odd).image is not None


def test_the_geometry_calibration_file_records_its_sensor(tmp_path: Path) -> None:
    doc = {"light_zero_deg": {"value": 0.1, "std_error": 0.01}, "sensor_px": [640, 480]}
    path = write_geometry_calibration(tmp_path / "geometry_calibration.json", doc)
    cal = read_geometry_calibration(path)
    assert cal.sensor_px == (640, 480)
    assert GeometryCalibration.from_snapshot(json.loads(json.dumps(cal.snapshot()))).sensor_px == (640, 480)
    bad = write_geometry_calibration(tmp_path / "bad.json", {**doc, "sensor_px": [640.5, 480]})
    with pytest.raises(CalibrationFileError, match=r"bad.json: sensor_px = \[640.5, 480\]: expected \[width, height\]"):
        read_geometry_calibration(bad)


@pytest.mark.mitsuba
def test_a_dng_image_run_bins_each_tiles_whole_colour_cells(tmp_path: Path) -> None:
    # RAW mosaics written as DNG and read back through rawpy, as a tethered camera's: a coloured material shows
    # a tile's R, G and B each from its own pixels of the mosaic, at the colour phase of the tile's place.
    colour = {"model": "Lambert", "rho_d": [0.7, 0.4, 0.15]}
    rig = sim_rig(colour, camera={"resolution": [64, 64]}, simulation={"camera_output": "dng"})
    start_run(rig, in_plane_sweep([20.0], [30.0], mode="image", tile_px=4, target_snr=50.0), tmp_path / "run",
              progress=False)  # fmt: skip
    rows = read_rows(tmp_path / "run" / "samples.csv")
    assert len(rows) >= 20
    truth, got, se = truth_and_measured(rows, rig)
    assert np.allclose(truth[0], np.array([0.7, 0.4, 0.15]) / np.pi)
    z = (got - truth) / se
    for channel in range(3):
        assert float(np.mean(np.abs(z[:, channel]) < 3)) >= 0.95, (channel, z[:, channel])
