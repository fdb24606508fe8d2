"""The per-pixel bracket: frames added to a plan until the darkest ROI pixels reach their SNR, then pruned.

Split from ``acquisition.exposure.plan`` (which describes the whole plan); exposures in seconds, rates in
counts/s at gain 1, SNRs dimensionless.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from acquisition.exposure.snr import FloatArray, Frames, pixel_snr
from acquisition.exposure.spec import CameraTiming, RoiLevel, _finite, _Rules
from acquisition.noise import SensorNoise


def _cost(frames: Frames, overhead_s: float, dark_frames: int) -> float:
    light = sum(n * (t + overhead_s) for t, n in frames.items())
    return light + dark_frames * sum(t + overhead_s for t in frames)


def _prune(frames: Frames, ok: Callable[[Frames], bool]) -> Frames:
    """Drop frames, longest first, while ``ok`` still holds: the greedy additions can make earlier ones spare."""
    frames = dict(frames)
    for t in sorted(frames, reverse=True) + sorted(frames):
        while frames.get(t, 0) > 0:
            trial = dict(frames)
            trial[t] -= 1
            if trial[t] == 0:
                del trial[t]
            if not trial or not ok(trial):
                break
            frames = trial
    return frames


def _greedy_pixel(
    frames: Frames,
    worst: Callable[[Frames], tuple[float, float]],
    ladder: Sequence[float],
    target: float,
    limit_dn: float,
    dark_rate: float,
    overhead_s: float,
    dark_frames: int,
    max_frames: int,
    budget: float,
    noise: SensorNoise,
    gain: float,
) -> tuple[Frames, bool]:
    """Add frames until the worst pixel of the ROI reaches ``target`` per-pixel SNR.

    Each round looks at the worst pixel: if k repeats of one ladder exposure bring it to the target, the
    cheapest such (t, k) in capture seconds (dark frames of a new exposure included; within 5 % of the
    cheapest, the fewest frames) is added; otherwise
    the single frame that buys it the most SNR^2 per second. Adding frames never lowers another pixel's
    SNR much, so the worst pixel moves on until all reach the target or the limits stop it.
    """
    frames = dict(frames)

    def snr_with(t: float, k: int) -> float:
        trial = dict(frames)
        trial[t] = trial.get(t, 0) + k
        ts = [x for x, m in trial.items() for _ in range(m)]
        return float(pixel_snr(r_w, noise, ts, gain, dark_frames))

    while True:
        snr_w, r_w = worst(frames)
        if snr_w >= target:
            return frames, True
        room = max_frames - sum(frames.values())
        if room <= 0:
            return frames, False
        base_cost = _cost(frames, overhead_s, dark_frames)
        best: tuple[float, float] | None = None  # (SNR^2 per second, exposure) of one added frame
        enough: list[tuple[float, int, float]] = []  # (added seconds, k, exposure) of k frames that suffice
        for t in ladder:
            if (r_w * gain + dark_rate) * t > limit_dn:
                continue  # this frame would clip (or nearly) the worst pixel: no help to it
            new_dark = 0 if t in frames else dark_frames
            for k in range(1, room + 1):
                added = (k + new_dark) * (t + overhead_s)
                if base_cost + added > budget:
                    break
                new_snr = snr_with(t, k)
                if k == 1:
                    score = (new_snr**2 - snr_w**2) / added
                    if best is None or score >= best[0]:
                        best = (score, t)
                if new_snr >= target:
                    enough.append((added, k, t))
                    break
        if enough:
            # Shot-limited frames cost about the same per photon at any length: within 5 % of the cheapest,
            # take the fewest frames (less readout, less read noise, a shorter journal).
            cheapest = min(e[0] for e in enough)
            _, k, t = min((e for e in enough if e[0] <= 1.05 * cheapest), key=lambda e: (e[1], e[0]))
            frames[t] = frames.get(t, 0) + k
        elif best is not None and best[0] > 0:
            frames[best[1]] = frames.get(best[1], 0) + 1
        else:
            return frames, False


def _ladder(
    levels: Sequence[RoiLevel], cam: CameraTiming, t_top: float, limit_dn: float, dark_rate: float, ratio: float
) -> list[float]:
    """Exposures (s) a bracket may add: ``t_top``, then ``ratio`` apart up to the longest that keeps the darkest
    ROI pixel below ``limit_dn`` counts (or the camera's longest), that one included."""
    darkest = min((lv.dark_dn_per_s or 0.0) * cam.gain + dark_rate for lv in levels)
    t_dark = limit_dn / darkest if darkest > 0 else math.inf
    cap = cam.floor(min(t_dark, cam.max_exposure_s)) or t_top
    ladder = [t_top]
    while ladder[-1] * ratio <= cap * (1 + 1e-9):
        nxt = cam.floor(ladder[-1] * ratio)
        if nxt is None or nxt <= ladder[-1]:
            break
        ladder.append(nxt)
    if cap >= t_top * ratio and cap > ladder[-1] * (1 + 1e-9):
        ladder.append(cap)
    return ladder


@dataclass(frozen=True, eq=False)
class _WorstPixel:
    """The lowest per-pixel SNR a set of frames gives over the ROI's rates ``grid`` (counts/s), and that rate."""

    grid: FloatArray
    noise: SensorNoise
    gain: float
    dark_frames: int

    def __call__(self, frames: Frames) -> tuple[float, float]:
        """(SNR, rate in counts/s) of the worst pixel; (0, 0) for an ROI without light."""
        if not self.grid.size:
            return 0.0, 0.0  # no light in the ROI
        ts = [t for t, k in frames.items() for _ in range(k)]
        s = pixel_snr(self.grid, self.noise, ts, self.gain, self.dark_frames)
        i = int(np.argmin(s))
        return float(s[i]), float(self.grid[i])


def _lift_dark_end(
    frames: Frames, reached: bool, notes: list[str], pixel_target: float, roi_ok: Callable[[Frames], bool],
    worst: _WorstPixel, ladder: Sequence[float], t_top: float, rules: _Rules,
) -> tuple[Frames, bool]:
    """Longer frames from ``ladder`` (s) until the worst pixel reaches ``pixel_target``, then the spare ones dropped.

    ``roi_ok(frames)`` says whether the ROI mean still reaches its target (the pruning keeps it so).
    Returns (frames, reached) and appends to ``notes`` why the target was missed and which frames clip the
    bright pixels.
    """
    frames, ok = _greedy_pixel(frames, worst, ladder, pixel_target, rules.safety * rules.sat, rules.dr,
                               rules.cam.overhead_s, rules.dark_frames, rules.max_frames, rules.budget, rules.noise,
                               rules.cam.gain)  # fmt: skip
    if ok and reached:
        frames = _prune(frames, lambda fr: roi_ok(fr) and worst(fr)[0] >= pixel_target)
    if not ok:
        reached = False
        notes.append(
            f"per-pixel SNR {pixel_target:g} unreachable within max_frames/max_total_s: "
            f"lowest achieved {worst(frames)[0]:.4g}"
        )
    long = [t for t in sorted(frames) if t > t_top * (1 + 1e-9)]
    if long:
        notes.append(
            f"bracket: frames of {', '.join(f'{t:.4g}' for t in long)} s saturate the brighter ROI pixels "
            "(the merge ignores those samples) to lift the dark end"
        )
    return frames, reached


def fixed_bracket(center_s: float, n: int = 7, stops: float = 2.0) -> tuple[float, ...]:
    """Exposures in seconds of an n-frame bracket ``stops`` EV apart, centred (geometrically) on ``center_s``."""
    _finite("fixed_bracket", "center_s", center_s, lo_open=True)
    if int(n) != n or n < 1:
        raise ValueError(f"fixed_bracket.n = {n!r}: expected a whole number >= 1")
    return tuple(center_s * 2.0 ** (stops * (k - (n - 1) / 2)) for k in range(n))
