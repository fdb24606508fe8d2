"""A mosaic's ROI read per CFA colour (acquisition/cfa.py), on synthetic mosaics and on the Kodak DC50 file."""

from __future__ import annotations

import numpy as np
import pytest

from acquisition.cfa import bin_hdr, cell_box, demosaic_hdr, reduce_hdr_roi, reduce_mosaic_roi, shift_pattern
from acquisition.files.raw import bin_bayer, read_raw
from acquisition.hdr.merge import merge_linear
from acquisition.noise import SensorNoise
from acquisition.roi import RoiError
from tests.acquisition.raw_helpers import KODAK


def _mosaic(pattern: str, rgb: tuple[float, float, float], shape: tuple[int, int] = (10, 12)) -> np.ndarray:
    out = np.empty(shape)
    for pos, letter in enumerate(pattern):
        out[pos // 2 :: 2, pos % 2 :: 2] = rgb["RGB".index(letter)]
    return out


@pytest.mark.parametrize("pattern", ["RGGB", "BGGR", "GRBG", "GBRG"])
def test_each_colour_is_read_from_its_own_pixels(pattern: str) -> None:
    rad = _mosaic(pattern, (300.0, 200.0, 50.0))
    var = _mosaic(pattern, (4.0, 2.0, 1.0))
    reading = reduce_mosaic_roi(rad, var, (0, 0, 12, 10), pattern)
    assert reading.mean.tolist() == [300.0, 200.0, 50.0]
    # 30 cells; the green of a cell is the mean of two pixels: a quarter of their summed variance.
    assert reading.std_error_propagated == pytest.approx(np.sqrt(np.array([4.0, 1.0, 1.0]) / 30))
    assert reading.n_pixels == 30


def test_a_box_keeps_only_whole_cells_in_the_sensor_phase() -> None:
    assert cell_box((1, 1, 7, 6), (10, 12)) == (1, 1, 3, 3)
    with pytest.raises(RoiError, match="no whole 2x2 CFA cell"):
        cell_box((1, 1, 3, 2), (10, 12))
    # Seen from an odd pixel the pattern shifts: the mosaic's phase stays the sensor's.
    assert shift_pattern("RGGB", 1, 0) == "GRBG" and shift_pattern("RGGB", 1, 1) == "BGGR"


def test_a_saturated_pixel_flags_its_cell_in_its_colour_only() -> None:
    rad = _mosaic("RGGB", (300.0, 200.0, 50.0))
    var = np.ones_like(rad)
    flags = np.zeros(rad.shape, dtype=np.uint8)
    flags[0, 0] = 1  # an R pixel
    var[0, 0] = np.inf
    _, v, f = bin_hdr(rad, var, flags, "RGGB")
    assert f[0, 0].tolist() == [True, False, False] and np.isinf(v[0, 0, 0])
    reading = reduce_mosaic_roi(rad, var, (0, 0, 12, 10), "RGGB", flags=flags)
    assert reading.n_flagged.tolist() == [1, 0, 0] and reading.n_used.tolist() == [29, 30, 30]


def test_demosaic_interpolates_each_colour_linearly() -> None:
    yy, xx = np.mgrid[0:10, 0:12].astype(float)
    truth = np.stack([100 + 3 * xx, 200 + 2 * yy, 50 + xx + yy], axis=-1)
    rad = np.zeros((10, 12))
    for pos, letter in enumerate("RGGB"):
        rad[pos // 2 :: 2, pos % 2 :: 2] = truth[pos // 2 :: 2, pos % 2 :: 2, "RGB".index(letter)]
    full, full_var = demosaic_hdr(rad, np.ones_like(rad), "RGGB")
    inner = (slice(1, -1), slice(1, -1))
    assert np.allclose(full[inner], truth[inner])  # bilinear is exact on a linear ramp
    assert np.all(full_var[inner] <= 1.0)


def test_the_kodak_mosaic_reads_three_colours_not_one_number() -> None:
    frame = read_raw(KODAK)
    hdr = merge_linear([frame], SensorNoise(black_level_dn=0.0, white_level_dn=frame.white_level))
    h, w = frame.shape
    box = (w // 4, h // 4, 3 * w // 4, 3 * h // 4)
    reading = reduce_hdr_roi(hdr, box)
    assert reading.mean.shape == (3,)
    assert len(set(np.round(reading.mean, 3))) == 3  # a real scene's colours differ
    # The same means as binning the mosaic's counts over the box's cells, over exposure times gain (ISO / 100).
    cells = bin_bayer(frame)[box[1] // 2 : box[3] // 2, box[0] // 2 : box[2] // 2]
    assert reading.mean == pytest.approx(cells.reshape(-1, 3).mean(axis=0) / (frame.exposure_s * frame.gain), rel=1e-4)
