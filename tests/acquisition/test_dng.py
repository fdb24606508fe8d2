"""The DNG writer read back through rawpy (LibRaw): bit-exact mosaics, black levels per CFA position,
exposure and ISO metadata, atomic writes and refused input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rawpy
import tifffile

from acquisition.files.dng import MIN_DNG_SIDE, write_dng
from acquisition.files.raw import (
    read_raw,
)
from acquisition.frame import Frame
from tests.acquisition.raw_helpers import PATTERNS, _mosaic


@pytest.mark.parametrize("pattern", PATTERNS)
@pytest.mark.parametrize("white", [4095, 65535])
@pytest.mark.parametrize("shape", [(MIN_DNG_SIDE, MIN_DNG_SIDE), (64, 96), (101, 150)])
def test_dng_round_trip_is_bit_exact(tmp_path: Path, pattern: str, white: int, shape: tuple[int, int]) -> None:
    mosaic = _mosaic(shape, white, seed=shape[0] + white)
    blacks = (60, 61, 62, 63) if white == 4095 else (1000, 1010, 1020, 1030)
    path = write_dng(
        tmp_path / "shot.dng",
        mosaic,
        cfa_pattern=pattern,
        black_level=blacks,
        white_level=white,
        exposure_s=1 / 250,
        iso=400,
        camera_id="gonio sim",
    )
    frame = read_raw(path)
    assert frame.kind == "raw"
    assert frame.data.dtype == np.uint16
    assert np.array_equal(frame.data, mosaic)
    assert frame.cfa_pattern == pattern
    assert frame.black_level == tuple(float(b) for b in blacks)
    assert frame.white_level == white
    assert frame.exposure_s == 1 / 250
    assert frame.gain == 4.0
    assert frame.camera_id == "gonio sim"
    assert frame.source == str(path)
    assert frame.extra["exposure_source"] == "metadata"


def test_dng_black_levels_reach_libraw_per_cfa_position(tmp_path: Path) -> None:
    path = write_dng(
        tmp_path / "b.dng", _mosaic((32, 32), 4095), black_level=(10, 20, 30, 40), white_level=4095, exposure_s=0.01
    )
    with rawpy.imread(str(path)) as raw:
        pattern = raw.raw_pattern
        per_channel = raw.black_level_per_channel
    # position (i, j) of the 2x2 cell has colour index pattern[i, j]; LibRaw reports black per colour index
    assert [per_channel[int(pattern[i, j])] for i in range(2) for j in range(2)] == [10, 20, 30, 40]


@pytest.mark.parametrize("exposure", [1e-6, 1 / 8000, 1 / 3, 0.00435, 2.5, 120.0, 3600.0])
def test_dng_exposure_extremes_round_trip(tmp_path: Path, exposure: float) -> None:
    path = write_dng(tmp_path / "e.dng", _mosaic((24, 24), 4095), black_level=0, white_level=4095, exposure_s=exposure)
    frame = read_raw(path)
    assert frame.exposure_s == pytest.approx(exposure, rel=1e-9)
    with rawpy.imread(str(path)) as raw:  # LibRaw itself finds it (float32)
        assert raw.other.shutter_speed == pytest.approx(exposure, rel=1e-6)
        assert raw.other.iso_speed == 0  # no ISO given: none written
    assert frame.gain == 1.0


def test_dng_iso_is_in_the_exif_ifd_where_libraw_reads_it(tmp_path: Path) -> None:
    path = write_dng(
        tmp_path / "i.dng", _mosaic((24, 24), 4095), black_level=0, white_level=4095, exposure_s=0.01, iso=800
    )
    with rawpy.imread(str(path)) as raw:
        assert raw.other.iso_speed == 800
    with tifffile.TiffFile(path) as tif:
        tags = tif.pages.first.tags
        assert tags.valueof("ExifTag") == {"ExposureTime": (1, 100), "ISOSpeedRatings": 800, "ExifVersion": "0230"}
        assert tags.valueof(33434) == (1, 100)
        assert tags.valueof("PhotometricInterpretation") == 32803
        assert tags.valueof("DNGVersion") == b"\x01\x04\x00\x00"
        assert tags.valueof("BitsPerSample") == 16
        assert tags.valueof("Compression") == 1


def test_dng_from_a_frame_round_trips_the_frame(tmp_path: Path) -> None:
    frame = Frame(
        data=_mosaic((40, 60), 16383),
        kind="raw",
        exposure_s=0.02,
        gain=2.0,
        black_level=(512.0, 512.0, 512.0, 512.0),
        white_level=16383.0,
        cfa_pattern="GBRG",
        camera_id="simulated camera",
    )
    back = read_raw(write_dng(tmp_path / "f.dng", frame))
    assert np.array_equal(back.data, frame.data)
    for key in ("kind", "exposure_s", "gain", "black_level", "white_level", "cfa_pattern", "camera_id"):
        assert getattr(back, key) == getattr(frame, key), key


def test_dng_write_is_atomic_and_replaces(tmp_path: Path) -> None:
    first = write_dng(tmp_path / "a.dng", _mosaic((24, 24), 4095, 1), black_level=0, white_level=4095, exposure_s=0.1)
    second = _mosaic((24, 24), 4095, 2)
    write_dng(first, second, black_level=0, white_level=4095, exposure_s=0.2)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.dng"]
    assert np.array_equal(read_raw(first).data, second)
    with pytest.raises(ValueError, match="too small"):
        write_dng(tmp_path / "b.dng", np.zeros((8, 8), np.uint16), black_level=0, white_level=4095, exposure_s=0.1)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.dng"]


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"data": np.zeros((21, 40), np.uint16)}, "too small"),
        ({"data": np.zeros((24, 24, 3), np.uint16)}, "2-D"),
        ({"data": np.full((24, 24), 0.5)}, "fractional"),
        ({"data": np.full((24, 24), 70000)}, "0..65535"),
        ({"cfa_pattern": "RRGB"}, "Bayer"),
        ({"cfa_pattern": "RGB"}, "Bayer"),
        ({"black_level": 4095}, "not below white"),
        ({"black_level": (1, 2, 3)}, "1 or 4"),
        ({"black_level": 1.5}, "whole number"),
        ({"white_level": 70000}, "whole number"),
        ({"exposure_s": 0.0}, "positive"),
        ({"exposure_s": None}, "exposure_s required"),
        ({"iso": 0}, "iso"),
    ],
)
def test_dng_refuses_bad_input(tmp_path: Path, kwargs: dict, message: str) -> None:
    args: dict = {"black_level": 0, "white_level": 4095, "exposure_s": 0.01, "cfa_pattern": "RGGB"}
    data = kwargs.pop("data", np.zeros((24, 24), np.uint16))
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        write_dng(tmp_path / "x.dng", data, **args)
    assert list(tmp_path.iterdir()) == []


def test_dng_refuses_non_raw_frames(tmp_path: Path) -> None:
    frame = Frame(data=np.zeros((24, 24, 3), np.uint8), kind="8bit", exposure_s=0.1, white_level=255)
    with pytest.raises(ValueError, match="'8bit', not raw"):
        write_dng(tmp_path / "x.dng", frame)
