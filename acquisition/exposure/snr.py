"""What a set of frames achieves: the variance and SNR of the linear merge, per pixel and for an ROI mean.

Computed from ``SensorNoise`` the way the linear merge ``X = sum_k (s_k - dark_k) / sum_k t_k`` over a
pixel's unsaturated frames achieves it; the derivation is in ``acquisition.exposure.plan``. Rates are in counts/s
above black at gain 1, exposures in seconds.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt

from acquisition.exposure.spec import RoiLevel
from acquisition.noise import SensorNoise

FloatArray = npt.NDArray[np.float64]
Frames = dict[float, int]
"""Frames to merge: exposure in seconds -> how many frames of it."""


def _frames(exposures_s: Sequence[float]) -> Frames:
    out: Frames = {}
    for t in exposures_s:
        out[float(t)] = out.get(float(t), 0) + 1
    return out


def _dark_rate(noise: SensorNoise, gain: float) -> float:
    """Dark current in counts/s at ``gain``: it fills the well alongside the signal."""
    return noise.dark_current_e_per_s * gain / noise.e_per_dn


def _merged_variance(
    rates: FloatArray, frames: Frames, noise: SensorNoise, gain: float, dark_frames: int, limit_dn: float
) -> FloatArray:
    """Variance in (counts/s)^2 of the linear merge per rate; inf where every frame clips (mean above limit)."""
    rates = np.asarray(rates, dtype=np.float64)
    rg = rates * gain  # counts/s the sensor delivers at this gain
    if len(frames) == 1:
        ((t, n),) = frames.items()
        if n * t > 0:
            return _one_kind_variance(rg, t, n, noise, gain, dark_frames, limit_dn)
    num = np.zeros_like(rates)
    total_t = np.zeros_like(rates)
    dr = _dark_rate(noise, gain)
    for t, n in frames.items():
        used = (rg + dr) * t <= limit_dn
        var = n * noise.variance_dn2(rg * t, t, gain)
        if dark_frames:
            var = var + n * n * noise.variance_dn2(0.0, t, gain) / dark_frames
        num += np.where(used, var, 0.0)
        total_t += np.where(used, n * t, 0.0)
    out = np.full_like(rates, np.inf)
    np.divide(num, (gain * total_t) ** 2, out=out, where=total_t > 0)  # the merge divides by sum(t g)
    return out


def _one_kind_variance(
    rg: FloatArray, t: float, n: int, noise: SensorNoise, gain: float, dark_frames: int, limit_dn: float
) -> FloatArray:
    """``_merged_variance`` of ``n`` frames of ``t`` seconds (n t > 0): the same bits in fewer numpy steps.

    The general loop adds each kind's terms to zeros (0.0 + x is x: the variances are positive or inf) and
    squares ``gain * (0.0 + n t)`` per pixel; here the sums are the terms and the square is one Python float
    (x * x, as numpy's square). The planner's per-pixel check asks this once a plan, most of them one kind.
    """
    used = (rg + _dark_rate(noise, gain)) * t <= limit_dn
    var = n * noise.variance_dn2(rg * t, t, gain)
    if dark_frames:
        var = var + n * n * noise.variance_dn2(0.0, t, gain) / dark_frames
    scale = gain * (n * t)
    out = np.full_like(rg, np.inf)
    np.divide(var, scale * scale, out=out, where=used)
    return out


def roi_snr(
    level: RoiLevel, noise: SensorNoise, exposures_s: Sequence[float], gain: float = 1.0, dark_frames: int = 0
) -> float:
    """SNR of the ROI mean reading (dimensionless) that the linear merge of these frames achieves.

    With a pixel distribution on ``level`` it is exact under the noise model (each level uses the frames in
    which it does not clip); without one it is computed at the mean level from the frames in which the
    peak does not clip, a lower bound when other frames saturate part of the ROI.
    """
    frames = _frames(exposures_s)
    sat = noise.saturation_dn(gain)
    if level.mean_dn_per_s == 0:
        return 0.0
    if level.rates_dn_per_s:
        r = np.asarray(level.rates_dn_per_s, dtype=float)
        w = np.asarray(level.weights, dtype=float)
    else:
        dr = _dark_rate(noise, gain)
        frames = {t: n for t, n in frames.items() if (level.peak_dn_per_s * gain + dr) * t <= sat}
        return _mean_level_snr(level, frames, noise, gain, dark_frames, sat, dr)
    var = _merged_variance(r, frames, noise, gain, dark_frames, sat)
    if not np.all(np.isfinite(var[w > 0])):
        return 0.0  # part of the ROI clips in every frame: the mean is not measurable
    var_mean = float(np.sum(w * var)) / level.n_pixels
    return level.mean_dn_per_s / math.sqrt(var_mean)


def _mean_level_snr(
    level: RoiLevel, frames: Frames, noise: SensorNoise, gain: float, dark_frames: int, sat: float, dr: float
) -> float:
    """``roi_snr`` at the mean level alone, in Python floats: the planner's bisection calls it ~150 times a plan.

    The same operations in the same order as ``_merged_variance`` on a one-element array, so the same bits
    (IEEE arithmetic and sqrt are correctly rounded in numpy and in Python alike), without numpy's per-call cost.
    """
    rg = level.mean_dn_per_s * gain
    g = noise.e_per_dn / gain
    read = noise.read_noise_e**2
    num = total_t = 0.0
    for t, n in frames.items():
        if (rg + dr) * t > sat:
            continue
        dark_e = noise.dark_current_e_per_s * t
        var = n * (max(rg * t, 0.0) / g + (read + dark_e) / g**2 + 1.0 / 12.0)
        if dark_frames:
            var = var + n * n * (0.0 / g + (read + dark_e) / g**2 + 1.0 / 12.0) / dark_frames
        num += var
        total_t += n * t
    if total_t <= 0:
        return 0.0  # the mean clips in every frame: not measurable
    gt = gain * total_t
    return level.mean_dn_per_s / math.sqrt(num / (gt * gt) / level.n_pixels)


def single_exposure_snr(
    level: RoiLevel, noise: SensorNoise, gain: float = 1.0, dark_frames: int = 0
) -> Callable[[float, int], float]:
    """``roi_snr(level, noise, [t] * n, gain, dark_frames)`` as a function of (t in seconds, n): the same bits.

    The planner's bisection asks this ~25 times a channel per plan with one exposure repeated; what does not
    depend on t is worked out once here. A level with a pixel distribution goes through ``roi_snr`` itself.
    """
    if level.rates_dn_per_s or level.mean_dn_per_s == 0:
        return lambda t, n: roi_snr(level, noise, [t] * n, gain, dark_frames)
    sat = noise.saturation_dn(gain)
    dr = _dark_rate(noise, gain)
    # The same operations in the same order as roi_snr's peak filter and _mean_level_snr for one frame kind.
    peak_rate = level.peak_dn_per_s * gain + dr
    mean = level.mean_dn_per_s
    rg = mean * gain
    g = noise.e_per_dn / gain
    g2 = g**2
    read = noise.read_noise_e**2
    dc = noise.dark_current_e_per_s
    n_px = level.n_pixels
    zero_g = 0.0 / g

    def snr(t: float, n: int) -> float:
        t = float(t)
        if peak_rate * t > sat or (rg + dr) * t > sat:
            return 0.0  # no frame the peak (or the mean) leaves unclipped
        dark_e = dc * t
        var = n * (max(rg * t, 0.0) / g + (read + dark_e) / g2 + 1.0 / 12.0)
        if dark_frames:
            var = var + n * n * (zero_g + (read + dark_e) / g2 + 1.0 / 12.0) / dark_frames
        total_t = 0.0 + n * t
        if total_t <= 0:
            return 0.0
        gt = gain * total_t
        return mean / math.sqrt((0.0 + var) / (gt * gt) / n_px)

    return snr


def single_exposure_min_snr(
    levels: Sequence[RoiLevel],
    noise: SensorNoise,
    gain: float = 1.0,
    dark_frames: int = 0,
    stop_below: float = -math.inf,
) -> Callable[[float, int], float]:
    """``min(single_exposure_snr(lv, ...)(t, n) for lv in levels)``, the same bits; the first below ``stop_below``.

    The levels share everything but their rates, so the terms that depend only on t and n are worked out once
    a call (with the operations grouped as ``_mean_level_snr`` groups them); the planner's reaches-the-target
    test passes the target as ``stop_below``, since any channel short of it decides.
    """
    if any(lv.rates_dn_per_s or lv.mean_dn_per_s == 0 for lv in levels):
        each = [single_exposure_snr(lv, noise, gain, dark_frames) for lv in levels]

        def some(t: float, n: int) -> float:
            low = math.inf
            for f in each:
                low = min(low, f(t, n))
                if low < stop_below:
                    break
            return low

        return some
    sat = noise.saturation_dn(gain)
    dr = _dark_rate(noise, gain)
    g = noise.e_per_dn / gain
    g2 = g**2
    read = noise.read_noise_e**2
    dc = noise.dark_current_e_per_s
    zero_g = 0.0 / g
    params = [(lv.peak_dn_per_s * gain + dr, lv.mean_dn_per_s * gain, lv.mean_dn_per_s, lv.n_pixels) for lv in levels]
    known: dict[tuple[float, int], float] = {}  # a plan asks for the same frames 3 times in 11

    def snr(t: float, n: int) -> float:
        t = float(t)
        if (t, n) in known:
            return known[t, n]
        dark_e = dc * t
        b = (read + dark_e) / g2
        master = n * n * (zero_g + b + 1.0 / 12.0) / dark_frames if dark_frames else 0.0
        total_t = 0.0 + n * t
        gt = gain * total_t
        low = math.inf
        for peak_rate, rg, mean, n_px in params:
            if peak_rate * t > sat or (rg + dr) * t > sat or total_t <= 0:
                value = 0.0  # no frame the peak (or the mean) leaves unclipped
            else:
                var = n * (max(rg * t, 0.0) / g + b + 1.0 / 12.0)
                if dark_frames:
                    var = var + master
                value = mean / math.sqrt((0.0 + var) / (gt * gt) / n_px)
            low = min(low, value)
            if low < stop_below:
                break
        known[t, n] = low
        return low

    return snr


def exposure_for_snr(
    level: RoiLevel, noise: SensorNoise, target_snr: float, n: int, gain: float = 1.0, dark_frames: int = 0
) -> float | None:
    """Exposure in seconds at which ``n`` equal frames give the ROI mean ``target_snr``, if nothing clips.

    ``roi_snr`` at the mean level solved for t: (g n t m)^2 n_px = S^2 (n V(t) + n^2 D(t) / n_d), with the
    frame variance V and the master dark's D both linear in t, is a quadratic. None for a dark ROI.
    """
    m = level.mean_dn_per_s
    if not m > 0 or not n >= 1:
        return None
    g = noise.e_per_dn / gain
    dark = noise.dark_current_e_per_s / g**2  # counts^2 per second of dark shot noise
    floor = noise.read_noise_e**2 / g**2 + 1.0 / 12.0
    s2 = target_snr * target_snr
    quad = (gain * n * m) ** 2 * level.n_pixels
    lin = s2 * (n * (m * gain / g + dark) + (n * n * dark / dark_frames if dark_frames else 0.0))
    const = s2 * (n * floor + (n * n * floor / dark_frames if dark_frames else 0.0))
    return (lin + math.sqrt(lin * lin + 4.0 * quad * const)) / (2.0 * quad)


def detection_exposure_s(
    levels: Sequence[RoiLevel], noise: SensorNoise, pixel_snr_goal: float, gain: float = 1.0, dark_frames: int = 0
) -> float | None:
    """Exposure (s) at which one frame gives a pixel at each level's ROI mean ``pixel_snr_goal``; None if all dark.

    The ROI mean's SNR is sqrt(n_pixels) times that pixel's, so this is ``exposure_for_snr`` of a one-pixel ROI.
    """
    if not (math.isfinite(pixel_snr_goal) and pixel_snr_goal > 0):
        raise ValueError(f"detection_exposure_s: pixel_snr_goal = {pixel_snr_goal!r}, expected a finite SNR > 0")
    need = [exposure_for_snr(RoiLevel(lv.peak_dn_per_s, lv.mean_dn_per_s), noise, pixel_snr_goal, 1, gain, dark_frames)
            for lv in levels]  # fmt: skip
    known = [t for t in need if t is not None]
    return max(known) if known else None


def pixel_snr(
    rate_dn_per_s: npt.ArrayLike,
    noise: SensorNoise,
    exposures_s: Sequence[float],
    gain: float = 1.0,
    dark_frames: int = 0,
) -> FloatArray:
    """Per-pixel SNR (dimensionless) of the merged radiance of pixels receiving ``rate_dn_per_s`` counts/s."""
    r = np.asarray(rate_dn_per_s, dtype=float)
    var = _merged_variance(r.reshape(-1), _frames(exposures_s), noise, gain, dark_frames, noise.saturation_dn(gain))
    return np.asarray((r.reshape(-1) / np.sqrt(var)).reshape(r.shape), dtype=np.float64)

def _geomspace(lo: float, hi: float, num: int) -> list[float]:
    """``np.geomspace(lo, hi, num).tolist()`` for 0 < lo < hi and num > 1: its steps without its generality.

    numpy's geomspace, logspace and linspace (sign handling, dtypes, broadcasting) were a large share of a plan's
    time; these are the operations they come down to for two positive floats, in their order.
    """
    if not (0 < lo < hi and num > 1):
        return list(np.geomspace(lo, hi, num).tolist())
    log_lo, log_hi = np.log10(np.float64(lo)), np.log10(np.float64(hi))
    step = (log_hi - log_lo) / (num - 1)
    if step == 0:
        return list(np.geomspace(lo, hi, num).tolist())
    y = np.arange(0, num, dtype=np.float64)
    y *= step
    y += log_lo
    y[-1] = log_hi
    out = np.power(10.0, y)
    out[0], out[-1] = lo, hi
    return list(out.tolist())


def _pixel_grid(
    levels: Sequence[RoiLevel], candidates: Sequence[float], sat: float, dark_rate: float, gain: float
) -> FloatArray:
    """Rates (counts/s) at which the per-pixel SNR is checked: log-spaced from dark to peak, plus every rate
    just too bright for a candidate exposure (the worst pixels of a bracket)."""
    pts: list[float] = []
    spaced: dict[tuple[float, float], list[float]] = {}  # colour channels mostly share their dark and peak
    for lv in levels:
        lo = float(lv.dark_dn_per_s or 0.0)
        hi = lv.peak_dn_per_s
        if hi <= 0:
            continue
        lo = max(lo, hi * 1e-9)
        if (lo, hi) not in spaced:
            spaced[lo, hi] = _geomspace(lo, hi, 48)
        pts.extend(spaced[lo, hi])
        for t in candidates:
            r = (sat / t - dark_rate) / gain
            if lo < r * (1 + 1e-9) < hi:
                pts.append(r * (1 + 1e-9))
    return np.asarray(sorted(pts), dtype=float)
