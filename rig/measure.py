"""One reading of whatever the camera sees: plan the exposures, capture the bracket and darks, merge, reduce.

The exposure plan comes from the previous point's light level (a ``RoiLevel`` rebuilt from the four numbers
the journal keeps, so a resumed run plans exactly what an uninterrupted one did) or, with no level yet or
when the planned bracket clipped, from metering test frames. A fixed list of exposures skips planning.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from acquisition.exposure import plan_exposure
from acquisition.exposure_types import CameraTiming, RoiLevel
from acquisition.frame import Camera, Frame
from acquisition.hdr import HdrImage, merge_linear
from acquisition.metering import meter
from acquisition.noise import SensorNoise
from acquisition.roi import RoiError, RoiReading, reduce_roi

Box = tuple[int, int, int, int]


@dataclass(frozen=True)
class CaptureSettings:
    """How each reading is exposed: SNR target of the ROI mean, frame limits, darks, ROI box (pixels)."""

    noise: SensorNoise
    timing: CameraTiming
    target_snr: float = 200.0
    exposures_s: tuple[float, ...] | None = None
    max_frames: int = 5
    dark_frames: int = 1
    first_exposure_s: float = 0.01
    roi: Box | None = None


@dataclass(frozen=True)
class Level:
    """An ROI's light level in counts/s at gain 1 (peak, mean, darkest pixel) over ``n_pixels`` pixels."""

    peak: float
    mean: float
    dark: float
    n_pixels: int

    def roi_level(self) -> RoiLevel:
        """The acquisition module's RoiLevel for planning."""
        return RoiLevel(self.peak, self.mean, self.n_pixels, self.dark)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (for the journal)."""
        return {"peak": self.peak, "mean": self.mean, "dark": self.dark, "n_pixels": self.n_pixels}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Level:
        """Inverse of ``as_dict``."""
        return cls(float(d["peak"]), float(d["mean"]), float(d["dark"]), int(d["n_pixels"]))


@dataclass(frozen=True)
class Reading:
    """A merged, reduced reading (counts/s) with the exposures that made it and the level for the next plan."""

    roi: RoiReading
    hdr: HdrImage
    exposures_s: tuple[float, ...]
    dark_exposures_s: tuple[float, ...]
    test_exposures_s: tuple[float, ...]
    level: Level
    notes: tuple[str, ...]


def _counts_above_black(frame: Frame) -> npt.NDArray[np.float64]:
    black = np.asarray(frame.black_level, dtype=np.float64)
    data = np.asarray(frame.data, dtype=np.float64)
    if black.ndim == 1 and data.ndim == 3 and black.size == data.shape[-1]:
        return data - black
    return data - float(np.max(black))


def _crop(a: npt.NDArray[Any], roi: Box | None) -> npt.NDArray[Any]:
    if roi is None:
        return a
    x0, y0, x1, y1 = roi
    return a[y0:y1, x0:x1]


def _shoot(camera: Camera, exposure_s: float) -> Frame:
    camera.set_exposure(exposure_s)
    return camera.capture()


def _darks(camera: Camera, exposures: tuple[float, ...], n: int) -> tuple[dict[float, list[Frame]], tuple[float, ...]]:
    take_dark = getattr(camera, "capture_dark", None)
    if n == 0 or take_dark is None:
        return {}, ()
    darks: dict[float, list[Frame]] = {}
    taken: list[float] = []
    for t in sorted(set(exposures)):
        applied = camera.set_exposure(t).exposure_s
        darks[applied] = [take_dark() for _ in range(n)]
        taken += [applied] * n
    return darks, tuple(taken)


def level_of(hdr: HdrImage, roi: Box | None) -> Level:
    """The ROI's level (counts/s) from a merged image: peak, mean and 1st-percentile pixel over channels."""
    rad = _crop(hdr.radiance, roi)
    finite = rad[np.isfinite(rad)]
    if finite.size == 0:
        return Level(0.0, 0.0, 0.0, int(rad.shape[0] * rad.shape[1]))
    return Level(float(finite.max()), float(finite.mean()), float(max(np.percentile(finite, 1.0), 0.0)),
                 int(rad.shape[0] * rad.shape[1]))  # fmt: skip


def take_reading(camera: Camera, settings: CaptureSettings, previous: Level | None) -> Reading:
    """Plan, capture, merge and reduce one reading of the camera's ROI, in counts/s at gain 1."""
    if settings.exposures_s is not None:
        return _capture(camera, settings, tuple(settings.exposures_s), (), ())
    notes: tuple[str, ...] = ()
    if previous is not None and previous.peak > 0:
        plan = plan_exposure(previous.roi_level(), settings.noise, settings.target_snr, settings.timing,
                             max_frames=settings.max_frames, dark_frames=settings.dark_frames)  # fmt: skip
        try:
            reading = _capture(camera, settings, plan.exposures_s, (), ())
        except RoiError:
            # Every ROI pixel clipped in every frame (a dark point followed by a specular peak): meter.
            notes = ("the bracket planned from the previous point clipped every pixel: metered afresh",)
        else:
            # Clipped pixels would be left out of the mean, and they are the brightest: never keep that.
            if not reading.roi.lower_bound and not np.any(reading.roi.n_flagged):
                return reading
            notes = ("the bracket planned from the previous point clipped: metered afresh",)

    def take_roi(t: float) -> npt.NDArray[np.float64]:
        return _crop(_counts_above_black(_shoot(camera, t)), settings.roi)

    metered = meter(take_roi, settings.noise, settings.target_snr, settings.timing,
                    start_exposure_s=settings.first_exposure_s, dark_frames=settings.dark_frames,
                    max_frames=settings.max_frames)  # fmt: skip
    return _capture(camera, settings, metered.plan.exposures_s, metered.test_exposures_s, notes + metered.notes)


def _capture(
    camera: Camera,
    settings: CaptureSettings,
    exposures: tuple[float, ...],
    test: tuple[float, ...],
    notes: tuple[str, ...],
) -> Reading:
    frames = [_shoot(camera, t) for t in exposures]
    applied = tuple(f.exposure_s for f in frames)
    darks, dark_taken = _darks(camera, applied, settings.dark_frames)
    hdr = merge_linear(frames, settings.noise, darks=darks or None)
    h, w = hdr.radiance.shape[:2]
    roi = settings.roi if settings.roi is not None else (0, 0, w, h)
    reading = reduce_roi(hdr.radiance, hdr.variance, roi, flags=hdr.saturated)
    return Reading(reading, hdr, applied, dark_taken, test, level_of(hdr, roi), notes)
