"""The linear HDR merge against scenes of known radiance taken through the simulated sensor."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from acquisition.frame import Frame, FrameError
from acquisition.hdr.merge import HdrFlag, measure_saturation, merge_linear
from acquisition.noise import SensorNoise
from simulator.camera.sensor import capture, capture_bracket, dark_frame

NOISE = SensorNoise()  # 4 e-/DN, 3 e- read noise, black 512, 14-bit, full well 15000 DN (below the ADC's 15871)
EXPOSURES = [0.001 * 4.0**k for k in range(5)]  # 2 stops apart, 1 ms .. 256 ms


def log_scene(shape: tuple[int, ...], lo: float, hi: float, seed: int = 0) -> np.ndarray:
    """Radiance (counts/s) log-uniform between lo and hi."""
    rng = np.random.default_rng(seed)
    return np.exp(rng.uniform(np.log(lo), np.log(hi), shape))


def mean_darks(noise: SensorNoise, exposures: list[float]) -> dict[float, float]:
    """The exact mean dark level (counts) per exposure: a noise-free master dark."""
    return {t: noise.black_level_dn + noise.dark_current_e_per_s * t / noise.e_per_dn for t in exposures}


def z_scores(scene: np.ndarray, seeds: range, **merge_kw: object) -> np.ndarray:
    zs = []
    for seed in seeds:
        frames = capture_bracket(scene, NOISE, EXPOSURES, seed)
        darks = {t: dark_frame(scene.shape, NOISE, t, 1000 + seed) for t in EXPOSURES}
        img = merge_linear(frames, NOISE, darks=darks, **merge_kw)  # type: ignore[arg-type]
        assert not img.flags.any()
        zs.append(((img.radiance - scene) / img.std_error).ravel())
    return np.concatenate(zs)


@pytest.mark.parametrize("weighting", ["sum", "inverse_variance"])
def test_merge_recovers_radiance_within_its_reported_error(weighting: str) -> None:
    # 4 decades, every pixel well above the dark threshold in the longest frame and below saturation
    # in the shortest: the z-scores of all pixels must be standard normal.
    scene = log_scene((96, 96, 3), 200.0, 1e7)
    z = z_scores(scene, range(3), weighting=weighting)
    assert abs(z.mean()) < 0.03
    assert abs(z.std() - 1.0) < 0.02
    assert 0.9955 < np.mean(np.abs(z) < 3.0) < 0.9985  # 99.73 % for a standard normal


def test_variance_matches_the_scatter_over_repeated_captures() -> None:
    levels = np.geomspace(50.0, 1.2e7, 48).reshape(6, 8)  # from read-noise limited to the shortest frame only
    estimates, variances = [], []
    for seed in range(300):
        frames = capture_bracket(levels, NOISE, EXPOSURES, seed)
        img = merge_linear(frames, NOISE, darks=mean_darks(NOISE, EXPOSURES), saturation_dn=15000.0)
        estimates.append(img.radiance)
        variances.append(img.variance)
    empirical = np.var(np.array(estimates, dtype=np.float64), axis=0, ddof=1)
    reported = np.mean(np.array(variances, dtype=np.float64), axis=0)
    ratio = empirical / reported
    # One pixel's sample variance over 300 captures has a relative standard error of sqrt(2/299) = 8 %.
    assert np.all(np.abs(ratio - 1) < 0.3), ratio
    assert abs(ratio.mean() - 1) < 0.05
    bias = np.mean(np.array(estimates, dtype=np.float64), axis=0) / levels - 1
    assert np.all(np.abs(bias) < 4 * np.sqrt(reported / 300) / levels + 1e-6)


def reference_merge(frames: list[Frame], thresholds: tuple[float, ...], offsets: list[float]) -> np.ndarray:
    """X = sum(s_k - dark_k) / sum(t_k g_k) over the frames below their threshold, in plain numpy."""
    num = np.zeros(frames[0].shape)
    den = np.zeros(frames[0].shape)
    for f, thr, off in zip(frames, thresholds, offsets, strict=True):
        s = f.data.astype(np.float64)
        ok = s - float(f.black_level) < thr  # type: ignore[arg-type]
        num += np.where(ok, s - off, 0.0)
        den += np.where(ok, f.exposure_s * f.gain, 0.0)
    return num / den


def test_sum_merge_is_the_formula() -> None:
    scene = log_scene((40, 30, 3), 100.0, 5e6, seed=3)
    frames = capture_bracket(scene, NOISE, EXPOSURES, 11)
    darks = mean_darks(NOISE, EXPOSURES)
    img = merge_linear(frames, NOISE, darks=darks, weighting="sum")
    thresholds = img.metadata["saturation_threshold_dn"]
    expected = reference_merge(frames, thresholds, [darks[t] for t in EXPOSURES])  # type: ignore[arg-type]
    np.testing.assert_allclose(img.radiance, expected, rtol=1e-6)
    assert img.metadata["weighting"] == "sum"
    assert img.exposures_s == tuple(EXPOSURES)


def test_input_order_and_gain_do_not_matter() -> None:
    scene = log_scene((30, 30), 1e3, 1e6, seed=4)
    settings = [(0.02, 1.0), (0.001, 4.0), (0.004, 2.0)]  # (exposure_s, gain)
    frames = [capture(scene, NOISE, t, 20 + i, gain=g) for i, (t, g) in enumerate(settings)]
    img = merge_linear(frames, NOISE, weighting="sum", saturation_dn=15000.0)
    shuffled = merge_linear(frames[::-1], NOISE, weighting="sum", saturation_dn=15000.0)
    np.testing.assert_allclose(img.radiance, shuffled.radiance, rtol=1e-6)
    assert img.exposures_s == (0.02, 0.001, 0.004)
    z = (img.radiance - scene) / img.std_error
    assert abs(z.mean()) < 0.1 and abs(z.std() - 1) < 0.1


def test_saturated_and_dark_in_every_frame_are_flagged() -> None:
    scene = log_scene((32, 32), 1e3, 1e6, seed=5)
    scene[:, 0] = 1e12  # saturated even in the 1 ms frame
    scene[:, 1] = 0.0  # no light at all
    frames = capture_bracket(scene, NOISE, EXPOSURES, 6)
    img = merge_linear(frames, NOISE, darks=mean_darks(NOISE, EXPOSURES))
    sat, dark = img.saturated, img.dark
    assert sat[:, 0].all() and not sat[:, 1:].any()
    assert np.array_equal(img.flags[:, 0], np.full(32, int(HdrFlag.SATURATED), np.uint8))
    assert np.all(img.frames_used[:, 0] == 0) and np.all(np.isinf(img.variance[:, 0]))
    # A lower bound: at least the saturation threshold over the shortest exposure, far below the truth.
    threshold = img.metadata["saturation_threshold_dn"][0]  # type: ignore[index]
    assert np.all(img.radiance[:, 0] >= threshold / EXPOSURES[0])
    assert np.all(img.radiance[:, 0] < 1e12)
    assert dark[:, 1].all()  # zero signal is below 3 sigma in the longest frame (with 99.87 % probability each)
    assert np.all(np.isfinite(img.variance[:, 1])) and np.all(img.frames_used[:, 1] == len(EXPOSURES))
    assert abs(float(img.radiance[:, 1].mean())) < 4 * float(np.sqrt(img.variance[:, 1].mean() / 32))
    assert not img.flags[:, 2:].any()


def test_measure_saturation_finds_a_full_well_clip_below_the_adc() -> None:
    scene = log_scene((64, 64), 1e4, 1e8, seed=7)
    frames = capture_bracket(scene, NOISE, EXPOSURES, 8)
    level = measure_saturation(frames)
    assert level is not None and abs(level - 15000.0) < 1.0  # full well 60000 e- / 4 e-/DN, not 16383 - 512
    adc_limited = SensorNoise(full_well_e=1e6)
    level = measure_saturation(capture_bracket(scene, adc_limited, EXPOSURES, 8))
    assert level == 16383 - 512
    dim = capture_bracket(log_scene((64, 64), 10.0, 1e3), NOISE, EXPOSURES, 9)
    assert measure_saturation(dim) is None
    img = merge_linear(dim, NOISE)
    assert img.metadata["saturation_source"] == {1.0: "noise model (no clipped plateau in the data)"}


def test_trusting_the_white_level_biases_pixels_clipped_at_full_well() -> None:
    # 20000 counts/s: 20000 DN in the 1 s frame, which clips at 15000 DN (full well), below white (15871).
    scene = np.full((40, 40), 20000.0)
    exposures = [0.25, 1.0]
    frames = capture_bracket(scene, NOISE, exposures, 10)
    measured = merge_linear(frames, NOISE, darks=mean_darks(NOISE, exposures))
    blind = merge_linear(frames, NOISE, darks=mean_darks(NOISE, exposures), saturation_dn=16383.0 - 512.0)
    assert measured.metadata["saturation_source"] == {1.0: "measured from the data"}
    assert np.all(measured.frames_used == 1)
    assert abs(measured.radiance.mean() / 20000.0 - 1) < 0.002
    assert blind.radiance.mean() / 20000.0 - 1 < -0.15  # (15000 + 5000) / 1.25 s = 16000 counts/s


def test_dark_current_biases_dim_pixels_without_darks() -> None:
    hot = SensorNoise(dark_current_e_per_s=400.0)  # 100 DN/s of dark signal
    scene = np.full((64, 64), 300.0)  # dim: 300 counts/s
    exposures = [0.25, 0.5, 1.0]
    frames = capture_bracket(scene, hot, exposures, 12)
    darks = {t: [dark_frame(scene.shape, hot, t, 100 + i + 10 * j) for j in range(4)] for i, t in enumerate(exposures)}
    with_darks = merge_linear(frames, hot, darks=darks)
    without = merge_linear(frames, hot)
    se = float(np.sqrt(with_darks.variance.mean() / scene.size))
    assert abs(with_darks.radiance.mean() - 300.0) < 4 * se
    # Without darks the dark signal adds 400 e-/s / 4 e-/DN = 100 counts/s.
    assert abs(without.radiance.mean() - 400.0) < 4 * se
    assert with_darks.metadata["darks_used"] is True
    assert with_darks.metadata["darks"] == ("4 dark frames averaged",) * 3
    assert without.metadata["darks_used"] is False
    assert str(without.metadata["darks"]).startswith("none: black level subtracted")
    # Four dark frames averaged: their noise (a quarter of one frame's) is in the variance.
    one = merge_linear(frames, hot, darks={t: d[0] for t, d in darks.items()})
    assert np.all(one.variance > with_darks.variance)


def test_inverse_variance_pass_lowers_the_error_when_read_noise_is_high() -> None:
    noisy = SensorNoise(read_noise_e=40.0)
    scene = log_scene((48, 48), 20.0, 2e4, seed=13)
    err = {"sum": [], "inverse_variance": []}  # type: dict[str, list[np.ndarray]]
    for seed in range(8):
        frames = capture_bracket(scene, noisy, EXPOSURES, seed)
        for weighting, errors in err.items():
            img = merge_linear(frames, noisy, darks=mean_darks(noisy, EXPOSURES), weighting=weighting)  # type: ignore[arg-type]
            errors.append((img.radiance / scene - 1)[img.flags == 0])
    rms = {w: float(np.sqrt(np.mean(np.concatenate(e) ** 2))) for w, e in err.items()}
    assert rms["inverse_variance"] < 0.85 * rms["sum"], rms
    auto = merge_linear(frames, noisy)
    assert auto.metadata["weighting"] == "inverse_variance"
    assert str(auto.metadata["weighting_reason"]).startswith("auto:")
    # A bright scene on a quiet sensor: shot noise dominates every frame used, the sum merge is kept.
    bright = capture_bracket(log_scene((48, 48), 1e5, 1e7, seed=14), NOISE, EXPOSURES, 15)
    assert merge_linear(bright, NOISE).metadata["weighting"] == "sum"


def test_raw_mosaic_with_black_level_per_cfa_site() -> None:
    scene = log_scene((32, 32, 3), 1e3, 1e6, seed=16)
    blacks = (500.0, 512.0, 520.0, 530.0)  # R, G, G, B of RGGB, row-major
    offsets = np.tile(np.array(blacks).reshape(2, 2) - NOISE.black_level_dn, (16, 16))
    frames = []
    for i, t in enumerate(EXPOSURES):
        f = capture(scene, NOISE, t, 30 + i, kind="raw")
        shifted = (f.data.astype(np.float64) + offsets).astype(np.uint16)
        frames.append(dataclasses.replace(f, data=shifted, black_level=blacks))
    img = merge_linear(frames, NOISE, saturation_dn=15000.0)
    truth = np.empty((32, 32))
    for pos, ch in enumerate((0, 1, 1, 2)):
        dy, dx = divmod(pos, 2)
        truth[dy::2, dx::2] = scene[dy::2, dx::2, ch]
    z = (img.radiance - truth) / img.std_error
    assert img.metadata["kind"] == "raw" and img.metadata["cfa_pattern"] == "RGGB"
    assert abs(z.mean()) < 0.15 and abs(z.std() - 1) < 0.1


def test_float_frames_give_the_same_merge_as_integer_frames() -> None:
    scene = log_scene((20, 20, 3), 1e3, 1e6, seed=17)
    frames = capture_bracket(scene, NOISE, EXPOSURES, 18)
    as_float = [dataclasses.replace(f, data=f.data.astype(np.float64)) for f in frames]
    a = merge_linear(frames, NOISE, saturation_dn=15000.0)
    b = merge_linear(as_float, NOISE, saturation_dn=15000.0)
    np.testing.assert_allclose(a.radiance, b.radiance, rtol=1e-6)
    np.testing.assert_array_equal(a.flags, b.flags)


# ------------------------------------------------------------------------------------------------------------
# Bad input


def small_bracket() -> list[Frame]:
    return capture_bracket(np.full((4, 5), 1e4), NOISE, [0.001, 0.004, 0.016], 0)


def test_empty_bracket() -> None:
    with pytest.raises(FrameError, match="empty bracket"):
        merge_linear([], NOISE)


def test_mismatched_shapes_name_the_frame() -> None:
    frames = small_bracket()
    frames[2] = capture(np.full((4, 6), 1e4), NOISE, 0.016, 0)
    with pytest.raises(FrameError, match=r"frame 2 \(simulated, 0.016 s\) has shape \(4, 6\) but frame 0 .* \(4, 5\)"):
        merge_linear(frames, NOISE)


def test_non_positive_exposure_names_the_frame() -> None:
    frames = small_bracket()
    with pytest.raises(FrameError, match="exposure_s"):
        dataclasses.replace(frames[1], exposure_s=0.0)  # Frame itself refuses it ...
    object.__setattr__(frames[1], "exposure_s", 0.0)  # ... so corrupt one to test the merge's own check
    with pytest.raises(FrameError, match=r"frame 1 .*exposure_s = 0.0"):
        merge_linear(frames, NOISE)


def test_mixed_kinds_name_the_frame() -> None:
    frames = small_bracket()
    frames[1] = dataclasses.replace(frames[1], kind="raw", cfa_pattern="RGGB", source="/data/b.dng")
    with pytest.raises(FrameError, match=r"frame 1 \(/data/b.dng\) is kind 'raw' but frame 0 .* is kind 'linear'"):
        merge_linear(frames, NOISE)


def test_8bit_frames_are_sent_to_the_8bit_path() -> None:
    frames = capture_bracket(np.full((4, 5), 1e4), NOISE, [0.001, 0.004], 0, kind="8bit")
    with pytest.raises(FrameError, match="merge_8bit"):
        merge_linear(frames, NOISE)


def test_missing_or_wrong_darks() -> None:
    frames = small_bracket()
    with pytest.raises(FrameError, match=r"frame 2 .*no dark for exposure 0.016 s"):
        merge_linear(frames, NOISE, darks={0.001: 512.0, 0.004: 512.0})
    wrong = {t: dark_frame((4, 4), NOISE, t, 0) for t in (0.001, 0.004, 0.016)}
    with pytest.raises(FrameError, match=r"dark 0 for 0.001 s .* has shape \(4, 4\)"):
        merge_linear(frames, NOISE, darks=wrong)
    with pytest.raises(FrameError, match=r"frame 3: expected an acquisition\.frame\.Frame, got str"):
        merge_linear([*frames, "frame.dng"], NOISE)  # type: ignore[list-item]


@pytest.mark.parametrize("bad", [np.nan, np.inf])
@pytest.mark.parametrize("form", ["frame", "averaged"])
def test_a_dark_with_non_finite_counts_is_refused_naming_it(bad: float, form: str) -> None:
    # Once accepted silently: a quarter of a run's dark frame NaN moved its reading 40 % up, with no flag.
    frames = small_bracket()
    darks: dict[float, object] = {}
    for t in (0.001, 0.004, 0.016):
        d = dark_frame(frames[0].shape, NOISE, t, 0)
        spoiled = np.array(d.data, dtype=np.float32)
        if t == 0.004:
            spoiled[0, :3] = bad
        d = dataclasses.replace(d, data=spoiled)
        darks[t] = d if form == "frame" else [d, d]
    size = frames[0].data.size
    with pytest.raises(FrameError, match=rf"dark 0 for 0.004 s .* has 3 non-finite pixel values of {size}"):
        merge_linear(frames, NOISE, darks=darks)  # type: ignore[arg-type]


def test_bad_parameters() -> None:
    frames = small_bracket()
    with pytest.raises(ValueError, match="weighting"):
        merge_linear(frames, NOISE, weighting="median")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="saturation_dn"):
        merge_linear(frames, NOISE, saturation_dn=-1.0)


@pytest.mark.parametrize("level", [2.0, 5.0])
def test_inverse_variance_weights_do_not_follow_a_pixels_own_noise(level: float) -> None:
    # At low signal the weights once came from each pixel's own first pass and read high (2 counts/s: +0.3 %,
    # 10 standard errors on a million pixels). Weights from the neighbours leave the mean unbiased.
    noise = dataclasses.replace(SensorNoise(), dark_current_e_per_s=0.0)  # no darks: dark current biases both
    frames = capture_bracket(np.full((1000, 1000), level), noise, (0.5, 2.0), rng=7)
    iv = merge_linear(frames, noise, weighting="inverse_variance")
    plain = merge_linear(frames, noise, weighting="sum")
    for img in (iv, plain):
        r = img.radiance.astype(np.float64)
        z = (r.mean() - level) / (r.std() / np.sqrt(r.size))
        assert abs(z) < 4.0, (img.metadata["weighting"], z)
    # ... and it is still the better estimator: its spread is below the sum's, as its variances say.
    assert iv.radiance.std() < plain.radiance.std()
    np.testing.assert_allclose(np.mean(iv.variance), np.var(iv.radiance.astype(np.float64)), rtol=0.05)
    assert merge_linear(frames, noise).metadata["weighting"] == "inverse_variance"  # what auto picks here


def test_frames_below_their_black_level_are_flagged_not_read_as_negative_light() -> None:
    noise = SensorNoise()
    frames = capture_bracket(np.full((8, 8), 100.0), noise, (0.007, 0.028), rng=1)
    below = [dataclasses.replace(f, data=np.zeros_like(f.data)) for f in frames]  # 512 DN under black
    img = merge_linear(below, noise)
    assert np.all(img.radiance < -10_000)  # the estimate as computed ...
    assert np.all(img.below_black) and np.all(img.dark)  # ... flagged: no radiance reads like this
    fine = merge_linear(capture_bracket(np.zeros((64, 64)), noise, (0.01, 0.04), rng=2), noise)
    assert not fine.below_black.any() and fine.dark.mean() > 0.9  # zero light: dark, not below black


def test_the_roi_counts_dark_pixels_and_a_dark_roi_says_so() -> None:
    from acquisition.roi import reduce_roi

    noise = SensorNoise()
    img = merge_linear(capture_bracket(np.zeros((16, 16)), noise, (0.01, 0.04), rng=3), noise)
    reading = reduce_roi(img.radiance, img.variance, (0, 0, 16, 16), flags=img.saturated, dark=img.dark)
    assert int(reading.n_dark) == 256 and reading.dark
    lit = merge_linear(capture_bracket(np.full((16, 16), 5e4), noise, (0.01, 0.04), rng=3), noise)
    reading = reduce_roi(lit.radiance, lit.variance, (0, 0, 16, 16), flags=lit.saturated, dark=lit.dark)
    assert int(reading.n_dark) == 0 and not reading.dark


@pytest.mark.parametrize(("read_noise_e", "chosen"), [(3.0, "sum"), (40.0, "inverse_variance")])
def test_auto_weighting_gives_the_forced_merges_numbers_and_decides_as_on_a_second_sum_pass(
    read_noise_e: float, chosen: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A small image (every pixel in the weighting sample) reuses the sample's sum pass as the merge's own,
    # and the inverse-variance prediction weights by that pass: the same bits as running each afresh.
    import acquisition.hdr.merge as merge_module
    from acquisition.hdr.merge import IV_FRACTION, IV_GAIN, _decide_weighting
    from acquisition.hdr.prepared import _Prepared

    noise = SensorNoise(read_noise_e=read_noise_e)
    scene = log_scene((12, 12, 3), *((1e5, 1e7) if chosen == "sum" else (20.0, 2e4)), seed=21)
    frames = capture_bracket(scene, noise, EXPOSURES, 22)
    darks = {t: [dark_frame(scene.shape, noise, t, 30 + k)] for k, t in enumerate(EXPOSURES)}
    auto = merge_linear(frames, noise, darks=darks)
    assert auto.metadata["weighting"] == chosen
    forced = merge_linear(frames, noise, darks=darks, weighting=chosen)  # type: ignore[arg-type]
    for name in ("radiance", "variance", "flags", "frames_used"):
        assert np.array_equal(getattr(auto, name), getattr(forced, name)), name
    captured: list[_Prepared] = []
    original = _decide_weighting

    def spy(prep: _Prepared) -> object:
        captured.append(prep)
        return original(prep)

    monkeypatch.setattr(merge_module, "_decide_weighting", spy)
    merge_linear(frames, noise, darks=darks)
    prep = captured[0]
    _, var_sum, flags, _ = prep.run(False)
    _, var_iv, _, _ = prep.run(True)  # its own sum pass inside, as the decision ran before
    ok = flags == 0
    fraction = float(np.mean(np.sqrt(var_sum[ok].astype(np.float64) / var_iv[ok]) - 1.0 > IV_GAIN))
    assert (fraction >= IV_FRACTION) == (chosen == "inverse_variance")
    assert f"for {fraction:.2%} of" in str(auto.metadata["weighting_reason"])
