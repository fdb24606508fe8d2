"""Frame files that are not right: missing, truncated, garbage, exposures that disagree; and TIFF and 8-bit
images (PNG, JPEG) read into frames."""

from __future__ import annotations

import io
import struct
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

from acquisition.files.dng import write_dng
from acquisition.files.images import read_frame, read_tiff
from acquisition.files.metadata import ReadOptions
from acquisition.files.raw import (
    demosaic_linear,
    read_raw,
)
from acquisition.frame import FrameError
from tests.acquisition.raw_helpers import _mosaic


def test_missing_file_names_the_path(tmp_path: Path) -> None:
    missing = tmp_path / "nope.dng"
    with pytest.raises(FileNotFoundError, match=r"nope\.dng") as info:
        read_raw(missing)
    assert info.value.filename == str(missing)
    with pytest.raises(FileNotFoundError, match=r"nope\.tif"):
        read_frame(tmp_path / "nope.tif")


@pytest.mark.parametrize("cut", [0.5, 0.99, 300, 8])
def test_truncated_dng_is_a_frame_error(tmp_path: Path, cut: float) -> None:
    good = write_dng(tmp_path / "g.dng", _mosaic((64, 96), 4095), black_level=0, white_level=4095, exposure_s=0.1)
    blob = good.read_bytes()
    bad = tmp_path / "truncated.dng"
    bad.write_bytes(blob[: int(cut * len(blob)) if cut < 1 else int(cut)])
    with pytest.raises(FrameError, match=r"truncated\.dng: cannot decode as RAW: LibRawIOError"):
        read_raw(bad)


@pytest.mark.parametrize("content", [b"", np.random.default_rng(0).bytes(5000)])
def test_garbage_raw_is_a_frame_error(tmp_path: Path, content: bytes) -> None:
    bad = tmp_path / "garbage.cr2"
    bad.write_bytes(content)
    with pytest.raises(FrameError, match=r"garbage\.cr2: cannot decode as RAW: LibRaw\w+Error: \w+"):
        read_frame(bad)


def test_directory_is_a_frame_error(tmp_path: Path) -> None:
    folder = tmp_path / "shots.dng"
    folder.mkdir()
    with pytest.raises(FrameError, match=r"shots\.dng: not a regular file"):
        read_frame(folder)


def test_exposure_disagreeing_with_the_request_is_an_error(tmp_path: Path) -> None:
    path = write_dng(tmp_path / "s.dng", _mosaic((24, 24), 4095), black_level=0, white_level=4095, exposure_s=1 / 250)
    with pytest.raises(
        FrameError, match=r"s\.dng: exposure 0\.004 s in the file disagrees with the requested 0\.008 s"
    ):
        read_raw(path, ReadOptions(expected_exposure_s=0.008))
    with pytest.raises(FrameError, match=r"requested 0\.008 s"):
        demosaic_linear(path, ReadOptions(expected_exposure_s=0.008))
    assert read_raw(path, ReadOptions(expected_exposure_s=0.00405)).exposure_s == 0.004  # within the 5 % tolerance
    with pytest.raises(FrameError, match="disagrees"):
        read_raw(path, ReadOptions(expected_exposure_s=0.00405, rtol=0.001))


def test_missing_exposure_metadata_needs_the_caller(tmp_path: Path) -> None:
    path = tmp_path / "noexp.dng"
    tags = [
        (33421, "H", 2, (2, 2), True),
        (33422, "B", 4, (0, 1, 1, 2), True),
        (50706, "B", 4, (1, 4, 0, 0), True),
        (50708, "s", 0, "no exposure", True),
        (50717, "I", 1, 4095, True),
    ]
    tifffile.imwrite(path, _mosaic((24, 24), 4095), photometric=32803, extratags=tags, metadata=None)
    with pytest.raises(FrameError, match=r"noexp\.dng: the file carries no exposure time; pass exposure_s="):
        read_raw(path)
    frame = read_raw(path, ReadOptions(exposure_s=0.25))
    assert frame.exposure_s == 0.25
    assert frame.extra["exposure_source"] == "caller"
    with pytest.raises(FrameError, match="disagrees"):
        read_raw(path, ReadOptions(exposure_s=0.25, expected_exposure_s=0.5))


def test_unsupported_extension_names_file_and_extension(tmp_path: Path) -> None:
    path = tmp_path / "frame.bmp"
    path.write_bytes(b"BM")
    with pytest.raises(FrameError, match=r"frame\.bmp: unsupported file extension '\.bmp'"):
        read_frame(path)
    with pytest.raises(FrameError, match=r"unsupported file extension '\(none\)'"):
        read_frame(tmp_path / "noext")


def test_linear_tiff_with_exif_exposure(tmp_path: Path) -> None:
    data = np.random.default_rng(1).integers(0, 65536, (20, 30, 3), dtype=np.uint16)
    path = tmp_path / "lin.tif"
    tifffile.imwrite(path, data, photometric="rgb", extratags=[(33434, "2I", 1, (1, 30), True)])
    frame = read_frame(path, ReadOptions(expected_exposure_s=1 / 30))
    assert frame.kind == "linear"
    assert np.array_equal(frame.data, data)
    assert frame.exposure_s == pytest.approx(1 / 30)
    assert frame.white_level == 65535
    assert frame.black_level == 0.0
    with pytest.raises(FrameError, match=r"lin\.tif: exposure 0\.0333333 s in the file disagrees"):
        read_frame(path, ReadOptions(expected_exposure_s=0.1))


def test_tiff_without_exposure_and_8bit_and_float(tmp_path: Path) -> None:
    mono = tmp_path / "mono16.tiff"
    tifffile.imwrite(mono, np.arange(600, dtype=np.uint16).reshape(20, 30))
    with pytest.raises(FrameError, match=r"mono16\.tiff: the file carries no exposure time"):
        read_tiff(mono)
    assert read_tiff(mono, ReadOptions(exposure_s=0.1), black_level=12).black_level == 12.0
    eight = tmp_path / "eight.tif"
    tifffile.imwrite(eight, np.zeros((20, 30, 3), np.uint8), photometric="rgb")
    assert read_frame(eight, ReadOptions(exposure_s=0.1)).kind == "8bit"
    flt = tmp_path / "float.tif"
    tifffile.imwrite(flt, np.ones((20, 30), np.float32))
    frame = read_frame(flt, ReadOptions(exposure_s=0.1))
    assert frame.kind == "linear"
    assert frame.white_level == np.inf


def test_tiff_holding_a_cfa_mosaic_is_read_as_raw(tmp_path: Path) -> None:
    mosaic = _mosaic((24, 24), 4095)
    path = write_dng(tmp_path / "mosaic.tif", mosaic, black_level=5, white_level=4095, exposure_s=0.01)
    frame = read_frame(path)
    assert frame.kind == "raw"
    assert np.array_equal(frame.data, mosaic)


def test_png_is_8bit_rgb_and_needs_an_exposure(tmp_path: Path) -> None:
    bgr = np.zeros((10, 12, 3), np.uint8)
    bgr[..., 0] = 200  # blue in OpenCV's channel order
    path = tmp_path / "shot.png"
    cv2.imwrite(str(path), bgr)
    with pytest.raises(FrameError, match=r"shot\.png: the file carries no exposure time"):
        read_frame(path)
    frame = read_frame(path, ReadOptions(exposure_s=0.02))
    assert frame.kind == "8bit"
    assert frame.white_level == 255
    assert np.all(frame.data[..., 2] == 200)
    assert np.all(frame.data[..., 0] == 0)
    assert frame.extra["exposure_source"] == "caller"


def test_jpeg_exposure_comes_from_its_exif(tmp_path: Path) -> None:
    ok, jpeg = cv2.imencode(".jpg", np.full((16, 16, 3), 128, np.uint8))
    assert ok
    exif_tiff = io.BytesIO()
    tifffile.imwrite(
        exif_tiff,
        np.zeros((1, 1), np.uint8),
        extratags=[(33434, "2I", 1, (1, 60), True), (34855, "H", 1, 200, True), (271, "s", 0, "Acme", True)],
    )
    payload = b"Exif\x00\x00" + exif_tiff.getvalue()
    app1 = b"\xff\xe1" + struct.pack(">H", len(payload) + 2) + payload
    path = tmp_path / "shot.JPG"
    path.write_bytes(jpeg.tobytes()[:2] + app1 + jpeg.tobytes()[2:])
    frame = read_frame(path)
    assert frame.kind == "8bit"
    assert frame.exposure_s == pytest.approx(1 / 60)
    assert frame.gain == 2.0
    assert frame.camera_id == "Acme"


def test_corrupt_png_is_a_frame_error(tmp_path: Path) -> None:
    path = tmp_path / "broken.png"
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 20)
    with pytest.raises(FrameError, match=r"broken\.png: OpenCV cannot decode"):
        read_frame(path, ReadOptions(exposure_s=0.1))


def test_16bit_png_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "deep.png"
    cv2.imwrite(str(path), np.zeros((8, 8), np.uint16))
    with pytest.raises(FrameError, match=r"deep\.png: uint16 image"):
        read_frame(path, ReadOptions(exposure_s=0.1))
