"""The per-pixel bracket: frames added to a plan until the darkest ROI pixels reach their SNR, then pruned.

Split from ``acquisition.exposure.plan`` (which describes the whole plan); exposures in seconds, rates in
counts/s at gain 1, SNRs dimensionless.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

from acquisition.exposure.snr import Frames, pixel_snr
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
