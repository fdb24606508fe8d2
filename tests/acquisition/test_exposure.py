import math

import numpy as np
import pytest

from acquisition.exposure.bracket import fixed_bracket
from acquisition.exposure.metering import meter, saturated
from acquisition.exposure.plan import evaluate_plan, plan_exposure
from acquisition.exposure.snr import pixel_snr, roi_snr
from acquisition.exposure.spec import CameraTiming, ExposureError, RoiLevel
from acquisition.noise import SensorNoise

NOISE = SensorNoise()  # 4 e-/DN, 3 e- read noise, 60000 e- full well: saturation 15000 counts above black


def simulate(rates, exposures, noise, rng, reps, gain=1.0):
    """Frames of an ROI (rates in counts/s at gain 1) as a linear sensor delivers them, black and mean dark
    subtracted.

    Returns (counts above black, clipped) of shape (reps, n_frames, *rates.shape): Poisson electrons
    (signal + dark current), full-well clip, Gaussian read noise, gain, rounding to counts, ADC clip.
    """
    rates = np.asarray(rates, dtype=float)
    g = noise.e_per_dn / gain  # electrons per count at this gain
    out = np.empty((reps, len(exposures), *rates.shape))
    clip = np.empty(out.shape, dtype=bool)
    for k, t in enumerate(exposures):
        mean_e = rates * t * noise.e_per_dn + noise.dark_current_e_per_s * t
        e = rng.poisson(mean_e, size=(reps, *rates.shape)).astype(float)
        full = e >= noise.full_well_e
        e = np.minimum(e, noise.full_well_e)
        raw = np.rint(noise.black_level_dn + (e + rng.normal(0.0, noise.read_noise_e, e.shape)) / g)
        raw = np.clip(raw, 0, noise.white_level_dn)
        clip[:, k] = full | (raw >= noise.white_level_dn)
        out[:, k] = raw - noise.black_level_dn - noise.dark_current_e_per_s * t / g
    return out, clip


def merge(counts, clipped, exposures, gain=1.0):
    """The simple linear merge: sum(s) / sum(t g) over unclipped frames, per pixel and repeat."""
    t = gain * np.asarray(exposures).reshape((1, -1) + (1,) * (counts.ndim - 2))
    used = ~clipped
    return np.sum(np.where(used, counts, 0.0), axis=1) / np.sum(np.where(used, t, 0.0), axis=1)


def empirical_roi_snr(rates, plan_exposures, rng, reps=3000, noise=NOISE, gain=1.0):
    counts, clipped = simulate(rates, plan_exposures, noise, rng, reps, gain)
    x = merge(counts, clipped, plan_exposures, gain)
    roi_means = x.reshape(reps, -1).mean(axis=1)
    return roi_means.mean() / roi_means.std(ddof=1), clipped


def textured(peak, shape=(16, 16), seed=1):
    """A fixed ROI texture from 0.3 to 1 times peak, its maximum exactly at peak."""
    r = np.random.default_rng(seed).uniform(0.3, 1.0, shape)
    return peak * r / r.max()


@pytest.mark.parametrize(
    ("rates", "target"),
    [
        (np.full((10, 10), 2e4), 200.0),  # one frame, shortened
        (np.full((10, 10), 2e4), 3000.0),  # repeated frames at the peak limit
        (textured(5e4), 1000.0),
        (textured(5e4), 4000.0),
    ],
)
def test_expected_snr_matches_simulated_frames(rates, target):
    level = RoiLevel.from_pixels(rates)
    plan = plan_exposure(level, NOISE, target)
    assert plan.reached and plan.expected_snr == pytest.approx(target, rel=0.02)
    snr, clipped = empirical_roi_snr(rates, plan.exposures_s, np.random.default_rng(7))
    # 3000 repeats: the sample SNR scatters by ~1.3 %.
    assert snr / plan.expected_snr == pytest.approx(1.0, abs=0.04)
    assert not clipped.any()


def test_gain_scales_counts_not_the_roi_level():
    # Levels are counts/s at gain 1. At gain 4 one count is one electron: the ADC (15871 counts) clips
    # before the full well, frames are shorter, and read noise (3 e-) weighs 4x more in counts.
    rates = textured(2e4, (10, 10))
    plan = plan_exposure(RoiLevel.from_pixels(rates), NOISE, 2000.0, CameraTiming(gain=4.0))
    unity = plan_exposure(RoiLevel.from_pixels(rates), NOISE, 2000.0)
    assert plan.reached and plan.gain == 4.0
    assert max(plan.exposures_s) * 2e4 * 4 <= 0.8 * NOISE.saturation_dn(4.0) * (1 + 1e-9)
    assert plan.total_exposure_s > unity.total_exposure_s  # 15871 e- of headroom against 60000 e-
    snr, clipped = empirical_roi_snr(rates, plan.exposures_s, np.random.default_rng(8), gain=4.0)
    assert snr / plan.expected_snr == pytest.approx(1.0, abs=0.04)
    assert not clipped.any()


def test_expected_snr_with_master_dark_matches_simulation():
    rates = np.full((8, 8), 300.0)  # dim: read and dark noise matter
    cam = CameraTiming(max_exposure_s=0.5)
    plan = plan_exposure(RoiLevel.uniform(300.0, 64), NOISE, 400.0, cam, dark_frames=2)
    assert plan.n_frames > 1 and len(plan.dark_exposures_s) == 2
    rng = np.random.default_rng(3)
    reps, t = 4000, plan.exposures_s[0]
    counts, clipped = simulate(rates, plan.exposures_s, NOISE, rng, reps)
    # The master dark: mean of 2 dark frames, subtracted from every light frame (the mean dark was removed by
    # simulate; its noise is what the master dark adds).
    dark, _ = simulate(np.zeros_like(rates), [t, t], NOISE, rng, reps)
    counts = counts - dark.mean(axis=1, keepdims=True)
    roi = merge(counts, clipped, plan.exposures_s).reshape(reps, -1).mean(axis=1)
    assert roi.mean() / roi.std(ddof=1) / plan.expected_snr == pytest.approx(1.0, abs=0.04)
    without = plan_exposure(RoiLevel.uniform(300.0, 64), NOISE, 400.0, cam)
    assert without.n_frames <= plan.n_frames  # the master dark's noise is common to all frames: it costs frames


def test_plan_never_saturates_the_roi_peak():
    rng = np.random.default_rng(11)
    for peak in (3e2, 1e4, 3e5, 1e6):
        rates = textured(peak, (12, 12), seed=int(peak))
        plan = plan_exposure(RoiLevel.from_pixels(rates), NOISE, 1e5, max_frames=8)  # long frames: at the limit
        assert max(plan.exposures_s) * peak <= 0.8 * NOISE.saturation_dn() * (1 + 1e-9)
        counts, clipped = simulate(rates, plan.exposures_s, NOISE, rng, 200)
        assert not clipped.any()
        assert counts.max() < NOISE.saturation_dn()
        assert plan.saturation_margin >= 1.25 * (1 - 1e-9)


def test_one_frame_less_or_shorter_misses_the_target():
    level = RoiLevel.from_pixels(textured(2e4))
    for target in (50.0, 500.0, 2000.0, 6000.0, 12000.0):
        plan = plan_exposure(level, NOISE, target)
        assert plan.reached
        assert len(set(plan.exposures_s)) == 1
        n, t = plan.n_frames, plan.exposures_s[0]
        t_limit = 0.8 * NOISE.saturation_dn() / (level.peak_dn_per_s + NOISE.dark_current_e_per_s / NOISE.e_per_dn)
        if n > 1:
            assert roi_snr(level, NOISE, [t_limit] * (n - 1)) < target  # one frame less misses, even at the limit
        assert roi_snr(level, NOISE, [t * 0.999] * n) < target  # a shorter frame misses
        assert roi_snr(level, NOISE, [t] * n) >= target * (1 - 1e-9)


def test_max_exposure_cap_repeats_frames():
    level = RoiLevel.uniform(50.0, 100)  # the peak limit would be 240 s
    plan = plan_exposure(level, NOISE, 1000.0, CameraTiming(max_exposure_s=2.0))
    assert plan.reached and plan.n_frames > 1
    assert len(set(plan.exposures_s)) == 1 and plan.exposures_s[0] <= 2.0
    assert roi_snr(level, NOISE, [2.0] * (plan.n_frames - 1)) < 1000.0
    assert any("max_exposure_s" in note for note in plan.notes)


def test_unreachable_target_is_reported_with_achievable_snr():
    level = RoiLevel.uniform(50.0, 100)
    cam = CameraTiming(max_exposure_s=1.0, overhead_s=0.1)
    plan = plan_exposure(level, NOISE, 1e4, cam, max_frames=5)
    assert not plan.reached
    assert plan.exposures_s == (1.0,) * 5
    assert plan.expected_snr == pytest.approx(roi_snr(level, NOISE, [1.0] * 5))
    assert plan.expected_snr < 1e4
    assert any("unreachable within max_frames" in note for note in plan.notes)
    timed = plan_exposure(level, NOISE, 1e4, cam, max_total_s=3.5)
    assert not timed.reached and timed.n_frames == 3 and timed.total_time_s <= 3.5
    assert any("max_total_s" in note for note in timed.notes)


def test_saturation_at_min_exposure_is_an_error():
    with pytest.raises(ExposureError, match=r"saturates even at the shortest exposure.*1e-05 s"):
        plan_exposure(RoiLevel.uniform(5e9, 10), NOISE, 100.0, CameraTiming(min_exposure_s=1e-5))
    with pytest.raises(ExposureError, match="saturates"):
        plan_exposure(RoiLevel.uniform(1e5, 10), NOISE, 100.0, CameraTiming(steps=[0.5, 1.0, 2.0]))


def test_quantised_exposure_steps_are_respected():
    steps = [1e-3 * 2**k for k in range(14)]
    level = RoiLevel.from_pixels(textured(3e4))
    for target in (100.0, 1000.0, 5000.0):
        plan = plan_exposure(level, NOISE, target, CameraTiming(steps=steps))
        assert plan.reached
        assert all(t in steps for t in plan.exposures_s)
        assert max(plan.exposures_s) * 3e4 <= 0.8 * NOISE.saturation_dn()
        t = plan.exposures_s[0]
        shorter = [s for s in steps if s < t]
        if shorter:  # the next step down misses the target
            assert roi_snr(level, NOISE, [shorter[-1]] * plan.n_frames) < target

    def camera(t):  # 0.1 ms steps, as a camera rounding the request
        return round(t / 1e-4) * 1e-4

    plan = plan_exposure(level, NOISE, 1000.0, CameraTiming(min_exposure_s=1e-4, steps=camera))
    t = plan.exposures_s[0]
    assert plan.reached and camera(t) == pytest.approx(t, abs=1e-12)
    assert roi_snr(level, NOISE, [t - 1e-4] * plan.n_frames) < 1000.0


def test_colour_channels_brightest_limits_and_dimmest_sets_snr():
    r, g, b = (RoiLevel.uniform(v, 100) for v in (4e4, 1e4, 2e3))
    plan = plan_exposure([r, g, b], NOISE, 2000.0)
    assert max(plan.exposures_s) * 4e4 <= 0.8 * NOISE.saturation_dn()
    assert roi_snr(b, NOISE, plan.exposures_s) == pytest.approx(plan.expected_snr)
    assert roi_snr(r, NOISE, plan.exposures_s) > plan.expected_snr


def test_wide_dynamic_range_bracket_lifts_the_dark_end():
    # 4 decades inside the ROI: at the peak-limited exposure the darkest pixels collect ~5 e-, below the
    # read noise, so repeating that frame buys little; longer frames that clip the bright pixels do.
    rates = np.geomspace(2.0, 2e4, 400).reshape(20, 20)
    level = RoiLevel.from_pixels(rates, dark_percentile=0.0)
    cam = CameraTiming(max_exposure_s=60.0, overhead_s=0.05)
    plan = plan_exposure(level, NOISE, 500.0, cam, pixel_snr_target=8.0)
    assert plan.reached and plan.expected_pixel_snr is not None and plan.expected_pixel_snr >= 8.0
    assert len(set(plan.exposures_s)) > 1
    assert min(plan.exposures_s) * 2e4 <= 0.8 * NOISE.saturation_dn()
    assert any("bracket" in note for note in plan.notes)
    repeats = plan_exposure(level, NOISE, 500.0, cam, pixel_snr_target=8.0, bracket_ratio=1e9)  # no longer frames
    assert max(repeats.exposures_s) * 2e4 <= 0.8 * NOISE.saturation_dn() * (1 + 1e-9)  # no frame clips the ROI
    assert not any("bracket" in note for note in repeats.notes)
    assert plan.total_time_s < 0.6 * repeats.total_time_s
    # Simulate: the darkest pixels' SNR and the ROI SNR match the plan; the bright pixels clip in the long
    # frames and the merge leaves those samples out.
    rng = np.random.default_rng(5)
    reps = 3000
    counts, clipped = simulate(np.full(40, 2.0), plan.exposures_s, NOISE, rng, reps)
    x = merge(counts, clipped, plan.exposures_s)
    per_pixel = x.mean(axis=0) / x.std(axis=0, ddof=1)
    assert per_pixel.mean() / float(pixel_snr(2.0, NOISE, plan.exposures_s)) == pytest.approx(1.0, abs=0.03)
    snr, clipped = empirical_roi_snr(rates, plan.exposures_s, rng, reps=reps)
    assert clipped.any() and not clipped[:, 0].any()
    assert snr / plan.expected_snr == pytest.approx(1.0, abs=0.05)


def test_fixed_bracket_and_the_planner_at_equal_snr():
    assert fixed_bracket(0.01, 3, 1) == pytest.approx((0.005, 0.01, 0.02))
    level = RoiLevel.from_pixels(textured(2e4, (20, 20)))
    t_meter = 0.8 * NOISE.saturation_dn() / 2e4
    bracket = evaluate_plan(level, NOISE, fixed_bracket(t_meter, 7, 2))
    assert bracket.total_exposure_s == pytest.approx(t_meter * sum(4.0**k for k in range(-3, 4)))
    plan = plan_exposure(level, NOISE, bracket.expected_snr)
    assert plan.reached and bracket.total_exposure_s / plan.total_exposure_s >= 20


def test_total_time_counts_overhead_and_dark_frames():
    cam = CameraTiming(overhead_s=0.05)
    plan = plan_exposure(RoiLevel.uniform(1e3, 100), NOISE, 2000.0, cam, dark_frames=3)
    t, n = plan.exposures_s[0], plan.n_frames
    assert plan.dark_exposures_s == (t, t, t)
    assert plan.total_exposure_s == pytest.approx(n * t)
    assert plan.total_time_s == pytest.approx((n + 3) * (t + 0.05))


def _camera(rates, rng, noise=NOISE):
    def take(t):
        counts, _ = simulate(rates, [t], noise, rng, 1)
        return counts[0, 0] + noise.dark_current_e_per_s * t / noise.e_per_dn  # the dark mean is in a raw frame

    return take


def test_meter_steps_down_from_a_saturated_test_frame():
    rng = np.random.default_rng(2)
    rates = textured(2e5)
    res = meter(_camera(rates, rng), NOISE, 1000.0, start_exposure_s=0.2)
    assert res.test_exposures_s[0] == 0.2 and len(res.test_exposures_s) >= 2
    assert res.test_exposures_s[1] == pytest.approx(0.2 / 8)
    assert any("clipped" in note for note in res.notes)
    assert res.level.peak_dn_per_s == pytest.approx(2e5, rel=0.05)
    assert res.plan.reached
    _, clipped = simulate(rates, res.plan.exposures_s, NOISE, rng, 100)
    assert not clipped.any()


def test_meter_retakes_a_dark_test_frame_longer_and_uses_a_prediction():
    rng = np.random.default_rng(4)
    rates = textured(1e3)
    res = meter(_camera(rates, rng), NOISE, 300.0, start_exposure_s=1e-4)
    assert len(res.test_exposures_s) == 2 and res.test_exposures_s[1] > 1e-4
    assert res.level.mean_dn_per_s == pytest.approx(rates.mean(), rel=0.05)
    predicted = RoiLevel.from_pixels(rates * 1.5)  # a model off by 50 %
    res2 = meter(_camera(rates, rng), NOISE, 300.0, predicted=predicted)
    assert len(res2.test_exposures_s) == 1
    assert res2.plan.expected_snr == pytest.approx(300.0, rel=0.01)


def test_meter_gives_up_when_the_roi_clips_at_every_exposure():
    def always_clipped(t):
        return np.full(16, NOISE.saturation_dn())

    with pytest.raises(ExposureError, match="clip"):
        meter(always_clipped, NOISE, 100.0, CameraTiming(min_exposure_s=1e-3), start_exposure_s=1.0, max_tries=3)
    assert saturated([NOISE.saturation_dn(), 100.0], NOISE).tolist() == [True, False]


def test_zero_light_and_bad_inputs():
    plan = plan_exposure(RoiLevel.uniform(0.0, 10), NOISE, 10.0, CameraTiming(max_exposure_s=1.0))
    assert not plan.reached and plan.expected_snr == 0 and plan.n_frames == 1
    with pytest.raises(ValueError, match="mean_dn_per_s"):
        RoiLevel(peak_dn_per_s=1.0, mean_dn_per_s=2.0)
    with pytest.raises(ValueError, match="n_pixels"):
        RoiLevel(1.0, 1.0, n_pixels=0)
    with pytest.raises(ValueError, match="target_snr"):
        plan_exposure(RoiLevel.uniform(1.0), NOISE, -1.0)
    with pytest.raises(ValueError, match="dark_dn_per_s = None"):
        plan_exposure(RoiLevel(10.0, 5.0, 4), NOISE, 10.0, pixel_snr_target=5.0)
    with pytest.raises(ValueError, match="max_exposure_s"):
        CameraTiming(min_exposure_s=1.0, max_exposure_s=0.5)
    with pytest.raises(ValueError, match="steps"):
        CameraTiming(min_exposure_s=1.0, max_exposure_s=2.0, steps=[0.1, 5.0])
    assert math.isnan(evaluate_plan(RoiLevel.uniform(1.0), NOISE, [1.0]).target_snr)


def test_meter_counts_pixels_not_pixels_times_channels_in_a_colour_roi():
    # A 4x4 RGB ROI: each channel's mean averages 16 pixels. Counting 48 planned a third of the exposure
    # and delivered SNR target / sqrt(3) (the first reference reading of every run came out at 230 for 400).
    rng = np.random.default_rng(7)
    rates = np.full((4, 4, 3), 1.5e5)
    res = meter(_camera(rates, rng), NOISE, 400.0, start_exposure_s=0.01)
    assert res.level.n_pixels == 16
    counts, _ = simulate(rates, res.plan.exposures_s, NOISE, rng, 400)  # 400 repeats of the planned bracket
    roi_means = (counts.sum(axis=1) / sum(res.plan.exposures_s)).mean(axis=(1, 2))  # (repeats, channel)
    snr = roi_means.mean(axis=0) / roi_means.std(axis=0)
    assert np.all(snr > 0.85 * 400.0), snr


def test_a_plan_is_the_evaluation_of_its_own_exposures_with_what_only_the_planner_knows() -> None:
    # plan_exposure evaluates its bracket without the evaluation's pixel SNR (it puts in its own, over the
    # bracket ladder): every other field must be what evaluate_plan says of the same exposures.
    import dataclasses

    noise, cam = SensorNoise(), CameraTiming(overhead_s=0.02)
    rng = np.random.default_rng(11)
    for _ in range(60):
        peak = float(10 ** rng.uniform(1, 6))
        means = [peak * float(rng.uniform(0.1, 0.9)) for _ in range(int(rng.integers(1, 4)))]
        levels = [RoiLevel(peak, m, 16, m * float(rng.uniform(0.0, 0.8))) for m in means]
        dark_frames = int(rng.integers(0, 3))
        plan = plan_exposure(levels, noise, 200.0, cam, max_frames=5, dark_frames=dark_frames)
        evaluated = evaluate_plan(levels, noise, plan.exposures_s, cam, target_snr=200.0, dark_frames=dark_frames)
        assert evaluated.expected_pixel_snr is not None and plan.expected_pixel_snr is not None
        same = dataclasses.replace(evaluated, reached=plan.reached, expected_pixel_snr=plan.expected_pixel_snr,
                                   notes=plan.notes)  # fmt: skip
        assert same == plan


def test_a_floor_keeps_a_large_rois_frames_long_enough_to_see_its_pixels() -> None:
    from acquisition.exposure.snr import detection_exposure_s

    level = RoiLevel(1.5e5, 1.4e5, 28080, 1.3e5)  # a 156 x 180 px ROI of a lit tile
    cam = CameraTiming()
    short = plan_exposure(level, NOISE, 400.0, cam, dark_frames=1)
    # The mean reaches SNR 400 in a frame where a pixel at the mean has SNR ~2: most pixels are not detected.
    assert pixel_snr(level.mean_dn_per_s, NOISE, short.exposures_s, dark_frames=1)[()] < 3.0
    seen = detection_exposure_s([level], NOISE, 5.0, dark_frames=1)
    assert seen is not None and pixel_snr(level.mean_dn_per_s, NOISE, [seen], dark_frames=1)[()] == pytest.approx(5.0)
    lifted = plan_exposure(level, NOISE, 400.0, cam, dark_frames=1, shortest_s=seen)
    assert lifted.exposures_s == (cam.ceil(seen),) and lifted.reached and lifted.expected_snr > 400.0
    assert any("lengthened" in n for n in lifted.notes)
    # The floor never pushes a frame past what the peak allows, and changes nothing where frames are longer.
    capped = plan_exposure(level, NOISE, 400.0, cam, dark_frames=1, shortest_s=10.0)
    assert max(capped.exposures_s) * (level.peak_dn_per_s + NOISE.dark_current_e_per_s / NOISE.e_per_dn) <= (
        0.8 * NOISE.saturation_dn() * (1 + 1e-9)
    )
    assert plan_exposure(level, NOISE, 400.0, cam, dark_frames=1, shortest_s=1e-6) == short
    assert detection_exposure_s([RoiLevel.uniform(0.0, 4)], NOISE, 5.0) is None
    with pytest.raises(ValueError, match="shortest_s"):
        plan_exposure(level, NOISE, 400.0, cam, shortest_s=-1.0)
