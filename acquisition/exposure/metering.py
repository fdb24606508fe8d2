"""Metering: a plan made from test frames of the ROI (``meter``, returning a ``MeterResult``).

Test frames are stepped shorter until unclipped (``saturated`` is the clip test) and longer until bright
enough, then the last unclipped frame's level is handed to ``plan_exposure``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from acquisition.exposure.plan import plan_exposure
from acquisition.exposure.snr import _dark_rate, detection_exposure_s
from acquisition.exposure.spec import CameraTiming, ExposureError, ExposurePlan, RoiLevel
from acquisition.noise import SensorNoise


@dataclass(frozen=True)
class MeterResult:
    """A plan made from test frames, with the level they measured and the test exposures taken (seconds)."""

    plan: ExposurePlan
    level: RoiLevel
    test_exposures_s: tuple[float, ...]
    notes: tuple[str, ...] = ()


def saturated(counts_above_black: npt.ArrayLike, noise: SensorNoise, gain: float = 1.0) -> npt.NDArray[np.bool_]:
    """Pixels of a frame (counts above black) at the clip level: within 4 read-noise sigmas of saturation."""
    c = np.asarray(counts_above_black, dtype=float)
    read_dn = noise.read_noise_e * gain / noise.e_per_dn
    return np.asarray(c >= noise.saturation_dn(gain) - max(4.0 * read_dn, 1.0), dtype=bool)


def meter(
    take_roi: Callable[[float], npt.ArrayLike],
    noise: SensorNoise,
    target_snr: float,
    camera: CameraTiming | None = None,
    *,
    predicted: RoiLevel | None = None,
    start_exposure_s: float | None = None,
    step_factor: float = 8.0,
    max_tries: int = 6,
    safety: float = 0.8,
    pixel_snr_target: float | None = None,
    dark_frames: int = 0,
    max_frames: int = 64,
    max_total_s: float | None = None,
    detect_snr: float | None = None,
) -> MeterResult:
    """Plan from test frames: ``take_roi(exposure_s)`` returns the ROI's pixels in counts above black.

    The pixels are (N,), (H, W) or (H, W, C) for colour frames; the SNR target is each channel's ROI mean.

    The first test exposure is ``start_exposure_s``, or the metered frame of ``predicted`` (a model's
    prediction or the previous point's level, counts/s at gain 1). A test frame with a clipped pixel is
    retaken ``step_factor`` shorter. One whose peak is below 1 % of saturation (per-pixel SNR ~25 at the
    default noise: too noisy a level estimate) is retaken at the exposure that would put its peak at
    ``safety``. At most ``max_tries`` test frames. The plan is made from the last unclipped frame's level
    (its noisy maximum overstates the peak: conservative); the test frames are not part of the plan.
    ``detect_snr``: no planned frame so short that a pixel at a channel's ROI mean has a lower SNR in it.
    """
    cam = camera or CameraTiming()
    if not step_factor > 1:
        raise ValueError(f"meter.step_factor = {step_factor!r}: expected a factor > 1")
    if start_exposure_s is None:
        if predicted is None:
            raise ValueError("meter: give start_exposure_s or a predicted RoiLevel")
        # The metered frame of the prediction (peak at `safety`), not the plan's shortened one: more signal.
        peak = predicted.peak_dn_per_s * cam.gain + _dark_rate(noise, cam.gain)
        start_exposure_s = safety * noise.saturation_dn(cam.gain) / peak if peak > 0 else cam.max_exposure_s
    t = cam.floor(max(start_exposure_s, cam.min_exposure_s)) or cam.ceil(cam.min_exposure_s)
    assert t is not None
    sat = noise.saturation_dn(cam.gain)
    dr = _dark_rate(noise, cam.gain)
    taken: list[float] = []
    notes: list[str] = []
    level: RoiLevel | None = None  # from the last unclipped test frame
    channels: list[RoiLevel] = []  # its channels' means, for detect_snr
    clipped = False
    for _ in range(max_tries):
        counts = np.asarray(take_roi(t), dtype=float)
        taken.append(t)
        if saturated(counts, noise, cam.gain).any():
            shorter = cam.floor(t / step_factor)
            if shorter is None or shorter >= t:
                raise ExposureError(
                    f"test frame at {t:.4g} s clips in the ROI and no shorter exposure is available "
                    f"(min {cam.min_exposure_s:g} s); reduce the light, the aperture or the gain"
                )
            notes.append(f"test frame at {t:.4g} s clipped: retaken at {shorter:.4g} s")
            t, clipped = shorter, True
            continue
        clipped = False
        rates = (counts / t - dr) / cam.gain
        level = RoiLevel.from_pixels(rates)
        means = rates.reshape(-1, counts.shape[-1]).mean(axis=0) if counts.ndim == 3 else [level.mean_dn_per_s]
        channels = [RoiLevel(level.peak_dn_per_s, min(max(float(m), 0.0), level.peak_dn_per_s)) for m in means]
        if counts.ndim == 3:
            # (H, W, C): each channel's ROI mean averages H*W pixels, not H*W*C; counting the channels as
            # pixels would promise sqrt(C) more SNR than the plan delivers.
            level = dataclasses.replace(level, n_pixels=counts.shape[0] * counts.shape[1])
        peak_signal = float(counts.max())
        if peak_signal < 0.01 * sat and t < cam.max_exposure_s:
            longer = cam.floor(min(t * safety * sat / max(peak_signal, 1.0), cam.max_exposure_s))
            if longer is not None and longer > t:
                notes.append(f"test frame at {t:.4g} s reached {peak_signal / sat:.1%} of saturation: retaken at "
                             f"{longer:.4g} s")
                t = longer
                continue
        break
    if level is None:
        raise ExposureError(f"ROI still clips after {max_tries} test frames down to {taken[-1]:.4g} s")
    if clipped:
        notes.append("out of test frames after a clipped one: planned from the last unclipped frame")
    seen = None if detect_snr is None else detection_exposure_s(channels, noise, detect_snr, cam.gain, dark_frames)
    plan = plan_exposure(level, noise, target_snr, cam, pixel_snr_target=pixel_snr_target, safety=safety,
                         dark_frames=dark_frames, max_frames=max_frames, max_total_s=max_total_s,
                         shortest_s=seen)
    return MeterResult(plan=plan, level=level, test_exposures_s=tuple(taken), notes=tuple(notes))
