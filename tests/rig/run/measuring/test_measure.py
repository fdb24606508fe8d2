"""One reading (rig/run/measuring/measure.py): planning from the previous point per colour channel, and the top-up."""

from __future__ import annotations

import numpy as np
import pytest

from acquisition.exposure.spec import CameraTiming
from acquisition.noise import SensorNoise
from rig.run.measuring.measure import TOP_UP_BELOW, CaptureSettings, Level, snr_reached, take_reading
from simulator.camera.simulated import SimulatedCamera

#: Red, green, blue of the scene: blue a quarter of the others, so the overall mean overstates it.
COLOUR = np.array([1.0, 1.0, 0.25])


class Scene:
    """A uniform scene whose brightness a test turns (W/(m^2 sr) times ``COLOUR``)."""

    def __init__(self, radiance: float) -> None:
        self.radiance = radiance

    def __call__(self) -> np.ndarray:
        return np.broadcast_to(self.radiance * COLOUR, (8, 8, 3)).copy()


def _setup(radiance: float, target_snr: float = 300.0) -> tuple[Scene, SimulatedCamera, CaptureSettings]:
    scene = Scene(radiance)
    noise = SensorNoise()
    cam = SimulatedCamera(scene, noise=noise, seed=4)
    settings = CaptureSettings(noise=noise, timing=CameraTiming(cam.min_exposure_s, cam.max_exposure_s),
                               target_snr=target_snr, max_frames=8, roi=(2, 2, 6, 6))  # fmt: skip
    return scene, cam, settings


def test_a_plan_from_the_previous_point_reaches_the_goal_in_the_dimmest_channel() -> None:
    _, cam, settings = _setup(0.02)
    first = take_reading(cam, settings, None)  # metered
    assert len(first.level.channel_means) == 3
    assert first.level.channel_means[2] == pytest.approx(0.25 * first.level.channel_means[0], rel=0.05)
    second = take_reading(cam, settings, first.level)
    # Planned per channel, the bracket is right at once: no top-up, and blue reaches the goal. Planned on
    # the overall mean (as before channel means were kept), blue would get sqrt(0.25 / 0.75) of it.
    assert not any("topped up" in n for n in second.notes)
    assert snr_reached(second.roi) >= TOP_UP_BELOW * settings.target_snr


def test_a_point_darker_than_the_previous_is_topped_up_to_the_goal() -> None:
    scene, cam, settings = _setup(0.2)
    bright = take_reading(cam, settings, None)
    scene.radiance = 0.02
    planned_frames = len(take_reading(cam, settings, None).exposures_s)  # what metering this point would take
    dark = take_reading(cam, settings, bright.level)
    assert any("topped up" in n for n in dark.notes), dark.notes
    assert snr_reached(dark.roi) >= TOP_UP_BELOW * settings.target_snr
    assert len(dark.exposures_s) > 1 and planned_frames >= 1
    # The darks cover every exposure of both brackets, taken once after the top-up.
    assert set(dark.dark_exposures_s) == set(dark.exposures_s)


def test_a_level_from_an_older_journal_plans_on_its_overall_mean() -> None:
    old = {"peak": 900.0, "mean": 500.0, "dark": 300.0, "n_pixels": 16}
    level = Level.from_dict(old)
    assert level.channel_means == () and [lv.mean_dn_per_s for lv in level.roi_level()] == [500.0]
    new = Level(900.0, 500.0, 100.0, 16, (700.0, 600.0, 200.0))
    assert Level.from_dict(new.as_dict()) == new
    # The dimmest channel's darkest pixel cannot be brighter than its mean.
    assert [lv.dark_dn_per_s for lv in new.roi_level()] == [100.0, 100.0, 100.0]
    assert [lv.dark_dn_per_s for lv in Level(900.0, 500.0, 300.0, 16, (700.0, 600.0, 200.0)).roi_level()][2] == 200.0


def test_a_black_point_after_a_bright_one_is_read_not_refused() -> None:
    scene, cam, settings = _setup(0.2)
    bright = take_reading(cam, settings, None)
    scene.radiance = 0.0
    black = take_reading(cam, settings, bright.level)
    # Noise about zero: some channel means come out negative, and the next plan must still be made from them.
    assert np.all(np.isfinite(black.roi.mean)) and np.all(np.abs(black.roi.mean) < 5 * black.roi.std_error + 1e-3)
    assert max(black.exposures_s) == cam.max_exposure_s  # the top-up went to the longest exposure
    nxt = take_reading(cam, settings, black.level)
    assert np.all(np.isfinite(nxt.roi.mean))


@pytest.mark.parametrize("kind", ["linear", "raw"])
def test_the_check_before_a_top_up_merges_the_roi_alone_to_the_same_reading(kind: str) -> None:
    from rig.run.measuring.measure import _frames, _merge, _roi_check

    image = np.random.default_rng(0).uniform(0.01, 0.03, (16, 16, 3))
    noise = SensorNoise()
    cam = SimulatedCamera(lambda: image, noise=noise, kind=kind, seed=2)
    # Odd offsets: a raw mosaic cropped there would swap its red and blue sites.
    settings = CaptureSettings(noise=noise, timing=CameraTiming(), dark_frames=0, roi=(3, 5, 9, 12))
    frames = _frames(cam, (0.05, 0.2))
    whole, check = _merge(None, settings, frames, (), ()), _roi_check(settings, frames)
    np.testing.assert_allclose(check.roi.mean, whole.roi.mean, rtol=1e-12)
    np.testing.assert_allclose(check.roi.std_error_propagated, whole.roi.std_error_propagated, rtol=1e-12)
    assert check.level == whole.level and check.hdr.radiance.shape[:2] == (8, 8)


def test_a_large_lit_roi_is_read_with_its_pixels_seen_not_as_dark() -> None:
    # A 160 x 160 px ROI (a 512 px frame's default ROI is this large): its mean reaches SNR 400 in a frame of a few
    # counts a pixel, below what the merge detects in one pixel, and the reading was called dark (a lit reference
    # tile was a camera fault). Each channel's mean pixel must be seen; blue is a quarter of the others.
    noise = SensorNoise()
    scene = Scene(0.05)
    cam = SimulatedCamera(lambda: np.broadcast_to(scene.radiance * COLOUR, (160, 160, 3)).copy(), noise=noise, seed=5)
    settings = CaptureSettings(noise=noise, timing=CameraTiming(cam.min_exposure_s, cam.max_exposure_s),
                               target_snr=400.0, max_frames=5, dark_frames=1)  # fmt: skip
    metered = take_reading(cam, settings, None)
    again = take_reading(cam, settings, metered.level)  # planned from the previous point
    scene.radiance = 0.05 / 3  # a point three times darker: its check without darks passed, the reading was dark
    darker = take_reading(cam, settings, metered.level)
    for r in (metered, again, darker):
        # Nearly every pixel seen (the mean pixel 2 sigma above the merge's dark threshold), and the SNR goal met.
        assert not r.roi.dark and np.all(r.roi.n_dark < 0.03 * r.roi.n_used), (r.roi.n_dark, r.exposures_s, r.notes)
        assert snr_reached(r.roi) >= TOP_UP_BELOW * settings.target_snr
