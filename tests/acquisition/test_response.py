"""The 8-bit path: OpenCV camera-response calibration and merge, curve storage, and the flags OpenCV lacks."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from acquisition.frame import Frame, FrameError
from acquisition.hdr.merge import HdrFlag
from acquisition.hdr.response import ResponseCurve, calibrate_or_load, calibrate_response, merge_8bit
from acquisition.noise import SensorNoise
from simulator.camera.sensor import SCurve, capture_bracket, srgb_curve

NOISE = SensorNoise()
EXPOSURES = [0.001 * 4.0**k for k in range(6)]  # 1 ms .. 1 s, 2 stops apart


@pytest.fixture(scope="module")
def scene() -> np.ndarray:
    # 4 decades, so that every pixel is well exposed (codes 30..230) in at least two frames.
    rng = np.random.default_rng(0)
    return np.exp(rng.uniform(np.log(300.0), np.log(3e6), (64, 64, 3)))


@pytest.fixture(scope="module")
def bracket(scene: np.ndarray) -> list[Frame]:
    return capture_bracket(scene, NOISE, EXPOSURES, 1, kind="8bit", camera_id="cam-8")


def srgb_inverse(codes: np.ndarray) -> np.ndarray:
    """Mean relative exposure that the simulator's sRGB curve maps to each code (the true inverse response)."""
    x = np.linspace(0.0, 1.0, 200_001)
    y = np.rint(255 * srgb_curve(x))
    return np.array([x[y == c].mean() for c in codes])


@pytest.mark.parametrize("method", ["debevec", "robertson"])
def test_calibration_recovers_the_inverse_tone_curve(bracket: list[Frame], method: str) -> None:
    curve = calibrate_response(bracket, method)  # type: ignore[arg-type]
    assert curve.inverse.shape == (256, 3) and curve.channels == 3
    assert curve.camera_id == "cam-8" and curve.method == method
    codes = np.arange(16, 240)
    assert np.all(np.diff(curve.inverse[codes], axis=0) > 0)
    # Up to a scale per channel, the recovered inverse response is the sRGB curve's inverse.
    log_ratio = np.log(curve.inverse[codes]) - np.log(srgb_inverse(codes))[:, None]
    spread = log_ratio - np.median(log_ratio, axis=0)
    tolerance = {"debevec": 0.05, "robertson": 0.35}[method]  # Robertson's curve bends at the ends
    assert np.abs(spread).max() < tolerance, np.abs(spread).max()


@pytest.mark.parametrize("method", ["debevec", "robertson"])
def test_merged_radiance_follows_the_truth(scene: np.ndarray, bracket: list[Frame], method: str) -> None:
    curve = calibrate_response(bracket, method)  # type: ignore[arg-type]
    img = merge_8bit(bracket, curve)
    assert img.radiance.shape == scene.shape and img.radiance.dtype == np.float32
    assert np.all(np.isnan(img.variance))
    assert img.metadata["method"] == f"opencv-{method}"
    assert not img.flags.any()
    log_est, log_true = np.log(img.radiance), np.log(scene)
    assert np.corrcoef(log_est.ravel(), log_true.ravel())[0, 1] > 0.98
    # Relative radiance: one scale per channel. Measured here (seed fixed): median error 16 % for Debevec,
    # 6.6 % for Robertson. OpenCV's Debevec merge gives codes 0 and 255 a weight of 1 (its hat never
    # reaches 0), so clipped frames pull the estimate; Robertson's weights vanish there.
    rel = img.radiance / scene
    rel /= np.median(rel, axis=(0, 1))
    assert np.median(np.abs(rel - 1)) < {"debevec": 0.25, "robertson": 0.1}[method]


def test_flags_pixels_saturated_or_dark_in_every_frame(scene: np.ndarray) -> None:
    patched = scene.copy()
    patched[0, :, :] = 1e12  # saturated everywhere
    patched[1, :, :] = 0.0  # black everywhere
    patched[2, :, 0] = 1e12  # only the red channel saturated: OpenCV weighs channels together
    frames = capture_bracket(patched, NOISE, EXPOSURES, 2, kind="8bit")
    curve = calibrate_response(frames, "robertson")
    img = merge_8bit(frames, curve)
    assert np.all(img.flags[0] == HdrFlag.SATURATED) and np.all(img.frames_used[0] == 0)
    assert np.all(img.flags[1] == HdrFlag.DARK) and np.all(img.frames_used[1] == 0)
    assert np.all(img.flags[2, :, 0] == HdrFlag.SATURATED) and not img.flags[2, :, 1:].any()
    assert not img.flags[3:].any()
    # Saturated pixels carry a lower bound: the shortest frame's code through the curve over its exposure.
    assert np.allclose(img.radiance[0], curve.inverse[255] / EXPOSURES[0])
    # What OpenCV gives there: Robertson returns 0 where every code is 0 (kept, flagged).
    black_everywhere = np.all([f.data[1] == 0 for f in frames], axis=0)
    assert black_everywhere.sum() > 50
    assert np.all(img.radiance[1][black_everywhere] == 0.0)


def test_curve_save_load_round_trip(tmp_path: Path, bracket: list[Frame]) -> None:
    curve = calibrate_response(bracket, "debevec", created="2026-11-22T10:00:00+00:00")
    for name in ("curve.json", "curve.npz"):
        path = curve.save(tmp_path / "cams" / name)
        loaded = ResponseCurve.load(path)
        assert np.array_equal(loaded.inverse, curve.inverse)  # bit-identical
        assert (loaded.method, loaded.camera_id, loaded.created) == ("debevec", "cam-8", "2026-11-22T10:00:00+00:00")
        assert loaded.params == curve.params and loaded.opencv_version == curve.opencv_version
    meta = json.loads((tmp_path / "cams" / "curve.json").read_text())
    assert meta["format"] == "gonio.response/1" and len(meta["inverse"]) == 256
    assert sorted(p.name for p in (tmp_path / "cams").iterdir()) == ["curve.json", "curve.npz"]  # no temp files
    img_a = merge_8bit(bracket, curve)
    img_b = merge_8bit(bracket, ResponseCurve.load(tmp_path / "cams" / "curve.json"))
    assert np.array_equal(img_a.radiance, img_b.radiance)


def test_load_rejects_other_files(tmp_path: Path) -> None:
    bad = tmp_path / "x.json"
    bad.write_text(json.dumps({"format": "other"}))
    with pytest.raises(ValueError, match="not a readable response curve"):
        ResponseCurve.load(bad)
    with pytest.raises(ValueError, match="not a readable response curve"):
        ResponseCurve.load(tmp_path / "missing.json")


def test_calibrate_or_load_reuses_the_stored_curve(tmp_path: Path, bracket: list[Frame]) -> None:
    path = tmp_path / "cam-8.json"
    first = calibrate_or_load(path, bracket, "debevec")
    stamp = path.stat().st_mtime_ns
    # A different bracket would calibrate differently: the stored curve comes back unchanged instead.
    other = capture_bracket(np.full((8, 8, 3), 5e3), NOISE, EXPOSURES[:3], 3, kind="8bit", camera_id="cam-8")
    again = calibrate_or_load(path, other, "debevec")
    assert np.array_equal(again.inverse, first.inverse) and again.created == first.created
    assert path.stat().st_mtime_ns == stamp
    with pytest.raises(FrameError, match="holds a debevec curve for camera 'cam-8'"):
        calibrate_or_load(path, bracket, "robertson")


def test_a_different_tone_curve_gives_a_different_response(scene: np.ndarray, bracket: list[Frame]) -> None:
    s_frames = capture_bracket(scene, NOISE, EXPOSURES, 1, kind="8bit", tone_curve=SCurve(2.2, 2.0))
    srgb = calibrate_response(bracket)
    s_curve = calibrate_response(s_frames)
    codes = np.arange(16, 240)
    ratio = np.log(s_curve.inverse[codes, 1]) - np.log(srgb.inverse[codes, 1])
    assert ratio.max() - ratio.min() > 1.0  # the S-curve's shadows and highlights differ by > e


def test_input_validation(bracket: list[Frame]) -> None:
    curve = calibrate_response(bracket)
    with pytest.raises(FrameError, match="at least 2"):
        calibrate_response(bracket[:1])
    with pytest.raises(FrameError, match="at least 2"):
        calibrate_response([bracket[0], dataclasses.replace(bracket[1], exposure_s=bracket[0].exposure_s)])
    linear = capture_bracket(np.full((64, 64, 3), 1e3), NOISE, EXPOSURES[:2], 0)
    with pytest.raises(FrameError, match="expected one of \\('8bit',\\)"):
        calibrate_response(linear)
    wide = [dataclasses.replace(f, data=f.data.astype(np.uint16)) for f in bracket]
    with pytest.raises(FrameError, match="uint8"):
        merge_8bit(wide, curve)
    with pytest.raises(FrameError, match="shape"):
        merge_8bit([bracket[0], dataclasses.replace(bracket[1], data=bracket[1].data[:10])], curve)
    grey = [dataclasses.replace(f, data=np.ascontiguousarray(f.data[..., 1])) for f in bracket]
    with pytest.raises(FrameError, match="1 channel\\(s\\) but the response curve has 3"):
        merge_8bit(grey, curve)
    other_cam = [dataclasses.replace(f, camera_id="cam-9") for f in bracket]
    with pytest.raises(FrameError, match="'cam-8', the frames are from 'cam-9'"):
        merge_8bit(other_cam, curve)
    with pytest.raises(FrameError, match="empty bracket"):
        merge_8bit([], curve)
    with pytest.raises(ValueError, match="dark_code"):
        merge_8bit(bracket, curve, dark_code=200, saturated_code=100)


def test_single_channel_bracket(scene: np.ndarray) -> None:
    frames = capture_bracket(scene[..., 1], NOISE, EXPOSURES, 4, kind="8bit")
    curve = calibrate_response(frames)
    assert curve.inverse.shape == (256, 1)
    img = merge_8bit(frames, curve)
    assert img.radiance.shape == scene.shape[:2]
    assert np.corrcoef(np.log(img.radiance).ravel(), np.log(scene[..., 1]).ravel())[0, 1] > 0.99
