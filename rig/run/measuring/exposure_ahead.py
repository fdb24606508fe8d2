"""Exposure planned ahead: each point's level predicted before it is measured, from a model or an earlier pass.

Without a source, a point is planned from the previous point's level (``rig.run.measuring.measure``) and a scan frame
from the previous frame's (``rig.run.measuring.scan``): a specular highlight entering the view is a jump the plan
does not see coming (a scan frame clips and is measured at rest), and a point far darker loses SNR. With
``[capture] exposure_model`` or ``exposure_from`` (``rig.run.measuring.exposure_sources``), ``ExposureAhead.plan``
predicts the level where the next point is:

    level per channel = scale x signal(next directions)

``scale`` is calibrated from the run's own readings (the median of measured / signal over the last
``CALIBRATION_POINTS`` usable points; before any, the source's prior: 1 for an earlier pass on the rig, none for a
model, whose absolute scale is unknown: its shape is what it brings). The predicted level borrows its pixel
statistics (peak over mean, darkest pixel over mean, pixel count) from the pass's level at that pair where its
journal kept one (a highlight's peak stands further above its mean than its neighbours'), else from the previous
point's level. The plan from it keeps every safety of the previous-level rule (a scan frame's peak at
``SCAN_SAFETY`` of saturation, a stop-and-go bracket that clips is metered afresh).

Fallback: a source that has no prediction there (a model beyond the horizon or dark, no pass point within reach, no
scale yet), or whose prediction at the last point was off by more than ``OFF_FACTOR``, gives way to the next source,
and the last of all to the previous-level rule. Every point's record says which planned it
(``exposure_planned_from``: "model", "pass", "previous", or "metered" for a first point metered afresh), and a
prediction off by more than ``OFF_FACTOR`` is an event (``exposure_prediction_off``).

The state (each source's recent ratios, whether it was off) is a function of the journal's point records in plan
order, so a resumed run replays them (``replay``) and plans exactly what an uninterrupted one did.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from rig.run.measuring.exposure_sources import LevelSource
from rig.run.measuring.measure import Level

#: A prediction off by more than this factor (either way) is an event, and its source sits out the next point.
OFF_FACTOR = 4.0
#: Readings (the most recent usable ones) whose median ratio to the signal is the source's scale.
CALIBRATION_POINTS = 5

Directions = tuple[float, float, float, float]


def _means(level: Level) -> npt.NDArray[np.float64]:
    """A level's per-channel means (counts/s); the overall mean for a grey one."""
    return np.asarray(level.channel_means or (level.mean,), dtype=np.float64)


def _matched(signal: npt.NDArray[np.float64], channels: int) -> npt.NDArray[np.float64]:
    """The signal on the level's channels: grey levels see the channels' mean, colour ones a grey signal in each."""
    if signal.size == channels:
        return signal
    if channels == 1:
        return np.asarray([float(signal.mean())])
    return np.full(channels, float(signal.mean()))


@dataclass
class _Track:
    """One source and what the run taught it: log(measured / signal) per usable point, and the last verdict."""

    source: LevelSource
    ratios: list[npt.NDArray[np.float64]] = field(default_factory=list)
    off: bool = False

    def log_scale(self, channels: int) -> npt.NDArray[np.float64] | None:
        recent = [r for r in self.ratios if r.size == channels][-CALIBRATION_POINTS:]
        if recent:
            return np.asarray(np.median(np.stack(recent), axis=0), dtype=np.float64)
        prior = self.source.prior_scale
        return None if prior is None else np.full(channels, math.log(prior))


@dataclass(frozen=True)
class Missed:
    """A prediction off by more than OFF_FACTOR: its source, the factor (measured / predicted) and both means."""

    source: str
    factor: float
    predicted: tuple[float, ...]
    measured: tuple[float, ...]


class ExposureAhead:
    """Plans each point's level from its sources in order; see the module docstring."""

    def __init__(self, sources: Sequence[LevelSource]) -> None:
        self.tracks = [_Track(s) for s in sources]

    def plan(self, directions_deg: Directions, previous: Level | None) -> tuple[Level | None, str]:
        """The level (counts/s) to plan the point at ``directions_deg`` from, and which source gave it."""
        for track in self.tracks:
            if track.off:
                continue
            signal = track.source.signal(directions_deg)
            if signal is None:
                continue
            # The pass's own level there knows the point's pixels (a highlight's peak over its mean); else the last's.
            template = _level(track.source.template(directions_deg)) or previous
            if template is None:
                continue
            shape = _means(template)
            if not (np.all(shape > 0) and template.peak > 0 and template.mean > 0):
                continue  # a dark template has no shape to borrow
            scale = track.log_scale(shape.size)
            if scale is None:
                continue
            return _shaped(template, np.exp(scale) * _matched(signal, shape.size)), track.source.name
        return previous, "previous" if previous is not None else "metered"

    def observe(self, directions_deg: Directions, level: Level, usable: bool = True) -> list[Missed]:
        """Learn from the level (counts/s) measured at ``directions_deg``; the sources whose prediction missed.

        ``usable``: False for a reading that is a lower bound or dark, whose level says too little to calibrate on.
        """
        measured = _means(level)
        if not usable or not np.all(np.isfinite(measured)) or not np.all(measured > 0):
            return []
        missed = []
        for track in self.tracks:
            signal = track.source.signal(directions_deg)
            if signal is None:
                track.off = False  # nothing predicted here: no verdict on the next point
                continue
            predicted = _matched(signal, measured.size)
            ratio = np.log(measured / predicted)
            scale = track.log_scale(measured.size)
            if scale is not None:
                off = float(np.max(np.abs(ratio - scale)))
                track.off = off > math.log(OFF_FACTOR)
                if track.off:
                    worst = int(np.argmax(np.abs(ratio - scale)))
                    factor = float(math.exp(ratio[worst] - scale[worst]))
                    expected = tuple((np.exp(scale) * predicted).tolist())
                    missed.append(Missed(track.source.name, factor, expected, tuple(measured.tolist())))
            track.ratios.append(ratio)
        return missed

    def replay(self, records: Iterable[Mapping[str, Any]]) -> None:
        """Rebuild the state from a journal's point records (a resume), in plan order, as the run learnt it."""
        points = sorted((r for r in records if r.get("kind") == "point"), key=lambda r: int(r["position"]))
        for rec in points:
            usable = not rec.get("lower_bound", False) and not rec.get("dark", False)
            self.observe(target_of(rec), Level.from_dict(rec["level"]), usable)


def target_of(record: Mapping[str, Any]) -> Directions:
    """A point record's planned BRDF directions (deg): what its level was predicted at."""
    ti, pi, to, po = (float(v) for v in record["target_deg"])
    return ti, pi, to, po


def _level(d: Mapping[str, Any] | None) -> Level | None:
    try:
        return None if d is None else Level.from_dict(dict(d))
    except (KeyError, TypeError, ValueError):
        return None


def _shaped(template: Level, means: npt.NDArray[np.float64]) -> Level:
    """A level with per-channel ``means`` (counts/s) and ``template``'s peak, darkest pixel and pixel count ratios."""
    shape = _means(template)
    peak = template.peak * float(means.max()) / float(shape.max())
    ratio = float(means.mean()) / float(shape.mean())
    channel_means = tuple(means.tolist()) if template.channel_means else ()
    return dataclasses.replace(template, peak=peak, mean=template.mean * ratio, dark=template.dark * ratio,
                               channel_means=channel_means)  # fmt: skip
