"""Camera backends: the tethered folder driven by a writer on a manual clock, OpenCV on image sequences,
and the optional backends' missing-library errors and pure helpers."""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

from acquisition.cameras import BackendNotInstalledError, CameraError, ClockLike, ExposureUnconfirmedError
from acquisition.cameras.genicam import GenICamCamera, parse_pixel_format
from acquisition.cameras.gphoto2 import GPhoto2Camera, nearest_choice, parse_iso, parse_shutter_speed
from acquisition.cameras.opencv import EXPOSURE_MAPPINGS, OpenCVCamera
from acquisition.cameras.tethered import TetheredFolderCamera
from acquisition.files.dng import write_dng
from acquisition.frame import Camera, ExposureSettings, FrameError
from rig.instrument.clock import ManualClock, SystemClock


class PollClock(ManualClock):
    """Manual time whose n-th sleep (1-based) runs the actions scheduled for it: the file writer."""

    def __init__(self) -> None:
        super().__init__()
        self.sleeps = 0
        self.actions: dict[int, list[Callable[[], None]]] = {}

    def at(self, sleep_number: int, action: Callable[[], None]) -> None:
        self.actions.setdefault(sleep_number, []).append(action)

    def sleep(self, seconds: float) -> None:
        super().sleep(seconds)
        self.sleeps += 1
        for action in self.actions.pop(self.sleeps, []):
            action()


def _mosaic(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 4096, (24, 32), dtype=np.uint16)


def _dng(path: Path, exposure_s: float = 1 / 250, seed: int = 0, iso: float | None = 100) -> Path:
    return write_dng(
        path, _mosaic(seed), black_level=64, white_level=4095, exposure_s=exposure_s, iso=iso, camera_id="Acme R1"
    )


def test_rig_clocks_are_clocklike() -> None:
    assert isinstance(ManualClock(), ClockLike)
    assert isinstance(SystemClock(), ClockLike)


# ---------------------------------------------------------------------------- tethered folder


def test_tethered_returns_the_next_new_file(tmp_path: Path) -> None:
    _dng(tmp_path / "old.dng", seed=9)  # present before: ignored
    clock = PollClock()
    cam = TetheredFolderCamera(tmp_path, clock=clock, poll_interval_s=0.1, timeout_s=5)
    assert isinstance(cam, Camera)
    assert cam.set_exposure(1 / 250, gain=1.0) == ExposureSettings(1 / 250, 1.0)
    clock.at(3, lambda: _dng(tmp_path / "IMG_0001.dng", seed=1))
    frame = cam.capture()
    assert np.array_equal(frame.data, _mosaic(1))
    assert frame.source == str(tmp_path / "IMG_0001.dng")
    assert frame.exposure_s == 1 / 250
    assert frame.extra["requested_exposure_s"] == 1 / 250
    # found on the poll after the 3rd sleep, complete after one more (size stable on two polls)
    assert clock.sleeps == 4
    assert frame.timestamp_s == pytest.approx(0.4)
    assert cam.identity == "Acme R1"
    assert frame.camera_id == "Acme R1"
    # The shot was fired when capture() was called, long before its file was found: a scan's exposure time.
    clock.advance(2.0)

    def shoot() -> None:
        _dng(tmp_path / "IMG_0002.dng", seed=2)

    clock.at(6, shoot)
    assert cam.capture().extra["triggered_s"] == pytest.approx(2.4) and clock.now() == pytest.approx(2.7)


def test_tethered_delivers_files_in_order_of_arrival(tmp_path: Path) -> None:
    clock = PollClock()
    cam = TetheredFolderCamera(tmp_path, clock=clock, poll_interval_s=0.1, stable_polls=1)
    cam.set_exposure(0.01)

    def two_shots() -> None:
        # names sort the other way round; modification times say which came first
        os.utime(_dng(tmp_path / "b_first.dng", exposure_s=0.01, seed=1), ns=(1_000_000_000, 1_000_000_000))
        os.utime(_dng(tmp_path / "a_second.dng", exposure_s=0.01, seed=2), ns=(2_000_000_000, 2_000_000_000))

    clock.at(1, two_shots)
    assert np.array_equal(cam.capture().data, _mosaic(1))
    assert np.array_equal(cam.capture().data, _mosaic(2))
    assert clock.sleeps == 1


def test_tethered_waits_for_a_file_still_being_written(tmp_path: Path) -> None:
    hot = tmp_path / "hot"
    hot.mkdir()
    blob = _dng(tmp_path / "full.dng", seed=5).read_bytes()
    target = hot / "slow.dng"
    clock = PollClock()
    cam = TetheredFolderCamera(hot, clock=clock, poll_interval_s=0.1, stable_polls=2, settle_s=1.0)
    cam.set_exposure(1 / 250)
    clock.at(2, lambda: target.write_bytes(blob[: len(blob) // 2]))  # writer stalls half way
    clock.at(6, lambda: target.write_bytes(blob))  # and finishes later
    frame = cam.capture()
    assert np.array_equal(frame.data, _mosaic(5))
    assert clock.sleeps == 7  # complete file seen after sleeps 6 and 7


def test_tethered_timeout_names_folder_and_wait(tmp_path: Path) -> None:
    clock = PollClock()
    cam = TetheredFolderCamera(tmp_path, clock=clock, poll_interval_s=0.25, timeout_s=3.0)
    cam.set_exposure(0.01)
    with pytest.raises(TimeoutError, match=rf"no new complete file matching .* in {tmp_path} after waiting 3 s"):
        cam.capture()
    assert clock.now() == pytest.approx(3.0)


def test_tethered_exposure_mismatch_names_file_and_both_values(tmp_path: Path) -> None:
    clock = PollClock()
    cam = TetheredFolderCamera(tmp_path, clock=clock, stable_polls=1)
    cam.set_exposure(0.01)
    clock.at(1, lambda: _dng(tmp_path / "wrong.dng", exposure_s=1 / 250))
    with pytest.raises(
        FrameError, match=r"wrong\.dng: exposure 0\.004 s in the file disagrees with the requested 0\.01 s"
    ):
        cam.capture()
    # the bad file is consumed: the next capture waits for a new one
    clock.at(clock.sleeps + 1, lambda: _dng(tmp_path / "right.dng", exposure_s=0.01, seed=3))
    assert np.array_equal(cam.capture().data, _mosaic(3))


def test_tethered_gain_mismatch(tmp_path: Path) -> None:
    clock = PollClock()
    cam = TetheredFolderCamera(tmp_path, clock=clock, stable_polls=1)
    cam.set_exposure(1 / 250, gain=4.0)
    clock.at(1, lambda: _dng(tmp_path / "iso100.dng", iso=100))
    with pytest.raises(
        FrameError, match=r"iso100\.dng: gain 1 \(ISO 100\) in the file disagrees with the requested gain 4"
    ):
        cam.capture()


def test_tethered_corrupt_file_is_reported_once_it_settles(tmp_path: Path) -> None:
    clock = PollClock()
    cam = TetheredFolderCamera(tmp_path, clock=clock, poll_interval_s=0.1, settle_s=0.5, timeout_s=10)
    cam.set_exposure(0.01)
    clock.at(1, lambda: (tmp_path / "junk.dng").write_bytes(np.random.default_rng(0).bytes(4000)))
    with pytest.raises(FrameError, match=r"junk\.dng: cannot decode as RAW"):
        cam.capture()
    assert clock.now() < 1.0


def test_tethered_trigger_shoots_with_the_requested_settings(tmp_path: Path) -> None:
    clock = PollClock()
    requests: list[ExposureSettings] = []

    def trigger(settings: ExposureSettings) -> None:
        requests.append(settings)
        _dng(tmp_path / f"shot{len(requests)}.dng", exposure_s=settings.exposure_s, seed=len(requests))

    cam = TetheredFolderCamera(tmp_path, clock=clock, trigger=trigger, stable_polls=1)
    with pytest.raises(CameraError, match="call set_exposure"):
        cam.capture()
    for t in (0.001, 0.004, 0.016):
        cam.set_exposure(t)
        assert cam.capture().exposure_s == pytest.approx(t)
    assert [r.exposure_s for r in requests] == [0.001, 0.004, 0.016]
    assert clock.sleeps == 0  # each file was there at the first look


def test_tethered_tiff_without_exposure(tmp_path: Path) -> None:
    clock = PollClock()
    cam = TetheredFolderCamera(tmp_path, clock=clock, stable_polls=1, settle_s=0)
    cam.set_exposure(0.05)
    clock.at(1, lambda: tifffile.imwrite(tmp_path / "a.TIF", np.zeros((8, 8), np.uint16)))
    with pytest.raises(FrameError, match=r"a\.TIF: the file has no exposure time, so the requested 0\.05 s cannot"):
        cam.capture()
    lenient = TetheredFolderCamera(tmp_path, clock=clock, stable_polls=1, accept_unconfirmed_exposure=True)
    lenient.set_exposure(0.05)
    clock.at(clock.sleeps + 1, lambda: tifffile.imwrite(tmp_path / "b.tiff", np.ones((8, 8), np.uint16)))
    frame = lenient.capture()
    assert frame.exposure_s == 0.05
    assert frame.extra["exposure_source"] == "caller"
    assert frame.camera_id == f"tethered camera at {tmp_path}"


def test_tethered_ignores_other_and_hidden_files(tmp_path: Path) -> None:
    clock = PollClock()
    cam = TetheredFolderCamera(tmp_path, clock=clock, stable_polls=1)
    cam.set_exposure(1 / 250)
    clock.at(1, lambda: (tmp_path / "preview.jpg").write_bytes(b"not a frame"))
    clock.at(1, lambda: (tmp_path / ".IMG_2.dng.part").write_bytes(b"partial"))
    clock.at(2, lambda: _dng(tmp_path / "IMG_2.DNG", seed=2))
    assert np.array_equal(cam.capture().data, _mosaic(2))


def test_tethered_discard_pending(tmp_path: Path) -> None:
    cam = TetheredFolderCamera(tmp_path, clock=PollClock(), stable_polls=1, timeout_s=0.5)
    _dng(tmp_path / "stray.dng")
    assert [p.name for p in cam.discard_pending()] == ["stray.dng"]
    cam.set_exposure(1 / 250)
    with pytest.raises(TimeoutError):
        cam.capture()


def test_tethered_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="nowhere"):
        TetheredFolderCamera(tmp_path / "nowhere")


def test_tethered_closed(tmp_path: Path) -> None:
    cam = TetheredFolderCamera(tmp_path, clock=PollClock())
    cam.close()
    with pytest.raises(CameraError, match="closed"):
        cam.capture()


# ---------------------------------------------------------------------------- OpenCV


@pytest.fixture
def sequence(tmp_path: Path) -> str:
    """Ten PNG frames; frame k is uniformly 10k (in B), 10k + 1 (G), 10k + 2 (R)."""
    for k in range(10):
        bgr = np.empty((12, 16, 3), np.uint8)
        bgr[...] = (10 * k, 10 * k + 1, 10 * k + 2)
        cv2.imwrite(str(tmp_path / f"frame_{k:03d}.png"), bgr)
    return str(tmp_path / "frame_%03d.png")


def test_opencv_reads_an_image_sequence_and_discards_stale_frames(sequence: str) -> None:
    clock = ManualClock(5.0)
    cam = OpenCVCamera(sequence, cv2.CAP_IMAGES, discard_frames=3, clock=clock)
    assert isinstance(cam, Camera)
    assert cam.backend_name == "CV_IMAGES"
    with pytest.raises(CameraError, match="call set_exposure"):
        cam.capture()
    assert cam.set_exposure(0.01) == ExposureSettings(0.01, 1.0)
    assert not cam.exposure_confirmed
    frame = cam.capture()  # frames 0..2 predate the setting
    assert cam.frames_read == 4
    assert frame.kind == "8bit"
    assert frame.shape == (12, 16, 3)
    assert tuple(frame.data[0, 0]) == (32, 31, 30)  # RGB order
    assert frame.extra["frame_index"] == 3
    assert frame.extra["exposure_confirmed"] is False
    assert frame.exposure_s == 0.01
    assert frame.timestamp_s == 5.0
    assert cam.capture().extra["frame_index"] == 4  # no setting change: nothing discarded
    cam.set_exposure(0.02)
    frame = cam.capture()
    assert frame.extra["frame_index"] == 8
    assert frame.exposure_s == 0.02
    assert cam.frames_read == 9
    cam.capture()
    with pytest.raises(CameraError, match="end of the file/sequence"):
        cam.capture()
    cam.close()


def test_opencv_strict_refuses_unconfirmable_exposure(sequence: str) -> None:
    with OpenCVCamera(sequence, cv2.CAP_IMAGES, strict=True) as cam:
        with pytest.raises(ExposureUnconfirmedError, match="backend CV_IMAGES has no known exposure control"):
            cam.set_exposure(0.01)


def test_opencv_device_that_does_not_open(tmp_path: Path) -> None:
    pattern = str(tmp_path / "missing_%03d.png")
    with pytest.raises(CameraError, match=r"cannot open camera '.*missing_%03d\.png' with backend CAP_IMAGES"):
        OpenCVCamera(pattern, cv2.CAP_IMAGES)
    with pytest.raises(CameraError, match=r"nothing\.avi' \(no such file\)"):
        OpenCVCamera(tmp_path / "nothing.avi")
    with pytest.raises(CameraError, match="cannot open camera 57 with backend CAP_V4L2"):
        OpenCVCamera(57, cv2.CAP_V4L2)


def test_opencv_exposure_units_per_backend() -> None:
    v4l2 = EXPOSURE_MAPPINGS["V4L2"]
    assert v4l2.manual_value == 1.0
    assert v4l2.to_driver(0.01) == 100  # 100 us steps
    assert v4l2.from_driver(100) == pytest.approx(0.01)
    assert v4l2.from_driver(0) is None
    dshow = EXPOSURE_MAPPINGS["DSHOW"]
    assert dshow.manual_value == 0.25
    assert dshow.to_driver(1 / 64) == -6  # log2 seconds
    assert dshow.from_driver(-6) == 1 / 64


# ---------------------------------------------------------------------------- optional backends


def test_gphoto2_missing_library_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "gphoto2", None)
    with pytest.raises(BackendNotInstalledError, match=r"pip install 'gonio\[gphoto2\]'") as info:
        GPhoto2Camera()
    assert isinstance(info.value, ImportError)
    assert info.value.name == "gphoto2"


def test_genicam_missing_library_names_the_extra(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setitem(sys.modules, "harvesters", None)
    monkeypatch.setitem(sys.modules, "harvesters.core", None)
    with pytest.raises(ImportError, match=r"pip install 'gonio\[genicam\]'"):
        GenICamCamera(tmp_path / "producer.cti")


@pytest.mark.parametrize(
    ("text", "seconds"),
    [("1/250", 0.004), ("1/8000", 1 / 8000), ("1/3", 1 / 3), ("0.5", 0.5), ("2.5", 2.5), ("30", 30.0),
     ("30s", 30.0), ('2"', 2.0), ("0,8", 0.8), (" 1/60 ", 1 / 60)],
)  # fmt: skip
def test_parse_shutter_speed(text: str, seconds: float) -> None:
    assert parse_shutter_speed(text) == pytest.approx(seconds)


@pytest.mark.parametrize("text", ["bulb", "Bulb", "auto", "", "x 1/200", "1/0", "0", "time"])
def test_parse_shutter_speed_refuses_non_times(text: str) -> None:
    with pytest.raises(ValueError, match="shutter speed"):
        parse_shutter_speed(text)


def test_nearest_choice_is_nearest_in_stops() -> None:
    choices = ["bulb", "1/250", "1/200", "1/160", "30"]
    assert nearest_choice(0.0045, choices) == ("1/200", 0.005)
    assert nearest_choice(100.0, choices) == ("30", 30.0)
    assert nearest_choice(250.0, ["Auto", "100", "ISO 200", "400"], parse_iso) == ("ISO 200", 200.0)
    with pytest.raises(ValueError, match="no usable choice"):
        nearest_choice(0.01, ["bulb", "auto"])


def test_parse_pixel_format() -> None:
    assert parse_pixel_format("BayerRG12") == ("raw", "RGGB", 12)
    assert parse_pixel_format("BayerGR8") == ("raw", "GRBG", 8)
    assert parse_pixel_format("BayerGB16") == ("raw", "GBRG", 16)
    assert parse_pixel_format("BayerBG10") == ("raw", "BGGR", 10)
    assert parse_pixel_format("Mono12") == ("linear", None, 12)
    assert parse_pixel_format("RGB8") == ("8bit", None, 8)
    with pytest.raises(ValueError, match="BayerRG12p"):
        parse_pixel_format("BayerRG12p")
