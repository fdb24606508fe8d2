"""RAW decoding through rawpy: the real Kodak DC50 file, Bayer binning, linear demosaicing and non-Bayer RAW."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rawpy

from acquisition.files.dng import write_dng
from acquisition.files.metadata import ReadOptions
from acquisition.files.raw import (
    bin_bayer,
    cfa_pattern_string,
    demosaic_linear,
    read_raw,
)
from acquisition.frame import Frame, FrameError
from tests.acquisition.raw_helpers import KODAK, PATTERNS, _linear_raw_dng, _mosaic, _postprocess, _smooth_signal


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
    rgb = demosaic_linear(KODAK, ReadOptions(expected_exposure_s=0.00435))
    assert rgb.kind == "linear"
    assert rgb.shape == (512, 768, 3)
    assert rgb.data.dtype == np.uint16
    assert rgb.exposure_s == 0.00435
    assert rgb.extra["counts_per_output"] == pytest.approx(16383 / 65535)


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
