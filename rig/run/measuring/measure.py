"""One reading of whatever the camera sees: plan the exposures, capture the bracket and darks, merge, reduce.

The exposure plan comes from the previous point's light level (``RoiLevel`` per colour channel, rebuilt from
the numbers the journal keeps, so a resumed run plans exactly what an uninterrupted one did) or, with no
level yet or when the planned bracket clipped, from metering test frames. A fixed list of exposures skips
planning. The previous point only predicts this one's level: where this point turns out darker and its
dimmest channel falls short of the SNR goal, a second bracket planned from its own level tops it up. No frame is
planned so short that a pixel at a channel's ROI mean goes undetected (``DETECT_SNR``), however large the ROI.
A dark ROI (most pixels undetected, or a mean within its noise of zero: a black frame, a capped lens, a
point far darker than the last) is metered afresh before it is accepted; one still dark after metering is
kept, with ``RoiReading.dark`` set and a note, so the table can say so.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

import numpy as np
import numpy.typing as npt

from acquisition.cfa import colour_planes, counts_above_black, reduce_hdr_roi
from acquisition.exposure.metering import meter
from acquisition.exposure.plan import plan_exposure
from acquisition.exposure.snr import detection_exposure_s
from acquisition.exposure.spec import CameraTiming, RoiLevel
from acquisition.flatfield import FlatField
from acquisition.frame import Camera, Frame
from acquisition.hdr.merge import HdrImage, merge_linear
from acquisition.noise import SensorNoise
from acquisition.roi import RoiError, RoiReading
from rig.run.measuring.tiles import ImageSettings

if TYPE_CHECKING:
    from rig.run.measuring.exposure_sources import LevelSource

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
    #: Divides every merged image (vignetting and PRNU) where the rig file names one (``[camera] flat_field``).
    flat_field: FlatField | None = None
    #: Image mode (``[capture] mode = "image"``): every k x k tile on the sample a reading; None: point mode.
    image: ImageSettings | None = None
    #: ``[capture] motion``: "continuous", runs of points scanned moving (``rig.run.measuring.scan``); "stop": at rest.
    motion: Literal["stop", "continuous"] = "stop"
    #: Continuous motion's speed of the scanning joint in deg/s, as the sweep gives it; None: chosen per scan run,
    #: the fastest the axis, the blur and the camera allow (``rig.run.planning.scans.chosen_speed_deg_s``).
    scan_speed_deg_s: float | None = None
    #: What predicts each point's level before it is measured (``[capture] exposure_from``, ``exposure_model``), in
    #: the order asked (rig.run.measuring.exposure_ahead); (): the previous point's level plans the next.
    exposure_sources: tuple[LevelSource, ...] = ()

    def __post_init__(self) -> None:
        if self.scan_speed_deg_s is not None and self.motion != "continuous":
            raise ValueError(f"CaptureSettings: scan_speed_deg_s = {self.scan_speed_deg_s!r} with motion = "
                             f"{self.motion!r}; expected motion = 'continuous' (a speed means nothing at rest)")


#: A reading whose dimmest channel reaches less than this fraction of the SNR goal is topped up.
TOP_UP_BELOW = 0.95
#: Per-pixel SNR at each channel's ROI mean that a bracket's frames reach. The merge flags a pixel dark below 3
#: sigma of its zero-signal noise, and a reading whose pixels are mostly dark is dark; a large ROI's mean reaches
#: its SNR goal in frames too short for that, and a lit ROI (a reference tile) would read as dark.
DETECT_SNR = 5.0


@dataclass(frozen=True)
class Level:
    """An ROI's light level in counts/s at gain 1 (peak, mean, darkest pixel) over ``n_pixels`` pixels.

    ``channel_means`` holds each colour channel's ROI mean (counts/s); empty for a grey frame or a journal
    written before it was kept, when the overall mean stands in for every channel.
    """

    peak: float
    mean: float
    dark: float
    n_pixels: int
    channel_means: tuple[float, ...] = ()

    def roi_level(self) -> list[RoiLevel]:
        """The acquisition module's RoiLevel per channel for planning (the dimmest sets the SNR)."""
        # A dark channel's mean is noise about zero and may be negative: plan for no light, not an error.
        means = [min(max(m, 0.0), self.peak) for m in (self.channel_means or (self.mean,))]
        return [RoiLevel(self.peak, m, self.n_pixels, min(self.dark, m)) for m in means]

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (for the journal)."""
        d: dict[str, Any] = {"peak": self.peak, "mean": self.mean, "dark": self.dark, "n_pixels": self.n_pixels}
        if self.channel_means:
            d["channel_means"] = list(self.channel_means)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Level:
        """Inverse of ``as_dict``."""
        means = tuple(float(m) for m in d.get("channel_means", ()))
        return cls(float(d["peak"]), float(d["mean"]), float(d["dark"]), int(d["n_pixels"]), means)


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


def _crop(a: npt.NDArray[Any], roi: Box | None) -> npt.NDArray[Any]:
    if roi is None:
        return a
    x0, y0, x1, y1 = roi
    return a[y0:y1, x0:x1]


def _shoot(camera: Camera, exposure_s: float) -> Frame:
    # A BoundedCamera (the runner's) makes the same two calls in one hand-off to its worker thread.
    exposed = getattr(camera, "exposed_frames", None)
    if exposed is not None:
        frame: Frame = exposed(exposure_s)[1][0]
        return frame
    camera.set_exposure(exposure_s)
    return camera.capture()


def _darks(camera: Camera, exposures: tuple[float, ...], n: int) -> tuple[dict[float, list[Frame]], tuple[float, ...]]:
    take_dark = getattr(camera, "capture_dark", None)
    if n == 0 or take_dark is None:
        return {}, ()
    darks: dict[float, list[Frame]] = {}
    taken: list[float] = []
    series = getattr(camera, "exposed_series", None)
    if series is not None:  # a BoundedCamera (the runner's): every exposure's darks in one hand-off
        for settings, frames in series([(t, n) for t in sorted(set(exposures))], dark=True):
            darks[settings.exposure_s] = frames
            taken += [settings.exposure_s] * n
        return darks, tuple(taken)
    for t in sorted(set(exposures)):
        applied = camera.set_exposure(t).exposure_s
        frames = [take_dark() for _ in range(n)]
        darks[applied] = frames
        taken += [applied] * n
    return darks, tuple(taken)


def level_of(hdr: HdrImage, roi: Box | None) -> Level:
    """The ROI's level (counts/s) from a merged image: peak, mean and 1st-percentile pixel over channels.

    A raw mosaic's ROI is read per colour (binned 2x2 cells), so the next plan is made per colour too.
    """
    h, w = hdr.radiance.shape[:2]
    rad = colour_planes(hdr, roi if roi is not None else (0, 0, w, h))
    ok = np.isfinite(rad)
    every = bool(ok.all())
    finite = rad.reshape(-1) if every else rad[ok]  # the same values in the same order
    n = int(rad.shape[0] * rad.shape[1])
    if finite.size == 0:
        return Level(0.0, 0.0, 0.0, n)
    means: tuple[float, ...] = ()
    if rad.ndim == 3 and rad.shape[-1] > 1:
        # A clipped pixel is not finite; a channel with none left keeps the overall mean, not a NaN.
        planes = rad.reshape(-1, rad.shape[-1])
        if every:  # nanmean's own steps where nothing is NaN: the channel sums over the pixel count
            per = np.true_divide(planes.sum(axis=0), np.full(planes.shape[-1], planes.shape[0], dtype=np.intp))
        else:
            with np.errstate(invalid="ignore"):
                per = np.nanmean(np.where(ok, rad, np.nan).reshape(-1, rad.shape[-1]), axis=0)
        means = tuple(m if math.isfinite(m) else float(finite.mean()) for m in per.tolist())
    return Level(float(finite.max()), float(finite.mean()), float(max(_percentile(finite, 1.0), 0.0)), n, means)


def _percentile(values: npt.NDArray[np.float64], q: float) -> float:
    """``np.percentile(values, q)`` (linear method) of a 1-D array of finite values, by numpy's own arithmetic.

    numpy's general quantile machinery was a visible share of a reading for a 16-pixel ROI; this is what it comes
    down to there: the virtual index (n - 1) q / 100, the two order statistics around it (partitioned at numpy's
    points), numpy's lerp.
    """
    n = values.size
    vi = (n - 1) * (q / 100)
    if not 0 <= vi < n - 1:  # the ends (and one value): numpy takes the last, or the first, order statistic
        return float(np.percentile(values, q))
    k = math.floor(vi)
    # numpy's partition points, so that equal values (0.0 and -0.0) land where numpy's land
    lo, hi = np.partition(values, sorted({0, -1, k, k + 1}))[k : k + 2].tolist()
    t = vi - k
    diff = hi - lo
    return hi - diff * (1 - t) if t >= 0.5 else lo + diff * t


def take_reading(camera: Camera, settings: CaptureSettings, previous: Level | None) -> Reading:
    """Plan, capture, merge and reduce one reading of the camera's ROI, in counts/s at gain 1."""
    if settings.exposures_s is not None:
        return _capture(camera, settings, tuple(settings.exposures_s), (), ())
    notes: tuple[str, ...] = ()
    if previous is not None and previous.peak > 0:
        plan = plan_exposure(previous.roi_level(), settings.noise, settings.target_snr, settings.timing,
                             max_frames=settings.max_frames, dark_frames=settings.dark_frames,
                             shortest_s=_seen_s(previous, settings))  # fmt: skip
        frames = _frames(camera, plan.exposures_s)
        try:
            check = _roi_check(settings, frames)
        except RoiError:
            # Every ROI pixel clipped in every frame (a dark point followed by a specular peak): meter.
            notes = ("the bracket planned from the previous point clipped every pixel: metered afresh",)
        else:
            # Clipped pixels would be left out of the mean, and they are the brightest: never keep that.
            if check.roi.dark:
                notes = ("the bracket planned from the previous point left the ROI dark: metered afresh",)
            elif not check.roi.lower_bound and not np.any(check.roi.n_flagged):
                reading = _topped_up(camera, settings, frames, check)
                # The check merged without darks, whose noise raises the final merge's dark threshold.
                if not reading.roi.dark:
                    return reading
                notes = ("the bracket planned from the previous point left the ROI dark: metered afresh",)
            else:
                notes = ("the bracket planned from the previous point clipped: metered afresh",)

    def take_roi(t: float) -> npt.NDArray[np.float64]:
        return counts_above_black(_shoot(camera, t), settings.roi)

    metered = meter(take_roi, settings.noise, settings.target_snr, settings.timing,
                    start_exposure_s=settings.first_exposure_s, dark_frames=settings.dark_frames,
                    max_frames=settings.max_frames, detect_snr=DETECT_SNR)  # fmt: skip
    reading = _capture(camera, settings, metered.plan.exposures_s, metered.test_exposures_s, notes + metered.notes)
    if reading.roi.dark:
        still = "the ROI is dark even after metering (no light detected): kept, flagged dark"
        return dataclasses.replace(reading, notes=(*reading.notes, still))
    return reading


def _seen_s(level: Level, settings: CaptureSettings) -> float | None:
    """The shortest frame (s) in which a pixel at each channel's mean of ``level`` has SNR ``DETECT_SNR``."""
    return detection_exposure_s(level.roi_level(), settings.noise, DETECT_SNR, settings.timing.gain,
                                settings.dark_frames)  # fmt: skip


def snr_reached(reading: RoiReading) -> float:
    """The reading's photon-and-read-noise SNR in its dimmest channel; inf where no channel has noise.

    The propagated error is what exposure controls; the pixel scatter of a small ROI is itself noisy, and
    where it is real (a gradient across the ROI) more frames would not shrink it.
    """
    mean = np.atleast_1d(np.asarray(reading.mean, dtype=np.float64))
    se = np.atleast_1d(np.asarray(reading.std_error_propagated, dtype=np.float64))
    if mean.shape == se.shape:  # in Python numbers, 1-3 channels: the same quotients, without numpy's calls
        ratios = [abs(m) / e for m, e in zip(mean.tolist(), se.tolist(), strict=True) if e > 0]
        if not ratios:
            return float("inf")
        if all(r == r for r in ratios):  # numpy's min is NaN if one is, Python's depends on the order
            return min(ratios)
    ok = se > 0
    return float(np.min(np.abs(mean[ok]) / se[ok])) if np.any(ok) else float("inf")


def _topped_up(camera: Camera, settings: CaptureSettings, frames: list[Frame], first: _Check) -> Reading:
    """The reading with darks, after a second bracket where the first fell short of the SNR goal."""
    reached = snr_reached(first.roi)
    notes: tuple[str, ...] = ()
    level = first.level if reached < TOP_UP_BELOW * settings.target_snr else None
    if level is not None and level.peak > 0:
        # Inverse-variance merging adds SNRs in quadrature: plan only the part still missing.
        missing = float(np.sqrt(settings.target_snr**2 - reached**2))
        plan = plan_exposure(level.roi_level(), settings.noise, missing, settings.timing,
                             max_frames=settings.max_frames, dark_frames=settings.dark_frames,
                             shortest_s=_seen_s(level, settings))  # fmt: skip
        frames = frames + _frames(camera, plan.exposures_s)
        notes = (f"SNR {reached:.0f} of {settings.target_snr:g} from the bracket planned on the previous point: "
                 f"topped up with {len(plan.exposures_s)} more frame(s)",)  # fmt: skip
    return _merge(camera, settings, frames, (), notes)


@dataclass(frozen=True)
class _Check:
    """A bracket merged without darks to judge it: its ROI reading, and its level (counts/s) on demand."""

    roi: RoiReading
    hdr: HdrImage
    box: Box

    @property
    def level(self) -> Level:
        """The level a top-up is planned from (only a top-up needs it, so it is not worked out before)."""
        return level_of(self.hdr, self.box)


def _check_settings(settings: CaptureSettings) -> tuple[CaptureSettings, Box | None]:
    """The settings a bracket is judged with (no darks, the ROI within the crop) and the crop (pixels) or None."""
    check = dataclasses.replace(settings, dark_frames=0)
    crop: Box | None = None
    if settings.roi is not None:
        x0, y0, x1, y1 = settings.roi
        cx, cy = x0 - x0 % 2, y0 - y0 % 2
        crop = (cx, cy, x1 + x1 % 2, y1 + y1 % 2)
        check = dataclasses.replace(check, roi=(x0 - cx, y0 - cy, x1 - cx, y1 - cy))
    return check, crop


def _cropped(frame: Frame, crop: Box) -> Frame:
    """``frame`` cut to ``crop`` (pixels), its origin moved with it."""
    origin = (frame.origin_xy[0] + crop[0], frame.origin_xy[1] + crop[1])
    return dataclasses.replace(frame, data=_crop(frame.data, crop), origin_xy=origin)


def _roi_check(settings: CaptureSettings, frames: list[Frame]) -> _Check:
    """The frames merged over the ROI alone, without darks: enough to judge them, at the ROI's cost.

    The crop is widened to even pixel bounds so a raw mosaic keeps its colour-filter phase.
    """
    check, crop = _check_settings(settings)
    if crop is not None:
        frames = [_cropped(f, crop) for f in frames]
    hdr, box = _merged(check, frames, None)
    return _Check(reduce_hdr_roi(hdr, box), hdr, box)


def _capture(
    camera: Camera,
    settings: CaptureSettings,
    exposures: tuple[float, ...],
    test: tuple[float, ...],
    notes: tuple[str, ...],
) -> Reading:
    return _merge(camera, settings, _frames(camera, exposures), test, notes)


def _frames(camera: Camera, exposures: tuple[float, ...]) -> list[Frame]:
    return [_shoot(camera, t) for t in exposures]


def _merge(
    camera: Camera | None,
    settings: CaptureSettings,
    frames: list[Frame],
    test: tuple[float, ...],
    notes: tuple[str, ...],
) -> Reading:
    """Merge and reduce the frames, with the camera's dark frames (none without a camera)."""
    applied = tuple(f.exposure_s for f in frames)
    darks, dark_taken = _darks(camera, applied, settings.dark_frames) if camera is not None else ({}, ())
    hdr, roi = _merged(settings, frames, darks or None)
    reading = reduce_hdr_roi(hdr, roi)
    return Reading(reading, hdr, applied, dark_taken, test, level_of(hdr, roi), notes)


def _merged(
    settings: CaptureSettings, frames: list[Frame], darks: dict[float, list[Frame]] | None
) -> tuple[HdrImage, Box]:
    """The frames merged (with ``darks`` where given) and flat-fielded, and the ROI box (pixels) to reduce."""
    hdr = merge_linear(frames, settings.noise, darks=darks)
    if settings.flat_field is not None:
        hdr = settings.flat_field.apply(hdr, frames[0].origin_xy)
    h, w = hdr.radiance.shape[:2]
    return hdr, settings.roi if settings.roi is not None else (0, 0, w, h)
