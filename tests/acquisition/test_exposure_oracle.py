"""The fast exposure planner makes exactly the plans of the original one, kept here as the oracle.

The original searched the shortest exposure with a fixed 100-step bisection in log time and evaluated every
step with the numpy ``roi_snr``; the planner now stops the bisection where it stalls, starts it from a
closed-form bracket and evaluates a mean level in Python floats. Every plan of a grid of levels, targets,
cameras and options must come out identical, to the bit. The oracle keeps the original's arithmetic, not its
code: the merge variance with the frame kinds as an array axis, roi_snr as one path for every level, the
search as a bracket of (failing, passing) log times.
"""

import itertools
import math
import re
from collections.abc import Callable, Sequence

import numpy as np
import pytest

from acquisition.exposure import plan as plan_module
from acquisition.exposure.plan import plan_exposure
from acquisition.exposure.snr import (
    FloatArray,
    Frames,
    _dark_rate,
    _frames,
    _merged_variance,
    exposure_for_snr,
    roi_snr,
    single_exposure_min_snr,
    single_exposure_snr,
)
from acquisition.exposure.spec import CameraTiming, ExposureError, ExposurePlan, RoiLevel
from acquisition.noise import SensorNoise


def reference_merged_variance(
    rates: FloatArray, frames: Frames, noise: SensorNoise, gain: float, dark_frames: int, limit_dn: float
) -> FloatArray:
    """The merge variance as it was before its one-kind path, with the frame kinds as an array axis.

    Var X = sum_k [unclipped_k] n_k var_k / (gain sum_k [unclipped_k] n_k t_k)^2 per rate: each sum starts
    from zero and adds the kinds in order (the original loop's arithmetic), the square per pixel.
    """
    rg = np.asarray(rates, dtype=np.float64) * gain
    kinds = len(frames)
    t = np.array(list(frames), dtype=np.float64).reshape(kinds, 1)  # a row per kind against the rates
    n = np.array(list(frames.values())).reshape(kinds, 1)
    unclipped = (rg + _dark_rate(noise, gain)) * t <= limit_dn
    frame_dn2 = np.array([noise.variance_dn2(rg * tk, tk, gain) for tk in frames]).reshape(kinds, *rg.shape)
    var = n * frame_dn2
    if dark_frames:  # one dark mean is subtracted from each of a kind's n frames: n^2 times its variance
        dark_dn2 = np.array([noise.variance_dn2(0.0, tk, gain) for tk in frames]).reshape(kinds, 1)
        var = var + n * n * dark_dn2 / dark_frames
    num = np.add.reduce(np.where(unclipped, var, 0.0), axis=0, initial=0.0)
    total_t = np.add.reduce(np.where(unclipped, n * t, 0.0), axis=0, initial=0.0)
    out = np.full_like(rg, np.inf)
    np.divide(num, (gain * total_t) ** 2, out=out, where=total_t > 0)
    return out


def oracle_roi_snr(
    level: RoiLevel, noise: SensorNoise, exposures_s: Sequence[float], gain: float = 1.0, dark_frames: int = 0
) -> float:
    """The original roi_snr: every level through the numpy merge variance, the mean level too.

    mean / sqrt(sum_i w_i Var_i / n_pixels) over the level's pixel distribution; without one, over the mean
    level alone (weight 1) and the frames in which the peak does not clip. 0 for a zero mean, and where a
    weighted rate clips in every frame.
    """
    sat = noise.saturation_dn(gain)
    frames = _frames(exposures_s)
    if level.mean_dn_per_s == 0:
        return 0.0
    if not level.rates_dn_per_s:
        peak_dn_per_s = level.peak_dn_per_s * gain + _dark_rate(noise, gain)
        frames = {t: n for t, n in frames.items() if peak_dn_per_s * t <= sat}
    rates = level.rates_dn_per_s or (level.mean_dn_per_s,)
    weights = np.asarray(level.weights if level.rates_dn_per_s else (1.0,), dtype=float)
    var = reference_merged_variance(np.asarray(rates, dtype=float), frames, noise, gain, dark_frames, sat)
    if not np.all(np.isfinite(var[weights > 0])):
        return 0.0
    return level.mean_dn_per_s / math.sqrt(float(np.sum(weights * var)) / level.n_pixels)


def oracle_shortest(ok: Callable[[float], bool], cam: CameraTiming, t_hi: float, guess: float | None = None) -> float:
    """The original search: 100 halvings in log time, whatever the estimate."""
    shortest = cam.ceil(cam.min_exposure_s) or t_hi
    if ok(shortest):
        return shortest
    fails, passes = math.log(shortest), math.log(t_hi)  # ok is false at e^fails and true at e^passes
    for _ in range(100):
        mid = 0.5 * (fails + passes)
        fails, passes = (fails, mid) if ok(math.exp(mid)) else (mid, passes)
    found = cam.ceil(math.exp(passes))
    return found if found is not None and found <= t_hi and ok(found) else t_hi


def oracle_min_snr(
    levels: Sequence[RoiLevel], noise: SensorNoise, gain: float = 1.0, dark_frames: int = 0, stop_below: float = 0.0
) -> Callable[[float, int], float]:
    """The lowest channel's SNR of one exposure repeated, through the original roi_snr."""
    return lambda t, n: min(oracle_roi_snr(lv, noise, [t] * n, gain, dark_frames) for lv in levels)


def oracle_plan(monkeypatch: pytest.MonkeyPatch, *args: object, **kwargs: object) -> ExposurePlan:
    with monkeypatch.context() as m:
        m.setattr(plan_module, "_shortest", oracle_shortest)
        m.setattr(plan_module, "roi_snr", oracle_roi_snr)
        m.setattr(plan_module, "single_exposure_min_snr", oracle_min_snr)
        return plan_exposure(*args, **kwargs)  # type: ignore[arg-type]


NOISES = [SensorNoise(), SensorNoise(e_per_dn=1.5, read_noise_e=12.0, full_well_e=20000.0, dark_current_e_per_s=40.0)]
CAMERAS = [
    CameraTiming(1e-5, 30.0),
    CameraTiming(1e-4, 2.0, gain=4.0, overhead_s=0.05),
    CameraTiming(1e-5, 30.0, steps=tuple(2.0 ** (k / 3) * 1e-5 for k in range(70))),
]


def level_grid() -> list[list[RoiLevel]]:
    """ROI levels from 1 to 1e7 counts/s: one grey level, three channels (one near dark), a distribution."""
    grid: list[list[RoiLevel]] = []
    for peak, n_px in itertools.product(np.geomspace(1.0, 1e7, 9), (1, 400)):
        p = float(peak)
        grid.append([RoiLevel(p, 0.7 * p, n_px)])
        grid.append([RoiLevel(p, 0.9 * p, n_px, 0.4 * p), RoiLevel(p, 0.5 * p, n_px, 0.2 * p),
                     RoiLevel(p, 0.02 * p, n_px, 0.01 * p)])  # fmt: skip
        grid.append([RoiLevel(p, 0.55 * p, n_px, 0.1 * p, (0.1 * p, 0.5 * p, p), (0.25, 0.5, 0.25))])
    return grid


#: (target ROI SNR, dark frames, max_total_s); each level meets one in turn (the oracle is slow: few levels).
OPTIONS = [(50.0, 0, None), (400.0, 0, None), (1000.0, 2, None), (300.0, 0, 1.5), (5000.0, 1, None)]


@pytest.mark.parametrize("noise", NOISES, ids=["default", "noisy"])
@pytest.mark.parametrize("cam", CAMERAS, ids=["continuous", "gain4", "stepped"])
def test_plans_equal_the_original_planners(
    monkeypatch: pytest.MonkeyPatch, noise: SensorNoise, cam: CameraTiming
) -> None:
    compared = 0
    for i, levels in enumerate(level_grid()):
        target, dark_frames, budget = OPTIONS[i % len(OPTIONS)]
        kwargs = {"dark_frames": dark_frames, "max_frames": 16, "max_total_s": budget}
        try:
            expected = oracle_plan(monkeypatch, levels, noise, target, cam, **kwargs)
        except ExposureError as exc:
            with pytest.raises(ExposureError, match=re.escape(str(exc))):
                plan_exposure(levels, noise, target, cam, **kwargs)  # type: ignore[arg-type]
            continue
        got = plan_exposure(levels, noise, target, cam, **kwargs)  # type: ignore[arg-type]
        assert got == expected, (levels, target, dark_frames, budget)
        compared += 1
    assert compared >= 40  # most of the grid plans something (the brightest levels saturate some cameras)


def test_pixel_snr_target_plans_equal_the_original(monkeypatch: pytest.MonkeyPatch) -> None:
    noise = NOISES[0]
    for levels in level_grid()[1::6]:
        expected = oracle_plan(monkeypatch, levels, noise, 200.0, CAMERAS[0], pixel_snr_target=20.0, max_frames=24)
        assert plan_exposure(levels, noise, 200.0, CAMERAS[0], pixel_snr_target=20.0, max_frames=24) == expected


@pytest.mark.parametrize("dark_frames", [0, 1, 3])
@pytest.mark.parametrize("n", [1, 2, 7])
def test_exposure_for_snr_reaches_the_target_exactly(dark_frames: int, n: int) -> None:
    noise = NOISES[1]
    for mean, n_px, gain in itertools.product((3.0, 400.0, 2e5), (1, 25), (1.0, 4.0)):
        level = RoiLevel(mean, mean, n_px)
        t = exposure_for_snr(level, noise, 150.0, n, gain, dark_frames)
        assert t is not None
        # Far below saturation the closed form is the root of roi_snr itself (its clipping check aside).
        big = SensorNoise(e_per_dn=noise.e_per_dn, read_noise_e=noise.read_noise_e, full_well_e=1e30,
                          dark_current_e_per_s=noise.dark_current_e_per_s, white_level_dn=1e30)  # fmt: skip
        assert roi_snr(level, big, [t] * n, gain, dark_frames) == pytest.approx(150.0, rel=1e-9)
    assert exposure_for_snr(RoiLevel(5.0, 0.0, 4), noise, 100.0, 1) is None


def test_scalar_mean_level_snr_matches_the_numpy_merge_bit_for_bit() -> None:
    rng = np.random.default_rng(3)
    for noise, _ in itertools.product(NOISES, range(40)):
        peak = float(10 ** rng.uniform(0, 6))
        level = RoiLevel(peak, peak * float(rng.uniform(0.01, 1)), int(rng.integers(1, 500)))
        ts = list(10 ** rng.uniform(-5, 0, size=int(rng.integers(1, 5))))
        gain, darks = float(rng.choice([1.0, 2.5])), int(rng.integers(0, 3))
        assert roi_snr(level, noise, ts, gain, darks) == oracle_roi_snr(level, noise, ts, gain, darks)


def test_single_exposure_snr_matches_roi_snr_bit_for_bit() -> None:
    rng = np.random.default_rng(11)
    for noise, _ in itertools.product(NOISES, range(200)):
        peak = float(10 ** rng.uniform(0, 7))
        level = RoiLevel(peak, peak * float(rng.choice([0.0, rng.uniform(0.01, 1), 1.0])), int(rng.integers(1, 500)))
        gain, darks = float(rng.choice([1.0, 2.5, 4.0])), int(rng.integers(0, 3))
        snr = single_exposure_snr(level, noise, gain, darks)
        for t in 10 ** rng.uniform(-6, 1, size=8):  # some clip the peak, some the mean, most neither
            n = int(rng.integers(1, 8))
            assert snr(float(t), n) == oracle_roi_snr(level, noise, [float(t)] * n, gain, darks)
    spread = RoiLevel(100.0, 55.0, 4, 10.0, (10.0, 50.0, 100.0), (0.25, 0.5, 0.25))
    assert single_exposure_snr(spread, NOISES[0])(0.5, 3) == roi_snr(spread, NOISES[0], [0.5] * 3)


def test_single_exposure_min_snr_matches_roi_snr_bit_for_bit() -> None:
    rng = np.random.default_rng(12)
    for noise, _ in itertools.product(NOISES, range(150)):
        peak = float(10 ** rng.uniform(0, 7))
        levels = [RoiLevel(peak, peak * float(rng.choice([rng.uniform(0.01, 1), 1.0])), int(rng.integers(1, 500)))
                  for _ in range(int(rng.integers(1, 4)))]  # fmt: skip
        gain, darks = float(rng.choice([1.0, 2.5, 4.0])), int(rng.integers(0, 3))
        lowest = single_exposure_min_snr(levels, noise, gain, darks)
        for t in 10 ** rng.uniform(-6, 1, size=6):
            n = int(rng.integers(1, 8))
            want = min(oracle_roi_snr(lv, noise, [float(t)] * n, gain, darks) for lv in levels)
            assert lowest(float(t), n) == want
            target = float(rng.uniform(0, 2 * want)) if want > 0 else 1.0
            short = single_exposure_min_snr(levels, noise, gain, darks, stop_below=target)
            assert (short(float(t), n) >= target) == (want >= target)
    dark = [RoiLevel(5.0, 0.0, 4), RoiLevel(100.0, 55.0, 4, 10.0, (10.0, 50.0, 100.0), (0.25, 0.5, 0.25))]
    assert single_exposure_min_snr(dark, NOISES[0])(0.5, 3) == 0.0
    assert single_exposure_min_snr(dark[1:], NOISES[0])(0.5, 3) == roi_snr(dark[1], NOISES[0], [0.5] * 3)


def test_geomspace_shortcut_equals_numpy() -> None:
    from acquisition.exposure.snr import _geomspace

    rng = np.random.default_rng(8)
    for _ in range(3000):
        lo = float(10 ** rng.uniform(-9, 7))
        hi = lo * float(10 ** rng.uniform(0, 9)) if rng.random() < 0.95 else lo
        num = int(rng.choice([2, 3, 48, 49]))
        assert _geomspace(lo, hi, num) == np.geomspace(lo, hi, num).tolist(), (lo, hi, num)
    assert _geomspace(5.0, 5.0, 48) == np.geomspace(5.0, 5.0, 48).tolist()
    assert _geomspace(1e-300, 1e300, 48) == np.geomspace(1e-300, 1e300, 48).tolist()


def test_one_kind_merge_variance_equals_the_general_loop_bit_for_bit() -> None:
    rng = np.random.default_rng(21)
    edges = np.array([0.0, -0.0, -5.0, 5e-324, 1e-300, 1.0, 1e6, 1e300, np.inf, -np.inf, np.nan])
    for noise, _ in itertools.product(NOISES, range(300)):
        rates = np.concatenate([10 ** rng.uniform(-3, 8, size=int(rng.integers(1, 150))), edges])
        t = float(rng.choice([float(10 ** rng.uniform(-6, 1)), 5e-324, 1e300, 0.0]))
        frames = {t: int(rng.integers(1, 9))}
        gain, darks = float(rng.choice([1.0, 2.5, 4.0, 1e-3])), int(rng.integers(0, 4))
        sat = float(rng.choice([noise.saturation_dn(gain), 1e300, 0.0]))
        with np.errstate(all="ignore"):
            want = reference_merged_variance(rates, frames, noise, gain, darks, sat)
            got = _merged_variance(rates, frames, noise, gain, darks, sat)
        assert got.tobytes() == want.tobytes(), (t, frames, gain, darks, sat)


@pytest.mark.parametrize("t", [1e-3, 1e-300, 1e300])
def test_one_kind_merge_variance_warns_as_before(t: float) -> None:
    import warnings

    rates, frames, sat = np.array([1.0, 1e308, 50.0, np.nan]), {t: 2}, NOISES[0].saturation_dn(1.0)
    caught = []
    for variance in (reference_merged_variance, _merged_variance):
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            out = variance(rates, frames, NOISES[0], 1.0, 1, sat)
        caught.append(([str(w.message) for w in seen], out.tobytes()))
    assert caught[0] == caught[1]
