"""Photon transfer and flat field (acquisition/photon_transfer.py, acquisition/flatfield.py) recover hidden sensors.

The sensors are drawn by simulator.camera.pixels.SensorTruth.random and their frames made by the sensor
model; the fits never see the truth. A few seeds here, twenty and more in bench/camera_calibration.py.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from acquisition.flatfield import FlatField, FlatFieldError, estimate_flat_field
from acquisition.frame import Frame
from acquisition.hdr.merge import merge_linear
from acquisition.noise import SensorNoise
from acquisition.photon_transfer import PhotonTransferError, fit_photon_transfer, pair_points
from simulator.camera.pixels import PixelResponse, SensorTruth
from simulator.camera.sensor import capture

SHAPE = (48, 64)


def _series(truth: SensorTruth, seed: int, steps: int = 24) -> list:
    n, resp = truth.noise, truth.response
    rate = n.saturation_dn() / 0.05
    gmap = resp.gain_map((SHAPE[1], SHAPE[0]))
    rng = np.random.default_rng(seed)
    points = []
    for t in np.linspace(0.06 / steps, 0.06, steps):
        flats = [capture(np.full(SHAPE, rate), n, t, rng, kind="raw", pixel_gain=gmap,
                         nonlinearity=resp.nonlinearity) for _ in range(2)]  # fmt: skip
        darks = [capture(np.zeros(SHAPE), n, t, rng, kind="raw") for _ in range(2)]
        points += pair_points(t, flats, darks)
    return points


@pytest.mark.parametrize("seed", [3, 11, 19])
def test_gain_and_read_noise_are_recovered_within_three_standard_errors(seed: int) -> None:
    truth = SensorTruth.random(seed)
    fit = fit_photon_transfer(_series(truth, seed), truth.noise.white_level_dn)
    assert abs(fit.e_per_dn.value - truth.noise.e_per_dn) < 3 * fit.e_per_dn.std_error
    assert abs(fit.read_noise_e.value - truth.noise.read_noise_e) < 3 * fit.read_noise_e.std_error
    assert fit.e_per_dn.std_error < 0.05 * fit.e_per_dn.value  # and the errors are small enough to mean something
    assert fit.black_level_dn.value == pytest.approx(truth.noise.black_level_dn, abs=0.5)
    clip = truth.noise.saturation_dn()
    assert fit.saturation_dn == pytest.approx(clip, rel=0.02)
    assert fit.noise().saturation_dn() == pytest.approx(clip, rel=0.02)


def test_a_bent_response_shows_as_linearity_error() -> None:
    straight = SensorTruth(SensorNoise(), PixelResponse())
    bent = SensorTruth(SensorNoise(), PixelResponse(nonlinearity=0.05))
    le_straight = fit_photon_transfer(_series(straight, 1), 16383).linearity_error_percent
    le_bent = fit_photon_transfer(_series(bent, 1), 16383).linearity_error_percent
    assert le_straight < 0.5 < le_bent


def test_a_series_without_enough_frames_is_refused() -> None:
    frame = capture(np.full(SHAPE, 1e4), SensorNoise(), 0.01, 0, kind="raw")
    with pytest.raises(PhotonTransferError, match="needs two of each"):
        pair_points(0.01, [frame], [frame])
    with pytest.raises(PhotonTransferError, match="at least 4"):
        fit_photon_transfer(pair_points(0.01, [frame, frame], [frame, frame]), 16383)


def _flat_frames(resp: PixelResponse, n: int, t: float, seed: int) -> tuple[list[Frame], list[Frame]]:
    noise = SensorNoise()
    rng = np.random.default_rng(seed)
    gmap = resp.gain_map((SHAPE[1], SHAPE[0]))
    rate = 0.5 * noise.saturation_dn() / t
    flats = [capture(np.full(SHAPE, rate), noise, t, rng, kind="raw", pixel_gain=gmap) for _ in range(n)]
    darks = [capture(np.zeros(SHAPE), noise, t, rng, kind="raw") for _ in range(4)]
    return flats, darks


def test_a_flat_field_removes_vignetting_and_prnu_below_the_photon_noise(tmp_path: Path) -> None:
    resp = PixelResponse(vignetting=0.3, prnu_rms=0.02, seed=5)
    flats, darks = _flat_frames(resp, 16, 0.02, 1)
    flat = estimate_flat_field(flats, darks)
    assert flat.vignetting == pytest.approx(0.3, abs=0.02) and flat.prnu_rms == pytest.approx(0.02, rel=0.15)
    # A new flat frame, merged and corrected: what is left across the sensor is its own photon noise.
    new, new_darks = _flat_frames(resp, 1, 0.02, 2)
    hdr = merge_linear(new, SensorNoise(), darks={0.02: new_darks})
    for corrected in (flat.apply(hdr), FlatField.load(flat.save(tmp_path / "flat.npz")).apply(hdr)):
        rel = corrected.radiance / np.median(corrected.radiance)
        photon = np.sqrt(np.median(corrected.variance)) / np.median(corrected.radiance)
        residual = np.sqrt(max(np.var(rel) - photon**2, 0.0))
        assert residual < 0.5 * photon, (residual, photon)
    uncorrected = hdr.radiance / np.median(hdr.radiance)
    assert np.std(uncorrected) > 5 * photon  # the vignetting was far above the noise before


def test_a_flat_field_corrects_a_window_where_it_lies_and_refuses_one_off_the_sensor() -> None:
    resp = PixelResponse(vignetting=0.3, seed=2)
    flats, darks = _flat_frames(resp, 4, 0.02, 3)
    flat = estimate_flat_field(flats, darks)
    assert flat.window((10, 6), (8, 8)).shape == (8, 8)
    assert np.array_equal(flat.window((10, 6), (8, 8)), flat.gain[6:14, 10:18])
    with pytest.raises(FlatFieldError, match="does not cover a 8x8 frame at sensor pixel"):
        flat.window((60, 0), (8, 8))
    with pytest.raises(FlatFieldError, match="no such flat-field file"):
        FlatField.load("/nonexistent/flat.npz")
