"""RAW decoding, the DNG writer and the file readers, against real rawpy/LibRaw, tifffile and OpenCV."""

from __future__ import annotations

import io
import struct
from pathlib import Path

import cv2
import numpy as np
import pytest
import rawpy
import tifffile

from acquisition.files.dng import MIN_DNG_SIDE, write_dng
from acquisition.files.images import read_frame, read_tiff
from acquisition.files.raw import (
    LINEAR_POSTPROCESS,
    bin_bayer,
    cfa_pattern_string,
    demosaic_linear,
    read_raw,
)
from acquisition.frame import Frame, FrameError

KODAK = Path("/work/shared/data/raw/kodak_dc50.kdc")
PATTERNS = ["RGGB", "BGGR", "GRBG", "GBRG"]


def _mosaic(shape: tuple[int, int], white: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, white + 1, shape, dtype=np.uint16)


def _smooth_signal(shape: tuple[int, int], peak: float, seed: int = 0) -> np.ndarray:
    """A smooth positive scene with some noise, in counts above black."""
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    scene = 1 + np.sin(xx / 7.0) * np.cos(yy / 5.0)
    noisy = scene + np.random.default_rng(seed).normal(0, 0.02, shape)
    return np.floor(np.clip(noisy, 0.05, None) / 2.1 * peak)


# ---------------------------------------------------------------------------- DNG round trip


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


# ---------------------------------------------------------------------------- the real Kodak RAW


def test_kodak_dc50_decodes_as_rawpy_reports_it() -> None:
    frame = read_raw(KODAK)
    assert frame.kind == "raw"
    assert frame.shape == (512, 768)
    assert frame.data.dtype == np.uint16
    assert frame.white_level == 16383
    assert frame.black_level == (0.0, 0.0, 0.0, 0.0)
    # LibRaw: raw_pattern [[1, 0], [2, 3]] with colour description "RGBG"
    assert frame.cfa_pattern == "GRBG"
    assert frame.exposure_s == 0.00435  # EXIF 435/100000; LibRaw's float32 is 0.0043500000611
    assert frame.gain == pytest.approx(0.84)  # ISO 84
    assert frame.camera_id == "Kodak Digital Science DC50 Zoom Camera"
    assert frame.extra["datetime"] == "1997-04-23T08:00:47"
    assert int(frame.data.min()) == 23
    assert int(frame.data.max()) == 16383
    with rawpy.imread(str(KODAK)) as raw:
        assert np.array_equal(frame.data, raw.raw_image_visible)
        assert raw.other.shutter_speed == pytest.approx(0.00435, rel=1e-6)


def test_kodak_binned_and_demosaiced() -> None:
    frame = read_raw(KODAK)
    binned = bin_bayer(frame)
    assert binned.shape == (256, 384, 3)
    g = frame.data.astype(float)
    assert binned[0, 0, 0] == g[0, 1]  # GRBG: R at (0, 1)
    assert binned[0, 0, 1] == (g[0, 0] + g[1, 1]) / 2
    assert binned[0, 0, 2] == g[1, 0]
    rgb = demosaic_linear(KODAK, expected_exposure_s=0.00435)
    assert rgb.kind == "linear"
    assert rgb.shape == (512, 768, 3)
    assert rgb.data.dtype == np.uint16
    assert rgb.exposure_s == 0.00435
    assert rgb.extra["counts_per_output"] == pytest.approx(16383 / 65535)


# ---------------------------------------------------------------------------- bin_bayer


@pytest.mark.parametrize("pattern", PATTERNS)
def test_bin_bayer_takes_r_mean_g_b_above_black(pattern: str) -> None:
    values = {"R": 1000.0, "G1": 2000.0, "G2": 2100.0, "B": 3000.0}
    blacks = (100.0, 110.0, 120.0, 130.0)
    cell = np.zeros((2, 2))
    greens = iter(("G1", "G2"))
    for i, c in enumerate(pattern):
        cell[i // 2, i % 2] = (values[next(greens)] if c == "G" else values[c]) + blacks[i]
    mosaic = np.tile(cell, (5, 7)).astype(np.uint16)
    mosaic = np.pad(mosaic, ((0, 1), (0, 1)))  # odd trailing row and column are dropped
    frame = Frame(data=mosaic, kind="raw", exposure_s=1.0, black_level=blacks, white_level=4095, cfa_pattern=pattern)
    out = bin_bayer(frame)
    assert out.shape == (5, 7, 3)
    assert out.dtype == np.float64
    assert np.all(out[..., 0] == 1000.0)
    assert np.all(out[..., 1] == 2050.0)
    assert np.all(out[..., 2] == 3000.0)


def test_bin_bayer_keeps_negative_values_and_scalar_black() -> None:
    frame = Frame(
        data=np.full((4, 4), 98, np.uint16), kind="raw", exposure_s=1.0, black_level=100.0, cfa_pattern="RGGB"
    )
    assert np.all(bin_bayer(frame) == -2.0)


def test_bin_bayer_refuses_non_mosaics() -> None:
    frame = Frame(data=np.zeros((4, 4, 3)), kind="linear", exposure_s=1.0)
    with pytest.raises(FrameError, match="needs a raw CFA mosaic"):
        bin_bayer(frame)


# ---------------------------------------------------------------------------- postprocess linearity


def _postprocess(path: Path, **overrides: object) -> np.ndarray:
    params = {**LINEAR_POSTPROCESS, "demosaic_algorithm": rawpy.DemosaicAlgorithm.LINEAR, **overrides}
    with rawpy.imread(str(path)) as raw:
        return raw.postprocess(**params).astype(np.float64)


def test_demosaic_linear_doubles_when_the_signal_doubles(tmp_path: Path) -> None:
    black, white = 64, 16383
    signal = _smooth_signal((128, 160), peak=7000)
    one = write_dng(tmp_path / "one.dng", black + signal, black_level=black, white_level=white, exposure_s=0.01)
    two = write_dng(tmp_path / "two.dng", black + 2 * signal, black_level=black, white_level=white, exposure_s=0.02)
    out1, out2 = demosaic_linear(one), demosaic_linear(two)
    assert out1.exposure_s == 0.01
    assert out2.exposure_s == 0.02
    diff = out2.data.astype(float) - 2 * out1.data.astype(float)
    assert np.abs(diff).max() <= 2.0  # two output quanta: each output is rounded once
    # the output is counts above black times 65535 / (white - black)
    scale = out1.extra["counts_per_output"]
    assert scale == pytest.approx((white - black) / 65535)
    binned = bin_bayer(read_raw(one))
    half = demosaic_linear(one, half_size=True)
    assert half.shape == binned.shape
    assert np.abs(half.data[..., 0] * scale - binned[..., 0]).max() <= scale  # one output quantum


def test_adjust_maximum_thr_zero_matters(tmp_path: Path) -> None:
    black, white = 64, 16383
    signal = _smooth_signal((64, 64), peak=0.8 * (white - black))
    assert 0.75 < signal.max() / (white - black) < 0.85  # brightest pixel near 80 % of the range
    path = write_dng(tmp_path / "m.dng", black + signal, black_level=black, white_level=white, exposure_s=0.01)
    ours = _postprocess(path)
    libraw_default = _postprocess(path, adjust_maximum_thr=0.75)
    # LibRaw's default takes the brightest pixel as the white level: a silent rescale
    expected = (white - black) / signal.max()
    assert libraw_default.mean() / ours.mean() == pytest.approx(expected, rel=0.01)
    assert ours.mean() * (white - black) / 65535 == pytest.approx(signal.mean(), rel=0.01)


def test_demosaic_linear_accepts_an_open_rawpy(tmp_path: Path) -> None:
    path = write_dng(tmp_path / "o.dng", _mosaic((32, 32), 4095), black_level=0, white_level=4095, exposure_s=0.5)
    with rawpy.imread(str(path)) as raw:
        frame = demosaic_linear(raw)
    assert frame.shape == (32, 32, 3)
    assert frame.exposure_s == pytest.approx(0.5)
    assert frame.source is None


# ---------------------------------------------------------------------------- non-Bayer RAW


def _patch_photometric(path: Path, value: int) -> None:
    data = bytearray(path.read_bytes())
    ifd = struct.unpack("<I", data[4:8])[0]
    (count,) = struct.unpack("<H", data[ifd : ifd + 2])
    for i in range(count):
        entry = ifd + 2 + 12 * i
        if struct.unpack("<H", data[entry : entry + 2])[0] == 262:
            data[entry + 8 : entry + 10] = struct.pack("<H", value)
    path.write_bytes(bytes(data))


def _linear_raw_dng(path: Path, data: np.ndarray, black: int) -> Path:
    """A LinearRaw (34892) DNG; tifffile refuses one-sample LinearRaw, so mono files get patched."""
    tags = [
        (33434, "2I", 1, (1, 100), True),
        (50706, "B", 4, (1, 4, 0, 0), True),
        (50708, "s", 0, "mono test", True),
        (50714, "I", 1, black, True),
        (50717, "I", 1, 4095, True),
    ]
    photometric = 34892 if data.ndim == 3 else 1
    tifffile.imwrite(path, data, photometric=photometric, extratags=tags, metadata=None, software="gonio")
    if data.ndim == 2:
        _patch_photometric(path, 34892)
    return path


def test_monochrome_raw_is_a_linear_plane(tmp_path: Path) -> None:
    data = _mosaic((32, 40), 4095)
    frame = read_raw(_linear_raw_dng(tmp_path / "mono.dng", data, black=50))
    assert frame.kind == "linear"
    assert frame.cfa_pattern is None
    assert np.array_equal(frame.data, data)
    assert frame.black_level == 50.0
    assert frame.exposure_s == 0.01


def test_linear_raw_rgb_is_a_linear_image(tmp_path: Path) -> None:
    data = np.random.default_rng(3).integers(0, 4096, (32, 40, 3), dtype=np.uint16)
    frame = read_raw(_linear_raw_dng(tmp_path / "rgb.dng", data, black=7))
    assert frame.kind == "linear"
    assert frame.shape == (32, 40, 3)
    assert np.array_equal(frame.data, data)
    assert frame.black_level == (7.0, 7.0, 7.0)


def test_cfa_pattern_string_refuses_non_bayer() -> None:
    assert cfa_pattern_string([[0, 1], [3, 2]], b"RGBG") == "RGGB"
    with pytest.raises(FrameError, match="X-Trans"):
        cfa_pattern_string(np.zeros((6, 6), int), b"RGBG", "x.raf")
    with pytest.raises(FrameError, match="not a Bayer"):
        cfa_pattern_string([[0, 1], [2, 3]], b"GMCY", "x.crw")


# ---------------------------------------------------------------------------- bad input


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
        read_raw(path, expected_exposure_s=0.008)
    with pytest.raises(FrameError, match=r"requested 0\.008 s"):
        demosaic_linear(path, expected_exposure_s=0.008)
    assert read_raw(path, expected_exposure_s=0.00405).exposure_s == 0.004  # within the 5 % tolerance
    with pytest.raises(FrameError, match="disagrees"):
        read_raw(path, expected_exposure_s=0.00405, rtol=0.001)


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
    frame = read_raw(path, exposure_s=0.25)
    assert frame.exposure_s == 0.25
    assert frame.extra["exposure_source"] == "caller"
    with pytest.raises(FrameError, match="disagrees"):
        read_raw(path, exposure_s=0.25, expected_exposure_s=0.5)


def test_unsupported_extension_names_file_and_extension(tmp_path: Path) -> None:
    path = tmp_path / "frame.bmp"
    path.write_bytes(b"BM")
    with pytest.raises(FrameError, match=r"frame\.bmp: unsupported file extension '\.bmp'"):
        read_frame(path)
    with pytest.raises(FrameError, match=r"unsupported file extension '\(none\)'"):
        read_frame(tmp_path / "noext")


# ---------------------------------------------------------------------------- TIFF and 8-bit files


def test_linear_tiff_with_exif_exposure(tmp_path: Path) -> None:
    data = np.random.default_rng(1).integers(0, 65536, (20, 30, 3), dtype=np.uint16)
    path = tmp_path / "lin.tif"
    tifffile.imwrite(path, data, photometric="rgb", extratags=[(33434, "2I", 1, (1, 30), True)])
    frame = read_frame(path, expected_exposure_s=1 / 30)
    assert frame.kind == "linear"
    assert np.array_equal(frame.data, data)
    assert frame.exposure_s == pytest.approx(1 / 30)
    assert frame.white_level == 65535
    assert frame.black_level == 0.0
    with pytest.raises(FrameError, match=r"lin\.tif: exposure 0\.0333333 s in the file disagrees"):
        read_frame(path, expected_exposure_s=0.1)


def test_tiff_without_exposure_and_8bit_and_float(tmp_path: Path) -> None:
    mono = tmp_path / "mono16.tiff"
    tifffile.imwrite(mono, np.arange(600, dtype=np.uint16).reshape(20, 30))
    with pytest.raises(FrameError, match=r"mono16\.tiff: the file carries no exposure time"):
        read_tiff(mono)
    assert read_tiff(mono, exposure_s=0.1, black_level=12).black_level == 12.0
    eight = tmp_path / "eight.tif"
    tifffile.imwrite(eight, np.zeros((20, 30, 3), np.uint8), photometric="rgb")
    assert read_frame(eight, exposure_s=0.1).kind == "8bit"
    flt = tmp_path / "float.tif"
    tifffile.imwrite(flt, np.ones((20, 30), np.float32))
    frame = read_frame(flt, exposure_s=0.1)
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
    frame = read_frame(path, exposure_s=0.02)
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
        read_frame(path, exposure_s=0.1)


def test_16bit_png_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "deep.png"
    cv2.imwrite(str(path), np.zeros((8, 8), np.uint16))
    with pytest.raises(FrameError, match=r"deep\.png: uint16 image"):
        read_frame(path, exposure_s=0.1)
