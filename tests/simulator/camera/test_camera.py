"""The simulated camera: radiometry, the sensor chain, simulated time, fixed pattern and the DNG path."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from acquisition.frame import Camera
from acquisition.hdr.merge import merge_linear
from acquisition.noise import SensorNoise
from rig.instrument.clock import ManualClock
from simulator.camera.simulated import CameraOptics, SimulatedCamera

NOISE = SensorNoise()


def constant(radiance: float, shape: tuple[int, int] = (32, 32)):
    image = np.full((*shape, 3), radiance)
    image[..., 2] *= 0.5  # blue half as bright: channels must stay apart
    return lambda: image


def test_it_is_a_camera() -> None:
    assert isinstance(SimulatedCamera(constant(1.0)), Camera)


def test_counts_per_radiance_follows_the_camera_equation() -> None:
    optics = CameraOptics(
        quantum_efficiency=0.5, pixel_pitch_m=4e-6, f_number=4.0, transmission=1.0, wavelength_m=500e-9
    )
    photons_per_j = 500e-9 / (6.62607015e-34 * 299_792_458.0)
    expected = math.pi / 64 * 16e-12 * photons_per_j * 0.5 / NOISE.e_per_dn
    assert optics.counts_per_radiance(NOISE) == pytest.approx(expected, rel=1e-12)
    with pytest.raises(ValueError, match=r"CameraOptics.f_number = 0"):
        CameraOptics(f_number=0)


def test_frames_have_the_expected_mean_and_take_simulated_time() -> None:
    clock = ManualClock()
    cam = SimulatedCamera(constant(0.2), clock=clock, seed=3)
    applied = cam.set_exposure(0.05, gain=2.0)
    assert (applied.exposure_s, applied.gain) == (0.05, 2.0)
    frame = cam.capture()
    assert clock.now() == pytest.approx(0.05)
    assert frame.exposure_s == 0.05 and frame.gain == 2.0 and frame.timestamp_s == 0.0
    rate = 0.2 * cam.optics.counts_per_radiance(NOISE)
    expected = NOISE.black_level_dn + rate * np.array([1, 1, 0.5]) * 0.05 * 2.0
    assert frame.data.reshape(-1, 3).mean(axis=0) == pytest.approx(expected, rel=0.01)


def test_exposure_is_clamped_to_the_shutter_range_and_bad_values_refused() -> None:
    cam = SimulatedCamera(constant(1.0), min_exposure_s=1e-4, max_exposure_s=2.0)
    assert cam.set_exposure(1e-6).exposure_s == 1e-4
    assert cam.set_exposure(10.0).exposure_s == 2.0
    with pytest.raises(ValueError, match=r"exposure_s = -1"):
        cam.set_exposure(-1.0)
    with pytest.raises(ValueError, match=r"gain = 0"):
        cam.set_exposure(0.1, gain=0.0)


def test_fixed_pattern_is_removed_by_dark_frames() -> None:
    noise = SensorNoise(read_noise_e=1.0)
    cam = SimulatedCamera(constant(0.05, (48, 48)), noise=noise, fixed_pattern_dn=20.0, seed=5)
    exposures = (0.01, 0.04)
    frames, darks = [], {}
    for t in exposures:
        cam.set_exposure(t)
        frames.append(cam.capture())
        darks[t] = cam.capture_dark()
    with_darks = merge_linear(frames, noise, darks=darks)
    without = merge_linear(frames, noise)
    truth = 0.05 * cam.optics.counts_per_radiance(noise)
    scatter_with = np.std(with_darks.radiance[..., 0]) / truth
    scatter_without = np.std(without.radiance[..., 0]) / truth
    # 20 counts of offset over 0.05 s of exposure dwarf the shot noise; darks take it out.
    assert scatter_without > 3 * scatter_with
    assert np.mean(with_darks.radiance[..., 0]) == pytest.approx(truth, rel=0.01)


def test_raw_frames_go_through_dng_and_rawpy(tmp_path: Path) -> None:
    cam = SimulatedCamera(constant(0.1), kind="raw", cfa_pattern="GRBG", dng_dir=tmp_path, seed=1)
    cam.set_exposure(0.02)
    frame = cam.capture()
    assert frame.source is not None and frame.source.endswith(".dng")
    assert frame.kind == "raw" and frame.cfa_pattern == "GRBG" and frame.shape == (32, 32)
    assert frame.exposure_s == pytest.approx(0.02)
    # Same seed, no DNG: the very same counts, so the file path loses nothing.
    direct = SimulatedCamera(constant(0.1), kind="raw", cfa_pattern="GRBG", seed=1)
    direct.set_exposure(0.02)
    np.testing.assert_array_equal(frame.data, direct.capture().data)


def test_eight_bit_frames_and_closing() -> None:
    cam = SimulatedCamera(constant(0.1), kind="8bit")
    frame = cam.capture()
    assert frame.kind == "8bit" and frame.data.dtype == np.uint8
    cam.close()
    with pytest.raises(RuntimeError, match="closed"):
        cam.capture()


def test_bad_configuration_is_refused() -> None:
    with pytest.raises(ValueError, match="dng_dir needs kind='raw'"):
        SimulatedCamera(constant(1.0), dng_dir=Path("x"))
    with pytest.raises(ValueError, match=r"radiance source gave shape \(4, 4\)"):
        SimulatedCamera(lambda: np.zeros((4, 4))).capture()
