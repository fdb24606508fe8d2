"""Exposure planning: the fewest and shortest frames that reach a target SNR in the ROI without saturating it.

Units: ROI levels are rates in counts/s above black at gain 1 (the HDR merge's radiance unit: counts over
exposure x gain), so a frame at gain g collects ``r g t`` counts; exposures in seconds; saturation in
counts above black from ``SensorNoise.saturation_dn(gain)``.

What the plan promises is computed from ``SensorNoise`` the way the linear merge achieves it. The merge
estimates a pixel as ``X = sum_k (s_k - dark_k) / sum_k t_k`` over its unsaturated frames, so

    var X = sum_k var_k / (g sum_k t_k)^2,       var_k = SensorNoise.variance_dn2(r g t_k, t_k, g),

which for N equal frames is ``SNR_N = N s / sqrt(N var)``. With ``dark_frames = n_d`` a master dark, the
mean of n_d dark frames at the same exposure, is subtracted from every frame of that exposure; it is
common to those N frames and adds ``N^2 var_dark / n_d`` to the numerator's variance (so repeating a frame
helps less than sqrt(N) when the dark noise matters). Without dark frames the black level and the mean
dark current are assumed known and subtracted as constants.

Two SNRs, both documented on ``ExposurePlan``:

- ROI SNR (``target_snr``): of the ROI mean reading, the mean of the merged radiance over the ROI's
  ``n_pixels`` pixels. Its noise is ``sqrt(sum_i var X_i) / n``; since the shot variance is linear in the
  signal, for frames that saturate no ROI pixel it depends only on the ROI mean level, so
  ``SNR_roi = sqrt(n) * SNR_pixel(mean)``. This is the noise a repeat of the capture would show, which is
  what ``reduce_roi``'s propagated standard error reports (texture is not noise).
- Per-pixel SNR (``pixel_snr``, optional): every pixel from the ROI's dark level up to its peak must
  reach it. In a bracket the worst pixel is not the darkest one but one just too bright for a long frame,
  so the planner checks the whole range.

The plan: one frame metered so the ROI peak sits at ``safety`` (80 %) of saturation, capped by the longest
exposure; if it alone reaches the ROI target it is shortened to the shortest exposure that does; if not, it
is repeated (long frames repeated rather than stops added: for a linear sensor the noise is set by the
photons collected, and extra stops of shorter frames add read noise, not photons) until the target is
met, within ``max_frames`` and ``max_total_s``. A target out of reach returns a plan with
``reached=False``, its achievable SNR and a note. When the per-pixel target at the dark end needs it, the
planner adds longer frames (a bracket, ``bracket_ratio`` apart) in which the bright pixels saturate and
the merge ignores them, choosing greedily the frame that buys the most SNR^2 per second of capture for the
worst pixel.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from acquisition.exposure.bracket import _cost, _ladder, _lift_dark_end, _WorstPixel
from acquisition.exposure.snr import (
    Frames,
    _dark_rate,
    _frames,
    _pixel_grid,
    exposure_for_snr,
    pixel_snr,
    roi_snr,
    single_exposure_min_snr,
)
from acquisition.exposure.spec import CameraTiming, ExposureError, ExposurePlan, RoiLevel, _finite, _Rules
from acquisition.noise import SensorNoise


def plan_exposure(
    level: RoiLevel | Sequence[RoiLevel],
    noise: SensorNoise,
    target_snr: float,
    camera: CameraTiming | None = None,
    *,
    pixel_snr_target: float | None = None,
    safety: float = 0.8,
    dark_frames: int = 0,
    max_frames: int = 64,
    max_total_s: float | None = None,
    bracket_ratio: float = 4.0,
    shortest_s: float | None = None,
) -> ExposurePlan:
    """Fewest and shortest frames (seconds) reaching ``target_snr`` on the ROI mean without saturating the ROI.

    ``level`` is one ROI level in counts/s, or one per colour channel (the brightest channel limits the exposure,
    the dimmest sets the SNR). ``pixel_snr_target`` asks in addition for that per-pixel SNR over the ROI's levels
    from ``dark_dn_per_s`` to the peak (it may add a bracket of longer frames). ``safety`` is the fraction of
    saturation the ROI peak may reach in the frames that must not clip. Raises ExposureError if the peak saturates
    even at the shortest exposure; an unreachable target returns a plan with ``reached=False``. ``shortest_s``: no
    frame shorter (s), up to the longest the peak allows (a large ROI's mean reaches its target in frames too short
    to detect its pixels: ``snr.detection_exposure_s``).
    """
    cam = camera or CameraTiming()
    levels = [level] if isinstance(level, RoiLevel) else list(level)
    target, budget = _checked(levels, target_snr, pixel_snr_target, safety, dark_frames, max_frames, max_total_s,
                              bracket_ratio)  # fmt: skip
    rules = _Rules(noise, cam, safety, dark_frames, max_frames, budget, noise.saturation_dn(cam.gain),
                   _dark_rate(noise, cam.gain))  # fmt: skip
    roi = _RoiSnr.of(levels, noise, cam.gain, dark_frames, target)

    # The ROI mean: the longest frame the peak allows, repeated until it reaches the target, then shortened.
    t_top, n_cap, limits = _longest_frame(levels, rules)
    frames, reached, notes = _repeat_frames(roi.snr_of, target, t_top, n_cap, max_frames, cam, limits, roi.guess,
                                            roi.reaches)  # fmt: skip
    floor_s = 0.0 if shortest_s is None else _finite("plan_exposure", "shortest_s", shortest_s)
    if reached and max(frames) < min(floor_s, t_top):
        frames = {min(cam.ceil(floor_s) or t_top, t_top): sum(frames.values())}
        notes.append(f"frames lengthened to {max(frames):.4g} s: shortest_s = {floor_s:.4g} s")

    # The worst pixel's SNR, known whenever every channel's dark level is; asked for, it may add longer frames.
    expected_pixel: float | None = None
    if pixel_snr_target is not None or all(lv.dark_dn_per_s is not None for lv in levels):
        ladder = _ladder(levels, cam, t_top, safety * rules.sat, rules.dr, bracket_ratio)
        worst = _WorstPixel(_pixel_grid(levels, ladder, rules.sat, rules.dr, cam.gain), noise, cam.gain, dark_frames)
        if pixel_snr_target is not None:
            frames, reached = _lift_dark_end(frames, reached, notes, pixel_snr_target,
                                             lambda fr: roi.snr_of(fr) >= target, worst, ladder, t_top, rules)
        expected_pixel = worst(frames)[0]

    return _as_plan(levels, frames, reached, expected_pixel, notes, pixel_snr_target, roi, rules)


def _checked(
    levels: Sequence[RoiLevel], target_snr: float, pixel_snr_target: float | None, safety: float, dark_frames: int,
    max_frames: int, max_total_s: float | None, bracket_ratio: float,
) -> tuple[float, float]:
    """The request checked: (target ROI SNR, time budget in seconds or inf); a ValueError names a bad argument."""
    if not levels:
        raise ValueError("plan_exposure: no ROI level given")
    target = _finite("plan_exposure", "target_snr", target_snr, lo_open=True)
    if not 0 < safety <= 1:
        raise ValueError(f"plan_exposure.safety = {safety!r}: expected a fraction in (0, 1]")
    if int(dark_frames) != dark_frames or dark_frames < 0:
        raise ValueError(f"plan_exposure.dark_frames = {dark_frames!r}: expected a whole number >= 0")
    if int(max_frames) != max_frames or max_frames < 1:
        raise ValueError(f"plan_exposure.max_frames = {max_frames!r}: expected a whole number >= 1")
    if not bracket_ratio > 1:
        raise ValueError(f"plan_exposure.bracket_ratio = {bracket_ratio!r}: expected a factor > 1")
    if pixel_snr_target is not None:
        _finite("plan_exposure", "pixel_snr_target", pixel_snr_target, lo_open=True)
        missing = [i for i, lv in enumerate(levels) if lv.dark_dn_per_s is None]
        if missing:
            raise ValueError(
                f"plan_exposure: pixel_snr_target needs the ROI's dark level, but RoiLevel {missing} has "
                "dark_dn_per_s = None"
            )
    budget = math.inf if max_total_s is None else _finite("plan_exposure", "max_total_s", max_total_s, lo_open=True)
    return target, budget


@dataclass(frozen=True, eq=False)
class _RoiSnr:
    """The ROI SNR of a set of frames (the lowest channel's), and whether it reaches ``target``."""

    levels: Sequence[RoiLevel]
    noise: SensorNoise
    gain: float
    dark_frames: int
    target: float
    #: The lowest channel's SNR of one exposure repeated: a faster form of roi_snr, the same bits.
    one_kind: Callable[[float, int], float]
    #: The same, channels dimmest first, stopping at the first below the target.
    one_kind_short: Callable[[float, int], float]
    dimmest_first: Sequence[RoiLevel]

    @classmethod
    def of(cls, levels: Sequence[RoiLevel], noise: SensorNoise, gain: float, dark_frames: int,
           target: float) -> _RoiSnr:  # fmt: skip
        """The checks of these channels; one exposure repeated (every step of the shortest-frame search) is fast."""
        one_kind = single_exposure_min_snr(levels, noise, gain, dark_frames)
        dimmest_first = sorted(levels, key=lambda lv: lv.mean_dn_per_s)
        one_kind_short = single_exposure_min_snr(dimmest_first, noise, gain, dark_frames, stop_below=target)
        return cls(levels, noise, gain, dark_frames, target, one_kind, one_kind_short, dimmest_first)

    def snr_of(self, frames: Frames) -> float:
        """The lowest channel's ROI SNR of these frames (exposure in seconds: count)."""
        if len(frames) == 1:
            ((t, n),) = frames.items()
            return self.one_kind(t, n)
        ts = [t for t, n in frames.items() for _ in range(n)]
        return min(roi_snr(lv, self.noise, ts, self.gain, self.dark_frames) for lv in self.levels)

    def reaches(self, frames: Frames) -> bool:
        """``snr_of(frames) >= target``, stopping at the first channel short of it (the dimmest, mostly)."""
        if len(frames) == 1:
            ((t, n),) = frames.items()
            return self.one_kind_short(t, n) >= self.target
        ts = [t for t, n in frames.items() for _ in range(n)]
        return all(roi_snr(lv, self.noise, ts, self.gain, self.dark_frames) >= self.target for lv in self.dimmest_first)

    def guess(self, n: int) -> float | None:
        """The exposure (s) at which n frames reach the target, in closed form; None where there is none."""
        if any(lv.rates_dn_per_s for lv in self.levels):
            return None  # a pixel distribution clips in parts: no closed form
        ts = [exposure_for_snr(lv, self.noise, self.target, n, self.gain, self.dark_frames) for lv in self.levels]
        return max(t for t in ts if t is not None) if all(t is not None for t in ts) else None


def _longest_frame(levels: Sequence[RoiLevel], rules: _Rules) -> tuple[float, int, list[str]]:
    """The longest frame (s) the ROI peak and the time budget allow, how many of it fit, and what bounds it."""
    cam, safety, dark_frames, budget = rules.cam, rules.safety, rules.dark_frames, rules.budget
    gain, sat, dr = cam.gain, rules.sat, rules.dr
    # The longest frame in which the brightest ROI pixel stays at `safety` of saturation.
    peak = max(lv.peak_dn_per_s for lv in levels)
    t_peak = safety * sat / (peak * gain + dr) if peak * gain + dr > 0 else math.inf
    t_top = cam.floor(t_peak)
    if t_top is None:
        raise ExposureError(
            f"ROI peak {peak:.6g} counts/s saturates even at the shortest exposure: keeping it at {safety:.0%} of "
            f"saturation ({sat:.6g} counts at gain {gain:g}) needs <= {t_peak:.3g} s, but the shortest available "
            f"exposure is {cam.ceil(0.0) or cam.min_exposure_s:.3g} s; reduce the light, the aperture or the gain"
        )
    limits: list[str] = []  # what bounds the longest frame; worth a note only if the plan ends up using it
    if t_top < t_peak * (1 - 1e-6):
        why = "max_exposure_s" if t_peak > cam.max_exposure_s else "the available exposure steps"
        limits.append(f"longest frame {t_top:.4g} s limited by {why} (peak would reach {safety:.0%} at {t_peak:.4g} s)")

    # Frames of t_top the time budget allows; a budget shorter than one frame shortens that frame.
    n_cap = rules.max_frames
    if math.isfinite(budget):
        per_frame = t_top + cam.overhead_s
        n_cap = min(n_cap, math.floor((budget - dark_frames * per_frame) / per_frame))
        if n_cap < 1:
            fit = cam.floor((budget - (1 + dark_frames) * cam.overhead_s) / (1 + dark_frames))
            if fit is None:
                raise ExposureError(
                    f"max_total_s = {budget:g} s cannot hold one frame: the shortest exposure plus overhead "
                    f"{cam.overhead_s:g} s (and {dark_frames} dark frames) exceeds it"
                )
            limits.append(f"max_total_s = {budget:g} s shortens the longest frame to {fit:.4g} s")
            t_top, n_cap = fit, 1
    return t_top, n_cap, limits


def _repeat_frames(
    snr_of: Callable[[Frames], float], target: float, t_top: float, n_cap: int, max_frames: int,
    cam: CameraTiming, limits: list[str], guess: Callable[[int], float | None] = lambda n: None,
    reaches: Callable[[Frames], bool] | None = None,
) -> tuple[Frames, bool, list[str]]:
    """Repeat the longest frame until the ROI SNR reaches ``target``, then shorten them: (frames, reached, notes).

    ``reaches(frames)`` is ``snr_of(frames) >= target``, perhaps computed faster.
    """
    ok = reaches or (lambda fr: snr_of(fr) >= target)
    notes: list[str] = []
    n = 1
    if snr_of({t_top: 1}) == 0:
        notes.append("the ROI mean is 0 counts/s (or clips in every frame): no exposure gives it an SNR")
    else:
        while n < n_cap and not ok({t_top: n}):
            n += 1
    reached = ok({t_top: n})
    if reached:
        t = _shortest(lambda t: ok({t: n}), cam, t_top, guess(n))
        frames: Frames = {t: n}
        if snr_of(frames) > 1.01 * target and t <= (cam.ceil(cam.min_exposure_s) or t) * (1 + 1e-9):
            above = snr_of(frames)
            notes.append(f"the shortest exposure {t:.4g} s already gives ROI SNR {above:.4g}, above the target")
        if n > 1:
            notes.extend(limits)
            one = snr_of({t_top: 1})
            notes.append(f"{n} repeats of {t:.4g} s: one frame at the peak limit reaches only SNR {one:.4g}")
    else:
        frames = {t_top: n}
        notes.extend(limits)
        if snr_of(frames) > 0:
            limit = "max_frames" if n_cap == max_frames else "max_total_s"
            notes.append(
                f"target ROI SNR {target:g} unreachable within {limit} ({n} frames of {t_top:.4g} s): "
                f"achievable {snr_of(frames):.4g}"
            )
    return frames, reached, notes


def _shortest(ok: Callable[[float], bool], cam: CameraTiming, t_hi: float, guess: float | None = None) -> float:
    """Shortest available exposure in [min, t_hi] seconds for which ok(t) holds (ok is monotone, ok(t_hi)).

    ``guess`` is an estimate of the boundary in seconds (a closed form); it only narrows the search.
    """
    lo = cam.ceil(cam.min_exposure_s) or t_hi
    if ok(lo):
        return lo
    a, b = math.log(lo), math.log(t_hi)
    if guess is not None and lo < guess < t_hi:
        # With ok monotone the halvings below end on the same two neighbouring floats from any bracket of
        # the boundary, so a tight one around the estimate gives the same answer in ~8 halvings, not ~55.
        # The closed form lands within ~1e-15 of the boundary; 1e-9 is the fallback of a worse estimate.
        for rel in (1e-13, 1e-9):
            a0, b0 = math.log(guess * (1 - rel)), math.log(guess * (1 + rel))
            if a < a0 and b0 < b and not ok(math.exp(a0)) and ok(math.exp(b0)):
                a, b = a0, b0
                # The boundary is a float or two from the estimate's: walk to it (keeping ok(e^a) false and
                # ok(e^b) true), and the halvings below have nothing left to halve.
                x = math.log(guess)
                for _ in range(8):
                    if not a < x < b:
                        break
                    if ok(math.exp(x)):
                        b, x = x, math.nextafter(x, -math.inf)
                    else:
                        a, x = x, math.nextafter(x, math.inf)
                break
    # Halve until the midpoint rounds onto an end (about 55 halvings of a 1e-5..30 s range): from there on
    # a halving changes nothing, except that a start `a` which passes moves `b` onto it. So this is the
    # same boundary, to the last bit, that 100 halvings reach.
    for _ in range(100):
        m = 0.5 * (a + b)
        if m == a or m == b:
            if m == a and ok(math.exp(a)):
                b = a
            break
        if ok(math.exp(m)):
            b = m
        else:
            a = m
    t = cam.ceil(math.exp(b))
    return t if t is not None and t <= t_hi and ok(t) else t_hi


def _as_plan(
    levels: Sequence[RoiLevel], frames: Frames, reached: bool, expected_pixel: float | None, notes: list[str],
    pixel_snr_target: float | None, roi: _RoiSnr, rules: _Rules,
) -> ExposurePlan:
    """The frames evaluated as a plan, with what only the planner knows: its verdict, pixel SNR and notes."""
    exposures = tuple(sorted(t for t, k in frames.items() for _ in range(k)))
    # The evaluation's own pixel SNR and verdict are replaced below, so it need not work them out.
    known = roi.snr_of(frames) if len(frames) == 1 else None  # the one-kind closure's bits are roi_snr's
    plan = _evaluate(levels, rules.noise, exposures, rules.cam, roi.target, pixel_snr_target, rules.dark_frames,
                     pixel=False, snr=known)  # fmt: skip
    clip_peak = any((lv.peak_dn_per_s * rules.cam.gain + rules.dr) * t > rules.sat for lv in levels for t in frames)
    if clip_peak and not all(lv.rates_dn_per_s for lv in levels):
        notes.append("expected_snr is a lower bound: no pixel distribution given, frames clipping the peak not counted")
    # The evaluated plan (its target, gain and pixel target are the planner's), with what only the planner knows.
    return dataclasses.replace(
        plan,
        reached=reached and plan.expected_snr >= roi.target * (1 - 1e-9),
        expected_pixel_snr=expected_pixel,
        notes=tuple(notes),
    )


def evaluate_plan(
    level: RoiLevel | Sequence[RoiLevel],
    noise: SensorNoise,
    exposures_s: Sequence[float],
    camera: CameraTiming | None = None,
    *,
    target_snr: float = math.nan,
    pixel_snr_target: float | None = None,
    dark_frames: int = 0,
) -> ExposurePlan:
    """What a given set of exposures (seconds) achieves on an ROI: SNR, times, saturation margin, as a plan.

    Used for fixed brackets and for checking a plan; ``reached`` compares against ``target_snr`` (False for
    NaN). Exposures are taken as given (not quantised to the camera's steps).
    """
    levels = [level] if isinstance(level, RoiLevel) else list(level)
    return _evaluate(levels, noise, exposures_s, camera or CameraTiming(), target_snr, pixel_snr_target, dark_frames)


def _evaluate(
    levels: Sequence[RoiLevel], noise: SensorNoise, exposures_s: Sequence[float], cam: CameraTiming,
    target_snr: float, pixel_snr_target: float | None, dark_frames: int, *, pixel: bool = True,
    snr: float | None = None,
) -> ExposurePlan:
    """``evaluate_plan``; without ``pixel`` the per-pixel SNR is left out (None) and ``reached`` ignores it.

    ``snr`` is the ROI SNR of these exposures where the caller knows it already (the planner, for one kind).
    """
    if not exposures_s or not all(math.isfinite(t) and t > 0 for t in exposures_s):
        raise ValueError(f"evaluate_plan: exposures_s = {tuple(exposures_s)!r}: expected positive seconds")
    gain = cam.gain
    sat = noise.saturation_dn(gain)
    dr = _dark_rate(noise, gain)
    exposures = tuple(sorted(float(t) for t in exposures_s))
    frames = _frames(exposures)
    if snr is None:
        snr = min(roi_snr(lv, noise, exposures, gain, dark_frames) for lv in levels)
    peak = max(lv.peak_dn_per_s for lv in levels)
    margin = sat / ((peak * gain + dr) * exposures[0]) if peak * gain + dr > 0 else math.inf
    notes: list[str] = []
    if margin < 1:
        notes.append(f"ROI peak clips in every frame (margin {margin:.3g}): the reading would be a lower bound")
    px: float | None = None
    if pixel and all(lv.dark_dn_per_s is not None for lv in levels):
        grid = _pixel_grid(levels, list(frames), sat, dr, gain)
        px = float(np.min(pixel_snr(grid, noise, exposures, gain, dark_frames))) if grid.size else None
    reached = snr >= target_snr and (pixel_snr_target is None or (px is not None and px >= pixel_snr_target))
    darks = tuple(t for t in sorted(frames) for _ in range(dark_frames))
    return ExposurePlan(
        exposures_s=exposures,
        expected_snr=snr,
        target_snr=target_snr,
        reached=bool(reached),
        total_exposure_s=float(sum(exposures)),
        total_time_s=_cost(frames, cam.overhead_s, dark_frames),
        saturation_margin=margin,
        dark_exposures_s=darks,
        expected_pixel_snr=px,
        pixel_snr_target=pixel_snr_target,
        gain=gain,
        notes=tuple(notes),
    )
