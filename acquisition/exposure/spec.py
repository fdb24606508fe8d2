"""The vocabulary of exposure planning: ROI light levels, camera timing, plans, and their validation.

Units: ROI levels are rates in counts/s above black at gain 1 (the HDR merge's radiance unit: counts over
exposure x gain), so a frame at gain g collects ``r g t`` counts; exposures in seconds. What a plan's SNRs
mean is explained in ``acquisition.exposure.plan``, which makes the plans.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from acquisition.noise import SensorNoise
from model.errors import GonioError

Steps = Sequence[float] | Callable[[float], float]
"""The camera's available exposures in seconds: a list, or a function mapping a request to what it applies."""


class ExposureError(GonioError, ValueError):
    """No exposure satisfies a hard constraint: the ROI saturates at the shortest exposure, or no step fits."""


def _finite(owner: str, name: str, value: float, lo: float = 0.0, lo_open: bool = False) -> float:
    v = float(value)
    if not math.isfinite(v) or v < lo or (lo_open and v == lo):
        cmp = ">" if lo_open else ">="
        raise ValueError(f"{owner}.{name} = {value!r}: expected a finite number {cmp} {lo:g}")
    return v


@dataclass(frozen=True)
class RoiLevel:
    """Light level of an ROI in counts/s above black at gain 1: predicted by a model or metered.

    Parameters
    ----------
    peak_dn_per_s:
        Brightest pixel of the ROI (must not saturate).
    mean_dn_per_s:
        Mean over the ROI's pixels (the reading whose SNR is planned).
    n_pixels:
        Pixels averaged into the ROI reading (per channel).
    dark_dn_per_s:
        Darkest pixel level the per-pixel SNR target applies to (e.g. the 1st percentile); None if unknown.
    rates_dn_per_s, weights:
        Optional distribution of the ROI's pixel levels (e.g. bin means), weights summing to 1. With it the
        ROI SNR of a bracket whose long frames saturate part of the ROI is exact; without it, it is a
        lower bound computed from the frames that saturate no ROI pixel.
    """

    peak_dn_per_s: float
    mean_dn_per_s: float
    n_pixels: int = 1
    dark_dn_per_s: float | None = None
    rates_dn_per_s: tuple[float, ...] = ()
    weights: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        peak = _finite("RoiLevel", "peak_dn_per_s", self.peak_dn_per_s)
        mean = _finite("RoiLevel", "mean_dn_per_s", self.mean_dn_per_s)
        if mean > peak * (1 + 1e-12):
            raise ValueError(f"RoiLevel: mean_dn_per_s {mean!r} exceeds peak_dn_per_s {peak!r}")
        if int(self.n_pixels) != self.n_pixels or self.n_pixels < 1:
            raise ValueError(f"RoiLevel.n_pixels = {self.n_pixels!r}: expected a whole number >= 1")
        if self.dark_dn_per_s is not None:
            dark = _finite("RoiLevel", "dark_dn_per_s", self.dark_dn_per_s)
            if dark > mean * (1 + 1e-12):
                raise ValueError(f"RoiLevel: dark_dn_per_s {dark!r} exceeds mean_dn_per_s {mean!r}")
        if len(self.rates_dn_per_s) != len(self.weights):
            raise ValueError(
                f"RoiLevel: {len(self.rates_dn_per_s)} rates_dn_per_s but {len(self.weights)} weights"
            )
        if self.rates_dn_per_s:
            r = np.asarray(self.rates_dn_per_s, dtype=float)
            w = np.asarray(self.weights, dtype=float)
            if not (np.all(np.isfinite(r)) and np.all(r >= 0) and np.all(w >= 0) and abs(w.sum() - 1) < 1e-9):
                raise ValueError("RoiLevel: rates_dn_per_s must be finite >= 0 and weights >= 0 summing to 1")
            if r.max() > peak * (1 + 1e-9):
                raise ValueError(f"RoiLevel: a rate {r.max()!r} exceeds peak_dn_per_s {peak!r}")

    @classmethod
    def uniform(cls, rate_dn_per_s: float, n_pixels: int = 1) -> RoiLevel:
        """A uniform ROI: every one of ``n_pixels`` pixels receives ``rate_dn_per_s`` counts/s."""
        return cls(rate_dn_per_s, rate_dn_per_s, n_pixels, rate_dn_per_s)

    @classmethod
    def from_pixels(cls, rates_dn_per_s: npt.ArrayLike, dark_percentile: float = 1.0, n_bins: int = 32) -> RoiLevel:
        """Level of an ROI from its pixels' rates in counts/s (a prediction, or a test frame divided by t).

        Peak is the maximum, dark the ``dark_percentile`` percentile; the distribution is kept as the means
        of ``n_bins`` equal-count bins of the sorted rates, so it has the exact ROI mean. Negative rates
        (noise around zero) count as 0 for the distribution.
        """
        r = np.sort(np.asarray(rates_dn_per_s, dtype=float).reshape(-1))
        if r.size == 0 or not np.all(np.isfinite(r)):
            raise ValueError("RoiLevel.from_pixels: expected a non-empty array of finite rates")
        r = np.maximum(r, 0.0)
        bins = [b for b in np.array_split(r, min(n_bins, r.size)) if b.size]
        rates = tuple(float(b.mean()) for b in bins)
        weights = tuple(b.size / r.size for b in bins)
        return cls(
            peak_dn_per_s=float(r[-1]),
            mean_dn_per_s=min(float(r.mean()), float(r[-1])),
            n_pixels=int(r.size),
            dark_dn_per_s=min(float(np.percentile(r, dark_percentile)), float(r.mean())),
            rates_dn_per_s=rates,
            weights=weights,
        )


@dataclass(frozen=True)
class CameraTiming:
    """What the camera can do: exposure range in seconds, available steps, gain, per-frame overhead in seconds.

    ``steps`` is either the list of exposures the camera offers, or a function returning the exposure the
    camera applies for a request (assumed non-decreasing); None for a continuous range. ``overhead_s`` is
    the readout and transfer time per frame, counted in the plan's total time.
    """

    min_exposure_s: float = 1e-5
    max_exposure_s: float = 30.0
    steps: Steps | None = None
    gain: float = 1.0
    overhead_s: float = 0.0

    def __post_init__(self) -> None:
        lo = _finite("CameraTiming", "min_exposure_s", self.min_exposure_s, lo_open=True)
        hi = _finite("CameraTiming", "max_exposure_s", self.max_exposure_s, lo_open=True)
        if hi < lo:
            raise ValueError(f"CameraTiming: max_exposure_s {hi!r} is below min_exposure_s {lo!r}")
        _finite("CameraTiming", "gain", self.gain, lo_open=True)
        _finite("CameraTiming", "overhead_s", self.overhead_s)
        if self.steps is not None and not callable(self.steps):
            s = [float(x) for x in self.steps]
            if not s or not all(math.isfinite(x) and x > 0 for x in s):
                raise ValueError("CameraTiming.steps: expected positive finite exposures in seconds")
            inside = sorted({x for x in s if lo * (1 - 1e-12) <= x <= hi * (1 + 1e-12)})
            if not inside:
                raise ValueError(f"CameraTiming.steps: none lies within [{lo:g}, {hi:g}] s")
            object.__setattr__(self, "steps", tuple(inside))

    def floor(self, t_s: float) -> float | None:
        """Longest available exposure in seconds not above ``t_s``; None if even the shortest is longer."""
        lo, hi = self.min_exposure_s, self.max_exposure_s
        if self.steps is None:
            return min(t_s, hi) if t_s >= lo else None
        if isinstance(self.steps, tuple):
            arr = np.asarray(self.steps)
            i = int(np.searchsorted(arr, t_s * (1 + 1e-12), side="right")) - 1
            return float(arr[i]) if i >= 0 else None
        q = self.steps
        assert callable(q)
        if q(lo) > t_s:
            return None
        if q(hi) <= t_s:
            return float(q(hi))
        a, b = math.log(lo), math.log(hi)  # q(e^a) <= t_s < q(e^b): bisect the request
        for _ in range(80):
            m = 0.5 * (a + b)
            if q(math.exp(m)) <= t_s:
                a = m
            else:
                b = m
        return float(q(math.exp(a)))

    def ceil(self, t_s: float) -> float | None:
        """Shortest available exposure in seconds not below ``t_s``; None if even the longest is shorter."""
        lo, hi = self.min_exposure_s, self.max_exposure_s
        if self.steps is None:
            return max(t_s, lo) if t_s <= hi else None
        if isinstance(self.steps, tuple):
            arr = np.asarray(self.steps)
            i = int(np.searchsorted(arr, t_s * (1 - 1e-12), side="left"))
            return float(arr[i]) if i < arr.size else None
        q = self.steps
        assert callable(q)
        if q(hi) < t_s:
            return None
        if q(lo) >= t_s:
            return float(q(lo))
        a, b = math.log(lo), math.log(hi)  # q(e^a) < t_s <= q(e^b)
        for _ in range(80):
            m = 0.5 * (a + b)
            if q(math.exp(m)) >= t_s:
                b = m
            else:
                a = m
        return float(q(math.exp(b)))


@dataclass(frozen=True)
class ExposurePlan:
    """Frames to capture for one measurement point and what they are expected to achieve.

    Parameters
    ----------
    exposures_s:
        Light frames, shortest first, repeats listed (seconds).
    expected_snr:
        SNR of the ROI mean reading the linear merge achieves with these frames (see
        ``acquisition.exposure.plan``);
        the minimum over channels when planned for several.
    target_snr:
        The ROI SNR asked for.
    reached:
        Whether every target (ROI, and per-pixel if asked) is met; False means the plan is the best within
        the limits and ``expected_snr`` is what it achieves (the notes say which limit bound it).
    total_exposure_s:
        Sum of the light frames' exposures (seconds).
    total_time_s:
        Capture time in seconds: light and dark frames' exposures plus ``overhead_s`` per frame.
    saturation_margin:
        Factor by which the ROI peak may be brighter than planned before it clips in the shortest frame
        (1 / 0.8 = 1.25 for the default safety); < 1 means it clips in every frame.
    dark_exposures_s:
        Dark frames (seconds) for the master darks, ``dark_frames`` per distinct exposure.
    expected_pixel_snr:
        Lowest per-pixel SNR over the ROI's levels from dark to peak; None unless a per-pixel target or a
        dark level was given.
    pixel_snr_target:
        The per-pixel SNR asked for, or None.
    gain:
        Gain the frames are taken at.
    notes:
        How the plan was reached, in words (limits that bound it, saturation in a bracket, lower bounds).
    """

    exposures_s: tuple[float, ...]
    expected_snr: float
    target_snr: float
    reached: bool
    total_exposure_s: float
    total_time_s: float
    saturation_margin: float
    dark_exposures_s: tuple[float, ...] = ()
    expected_pixel_snr: float | None = None
    pixel_snr_target: float | None = None
    gain: float = 1.0
    notes: tuple[str, ...] = ()

    @property
    def n_frames(self) -> int:
        """Number of light frames."""
        return len(self.exposures_s)


@dataclass(frozen=True)
class _Rules:
    """What bounds a plan's frames: the sensor, the camera, the planner's limits, and saturation at the gain."""

    noise: SensorNoise
    cam: CameraTiming
    safety: float  # fraction of saturation the ROI peak may reach in frames that must not clip
    dark_frames: int  # per distinct exposure
    max_frames: int
    budget: float  # seconds of capture, inf without a limit
    sat: float  # saturation, counts above black at the camera's gain
    dr: float  # dark signal, counts/s at the camera's gain
