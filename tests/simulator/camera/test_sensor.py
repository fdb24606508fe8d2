"""The simulated sensor against the noise model it shares with the HDR merge (acquisition.noise.SensorNoise)."""

from __future__ import annotations

import numpy as np
import pytest

from acquisition.frame import Frame
from acquisition.noise import SensorNoise
from simulator.camera.sensor import (
    GammaCurve,
    SCurve,
    capture,
    capture_bracket,
    dark_frame,
    mosaic,
    sensor_counts,
    srgb_curve,
    tone_lut,
)

NOISE = SensorNoise()  # 4 e-/DN, 3 e- read noise, 0.5 e-/s dark, black 512, white 16383, full well 60000 e-
N_PIX = 40_000


def _stats(frame: Frame, black: float) -> tuple[float, float]:
    d = frame.data.astype(np.float64) - black
    return float(d.mean()), float(d.var(ddof=1))


@pytest.mark.parametrize(
    ("rate", "exposure_s", "gain"),
    [(0.0, 0.01, 1.0), (300.0, 0.01, 1.0), (2e4, 0.05, 1.0), (1e5, 0.1, 1.0), (2e3, 0.2, 4.0), (50.0, 2.0, 1.0)],
)
def test_mean_and_variance_match_the_noise_model(rate: float, exposure_s: float, gain: float) -> None:
    frame = capture(np.full((200, 200), rate), NOISE, exposure_s, 7, gain=gain)
    mean, var = _stats(frame, NOISE.black_level_dn)
    g = NOISE.e_per_dn / gain
    photo_dn = rate * exposure_s * gain
    expected_mean = photo_dn + NOISE.dark_current_e_per_s * exposure_s / g
    # variance_dn2 adds the dark current's shot noise itself: its signal is the photo-signal alone.
    expected_var = float(NOISE.variance_dn2(photo_dn, exposure_s, gain))
    # Standard errors of the sample mean and variance of N_PIX (nearly Gaussian) values, 5 sigma.
    assert abs(mean - expected_mean) < 5 * np.sqrt(expected_var / N_PIX) + 0.01
    assert abs(var / expected_var - 1) < 5 * np.sqrt(2 / N_PIX) + 0.01


def test_frame_metadata_and_dtype() -> None:
    frame = capture(np.full((8, 6, 3), 100.0), NOISE, 0.02, 0, gain=2.0, camera_id="cam-1", timestamp_s=5.0)
    assert frame.kind == "linear"
    assert frame.shape == (8, 6, 3)
    assert frame.data.dtype == np.uint16
    assert (frame.exposure_s, frame.gain, frame.camera_id, frame.timestamp_s) == (0.02, 2.0, "cam-1", 5.0)
    assert frame.black_level == NOISE.black_level_dn
    assert frame.white_level == NOISE.white_level_dn
    assert frame.cfa_pattern is None


def test_full_well_clips_below_the_adc() -> None:
    # Default sensor: full well 60000 e- = 15000 DN above black, below the ADC's 16383 - 512 = 15871.
    frame = capture(np.full((100, 100), 1e9), NOISE, 1.0, 1)
    above = frame.data.astype(np.float64) - NOISE.black_level_dn
    assert abs(above.mean() - 15000) < 0.5
    assert 0.3 < above.std() < 1.2  # read noise after the clip, 0.75 DN
    assert above.max() < NOISE.white_level_dn - NOISE.black_level_dn


def test_adc_clips_at_white_level() -> None:
    noise = SensorNoise(full_well_e=1e6)
    frame = capture(np.full((50, 50), 1e9), noise, 1.0, 1)
    assert np.all(frame.data == 16383)


def test_no_negative_counts_and_black_level() -> None:
    noise = SensorNoise(black_level_dn=0.0, read_noise_e=8.0)
    frame = dark_frame((100, 100), noise, 0.01, 3)
    assert frame.data.min() == 0  # read noise below zero is clipped by the ADC, as on a real sensor
    assert frame.data.dtype == np.uint16


def test_deterministic_for_a_seed() -> None:
    rad = np.linspace(0.0, 1e5, 64 * 64).reshape(64, 64)
    a = capture(rad, NOISE, 0.01, 42)
    b = capture(rad, NOISE, 0.01, np.random.default_rng(42))
    c = capture(rad, NOISE, 0.01, 43)
    assert np.array_equal(a.data, b.data)
    assert not np.array_equal(a.data, c.data)
    bracket1 = capture_bracket(rad, NOISE, [0.001, 0.004], 5)
    bracket2 = capture_bracket(rad, NOISE, [0.001, 0.004], 5)
    assert all(np.array_equal(x.data, y.data) for x, y in zip(bracket1, bracket2, strict=True))
    assert not np.array_equal(bracket1[0].data, bracket1[1].data)
    assert [f.timestamp_s for f in bracket1] == [0.0, 0.001]


def test_dark_frame_statistics() -> None:
    exposure = 4.0
    frame = dark_frame((200, 200), NOISE, exposure, 9)
    mean, var = _stats(frame, NOISE.black_level_dn)
    dark_dn = NOISE.dark_current_e_per_s * exposure / NOISE.e_per_dn
    expected_var = float(NOISE.variance_dn2(0.0, exposure))  # read + dark shot + quantisation
    assert abs(mean - dark_dn) < 5 * np.sqrt(expected_var / N_PIX)
    assert abs(var / expected_var - 1) < 5 * np.sqrt(2 / N_PIX)


def test_bayer_mosaic_samples_the_right_channels() -> None:
    rgb = np.empty((40, 60, 3))
    rgb[..., 0], rgb[..., 1], rgb[..., 2] = 1e5, 5e4, 1e4
    m = mosaic(rgb, "GRBG")
    assert m[0, 0] == 5e4 and m[0, 1] == 1e5 and m[1, 0] == 1e4 and m[1, 1] == 5e4
    frame = capture(rgb, NOISE, 0.05, 2, kind="raw", cfa_pattern="GRBG")
    assert frame.kind == "raw" and frame.cfa_pattern == "GRBG" and frame.shape == (40, 60)
    above = frame.data.astype(np.float64) - NOISE.black_level_dn
    for (dy, dx), rate in {(0, 0): 5e4, (0, 1): 1e5, (1, 0): 1e4, (1, 1): 5e4}.items():
        site = above[dy::2, dx::2]
        assert abs(site.mean() / (rate * 0.05) - 1) < 0.01


def test_raw_defaults_to_rggb() -> None:
    frame = capture(np.ones((4, 4, 3)), NOISE, 0.01, 0, kind="raw")
    assert frame.cfa_pattern == "RGGB"


def test_8bit_output_follows_the_tone_curve() -> None:
    # No noise, so the code is the tone curve of the exact relative exposure (checked at several levels).
    quiet = SensorNoise(read_noise_e=0.0, dark_current_e_per_s=0.0, e_per_dn=1.0, full_well_e=15000.0)
    levels = np.array([0.0, 0.001, 0.01, 0.1, 0.18, 0.5, 0.9, 0.99, 3.0])
    rad = np.repeat(levels[None, :] * 15000.0, 2000, axis=0)  # 1 s exposure: counts = level * 15000
    frame = capture(rad, quiet, 1.0, 4, kind="8bit")
    assert frame.kind == "8bit" and frame.data.dtype == np.uint8
    assert frame.black_level == 0.0 and frame.white_level == 255.0
    mean_code = frame.data.astype(np.float64).mean(axis=0)
    expected = 255 * srgb_curve(np.minimum(levels, 1.0))
    # Poisson noise of the counts (e_per_dn 1) moves the code by < 1 on average at these levels.
    assert np.all(np.abs(mean_code - expected) < 1.0)
    assert mean_code[-1] == 255  # clipped at full well
    assert np.all(np.diff(mean_code) >= 0)


def test_tone_lut_and_curves_are_monotone() -> None:
    for curve in (srgb_curve, GammaCurve(2.2), SCurve(2.2, 1.6)):
        lut = tone_lut(NOISE, curve)
        assert lut.shape == (16384,)
        assert lut[0] == 0 and lut[512] == 0 and lut[512 + 15000] == 255 and lut[-1] == 255
        assert np.all(np.diff(lut.astype(int)) >= 0)
    s = SCurve(2.2, 2.0)
    g = GammaCurve(2.2)
    x = np.array([0.001, 0.5 ** 2.2, 0.9])
    # The S-curve darkens shadows and brightens highlights against the plain gamma, fixed at g = 0.5.
    assert s(x)[0] < g(x)[0] and abs(s(x)[1] - 0.5) < 1e-12 and s(x)[2] > g(x)[2]


def test_invalid_inputs() -> None:
    with pytest.raises(ValueError, match="finite and >= 0"):
        capture(np.array([[1.0, -1.0]]), NOISE, 0.01, 0)
    with pytest.raises(ValueError, match="finite and >= 0"):
        capture(np.array([[1.0, np.nan]]), NOISE, 0.01, 0)
    with pytest.raises(ValueError, match="exposure_s"):
        sensor_counts(np.ones((2, 2)), NOISE, 0.0, 0)
    with pytest.raises(ValueError, match="shape"):
        capture(np.ones(5), NOISE, 0.01, 0)
    with pytest.raises(ValueError, match="cfa_pattern"):
        capture(np.ones((2, 2, 3)), NOISE, 0.01, 0, kind="raw", cfa_pattern="RGGX")
    with pytest.raises(ValueError, match="only raw frames"):
        capture(np.ones((2, 2, 3)), NOISE, 0.01, 0, cfa_pattern="RGGB")
    with pytest.raises(TypeError, match="Generator or an integer"):
        capture(np.ones((2, 2)), NOISE, 0.01, "seed")  # type: ignore[arg-type]


def test_huge_radiance_stays_finite_and_clipped() -> None:
    frame = capture(np.full((10, 10), 1e30), NOISE, 60.0, 0)
    assert np.all(frame.data.astype(float) - NOISE.black_level_dn > 14990)
