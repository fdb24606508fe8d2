"""Continuous scans (``[capture] motion = "continuous"``): the arm sweeps at constant speed while the camera shoots.

A *scan run* is a stretch of consecutive planned points that differ in one joint only, monotonic in it, with no
reference reading or via pose between them (``scan_run``, ``rig.run.planning.scans``). The runner measures its
first point stop-and-go, as always; that reading's level plans the scan's exposure. ``Scanner.follow`` then sets
the scanning joint to the scan speed (``ScanLink.set_speed``: a Dynamixel's Profile Velocity, a GRBL's feed): the
sweep's ``scan_speed_deg_s`` as given, else the run's own, chosen from its first frame's exposure as the fastest
the axis, the blur and the camera's pace allow (``rig.run.planning.scans.chosen_speed_deg_s``; a ``scan_speed``
event and every scanned record's ``scan.speed_deg_s`` say what it was). It then commands the run's last pose
once, and, while the arm moves, takes one frame per remaining point: it waits until the read-back says the
joint is half an exposure's travel short of the point, then shoots one exposure (and its darks) planned from the
previous frame's level (or that point's level predicted ahead, ``rig.run.measuring.exposure_ahead``), never above
``SCAN_SAFETY`` of saturation (in point mode a frame that clips anyway is dropped, and the runner measures that
point at rest). The arm comes to rest where the device rounds the run's end to (a whole count or step,
``ScanLink.stops_at``), which may be short of it: the last frame is aimed no further than ``END_SLACK_DEG`` short
of that resting place, which a rounded read-back may never show exactly.

Each frame's directions come from the joints interpolated to the exposure's middle, linearly between the
time-stamped read-backs just before and just after the frame (``interpolate``); the exposure is taken to end
when the camera's call returns. Motion blur is uniform motion over the exposure: the moving joint's variance
gains (speed x exposure)^2 / 12, through the runner's ``_uncertainty`` (which adds a joint's travel squared over
twelve). Blur beyond ``BLUR_FRACTION`` of the smallest step of the run warns (``ScanTooFast``), naming the blur
and the speed that would keep it within bounds. Gear play is not taken out during a scan (the load's flank is
not pinned by a one-sided approach): it stays in the uncertainty.

In image mode (``[capture] mode = "image"``) each frame is read as image mode reads a pose
(``rig.run.measuring.image_capture``): the camera streams whole frames, cut to the window of the tiles at the
point's pose widened by one tile, and the tiles are those seen from the mid-exposure pose, each with its own
directions, irradiance, standard error and footprint covariance. The blur is each tile's: the moving joint's
(speed x exposure)^2 / 12 carried to that tile's own directions (``tiles.motion_covariance``, the propagation
``_uncertainty`` uses) and added to its footprint covariance; the pose's own errors (encoder, play, calibration)
are the record's, as at a stop. A frame is planned from the previous frame's brightest tile (the tile holding
its brightest pixel: the rest reading's for the first), at ``SCAN_SAFETY`` of saturation. A frame whose tiles
clip is kept: a clipped tile is a lower bound, as a tile saturated in every frame of a stop's bracket is (one
frame here), the rest of the frame are samples, and the scan goes on (a ``scan_clipped_tiles`` event), the next
frame planned shorter from the clipped tile's level. A point where no whole tile would see the sample ends the
scan: the runner measures it at rest, as image mode measures such a pose.
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Protocol, cast

import numpy as np

from acquisition.exposure.plan import plan_exposure
from acquisition.exposure.spec import ExposureError
from acquisition.frame import Camera, Frame
from acquisition.hdr.merge import HdrFlag
from rig.instrument.alignment import aligned_forward, aligned_pose
from rig.instrument.direction_uncertainty import travel_variance_deg2
from rig.instrument.kinematics import Joints
from rig.instrument.kinematics_types import Directions
from rig.instrument.links.base import ScanLink
from rig.run.measuring.image_capture import ImageShot, plan_shot, whole_frames
from rig.run.measuring.measure import Level, Reading
from rig.run.measuring.tiles import motion_covariance, with_spread
from rig.run.planning.plan import PlannedPoint
from rig.run.planning.scans import (
    BLUR_FRACTION,
    SpeedChoice,
    chosen_speed_deg_s,
    frame_time_s,
    run_angles,
    run_time_s,
    scan_run,
    smallest_step_deg,
    stops_time_s,
)

#: Fraction of saturation a frame's ROI peak is planned at: the next point may be this much brighter (x4).
SCAN_SAFETY = 0.25
#: Longest clock step (s) between read-backs while waiting for the arm to reach a frame's start.
POLL_S = 0.05
#: How far short (deg) of where the arm comes to rest the last frame of a run is aimed: read-backs are rounded
#: (GRBL prints its unit to three decimals), so one may never quite show the resting place itself.
END_SLACK_DEG = 0.01


#: What set a scan run's speed, for its ``scan_speed`` event.
_WHY = {
    "given": "the sweep's scan_speed_deg_s",
    "axis": "the axis's max_speed_deg_s",
    "blur": "the blur bound for its first frame's exposure",
    "camera": "the camera's time for each frame and its darks",
}


class ScanTooFast(UserWarning):
    """A continuous scan's frames blur over more than BLUR_FRACTION of the sweep's step."""


@dataclass(frozen=True)
class Stamp:
    """The joints read back (deg) and the clock time (s) of the read-back's middle."""

    t_s: float
    joints: dict[str, float]


def interpolate(a: Stamp, b: Stamp, t_s: float) -> dict[str, float]:
    """The joint angles (deg) at clock time ``t_s`` (s), linear between two time-stamped read-backs."""
    if b.t_s <= a.t_s:
        return dict(b.joints)
    w = (t_s - a.t_s) / (b.t_s - a.t_s)
    return {k: v + w * (b.joints[k] - v) for k, v in a.joints.items()}


class ScanHost(Protocol):
    """What a scan needs of the runner (``rig.run.measuring.runner.Runner``)."""

    link: Any
    camera: Any
    clock: Any
    geometry: Any
    alignment: Any
    capture: Any
    plan: Any
    options: Any
    guard: Any
    store: Any
    _sides: dict[str, int]

    @property
    def guard_names(self) -> frozenset[str]: ...  # noqa: D102

    def now(self) -> float: ...  # noqa: D102

    def _read(self, previous: Level | None, capture: Any = None, camera: Camera | None = None) -> Reading: ...

    def planned_level(self, point: PlannedPoint, previous: Level | None) -> Level | None:
        """The level to plan ``point`` from: predicted ahead (rig.run.measuring.exposure_ahead), else ``previous``."""
        ...

    def observed(self, point: PlannedPoint, reading: Reading) -> None:
        """Teach the level's predictors what ``point`` measured."""
        ...

    def _event(self, what: str, message: str, **extra: Any) -> None: ...

    def _reading_fields(self, reading: Reading) -> dict[str, Any]: ...

    def point_head(self, point: PlannedPoint, pos: int, d: Directions, joints: Joints) -> dict[str, Any]:
        """A point record's first fields (the runner's)."""
        ...

    def _times(self, start: float, end: float) -> dict[str, Any]: ...

    def _uncertainty(self, before: Joints, after: Mapping[str, float], measured: Any) -> dict[str, Any]: ...

    def _distance(self, joints: Joints) -> dict[str, Any]: ...


class _Stamped:
    """The camera with every light frame bracketed by time-stamped read-backs of the joints."""

    exposed_frames = None  # measure._shoot then calls set_exposure and capture, which pass through here

    def __init__(self, camera: Camera, read: Callable[[], Stamp], clock: Any) -> None:
        self._camera, self._read, self._clock = camera, read, clock
        self.light: list[tuple[Stamp, float, Frame, Stamp]] = []  # before, clock at return, frame, after

    def __getattr__(self, name: str) -> Any:
        return getattr(self._camera, name)

    def capture(self) -> Frame:
        before = self._read()
        frame = self._camera.capture()
        end = self._clock.now()
        self.light.append((before, end, frame, self._read()))
        return frame


def scan_exposure(level: Level, capture: Any) -> float:
    """One frame's exposure (s): the planner's single frame for the SNR goal, its peak at SCAN_SAFETY of full."""
    try:
        plan = plan_exposure(level.roi_level(), capture.noise, capture.target_snr, capture.timing, safety=SCAN_SAFETY,
                             dark_frames=capture.dark_frames, max_frames=1)  # fmt: skip
    except ExposureError:  # too bright even at the shortest exposure: that frame clips and is measured at rest
        return float(capture.timing.min_exposure_s)
    return float(max(plan.exposures_s))


def rest_reading_s(level: Level, capture: Any) -> float:
    """Camera seconds a reading at rest planned from ``level`` takes (its frames, darks and overheads; 0 if none
    can be planned)."""
    if capture.exposures_s:  # fixed: each frame, and each distinct exposure's darks
        kinds = set(capture.exposures_s)
        frames = len(capture.exposures_s) + capture.dark_frames * len(kinds)
        return float(sum(capture.exposures_s) + capture.dark_frames * sum(kinds) + frames * capture.timing.overhead_s)
    try:
        plan = plan_exposure(level.roi_level(), capture.noise, capture.target_snr, capture.timing,
                             max_frames=capture.max_frames, dark_frames=capture.dark_frames)  # fmt: skip
    except ExposureError:
        return 0.0
    return float(plan.total_time_s)


class Scanner:
    """Scans the runs of a plan for one runner; see the module docstring."""

    def __init__(self, host: ScanHost, speed_deg_s: float | None) -> None:
        """``speed_deg_s``: the sweep's scan speed, kept as given; None: chosen per run (``_speed``)."""
        self.host, self.speed = host, None if speed_deg_s is None else float(speed_deg_s)
        self._stops_through = -1  # the last plan position of a run left to stop and go

    def _stamp(self) -> Stamp:
        t0 = self.host.clock.now()
        joints = self.host.link.read_positions()
        return Stamp(0.5 * (t0 + self.host.clock.now()), {k: float(v) for k, v in joints.items()})

    def follow(self, start: int, level: Level, done: set[int], slots: set[int],
               plan_level: Level | None = None) -> tuple[Level, list[int]]:  # fmt: skip
        """Scan on from plan position ``start`` (just measured at rest, at ``level``); the last frame's level and
        the positions measured. ``plan_level``: what the first frame is planned from (None: ``level``)."""
        h = self.host
        if start < self._stops_through:  # inside a run found faster stop and go
            return level, []
        run = scan_run(h.plan.points, start, done, slots, h.guard_names)
        link = h.link
        if run is None or not isinstance(link, ScanLink):
            return level, []
        joint, rest = run
        points = h.plan.points
        angles = run_angles(points, start, rest, joint)
        step = smallest_step_deg(angles)
        direction = 1.0 if angles[-1] > angles[0] else -1.0
        target = {k: float(v) for k, v in points[rest[-1]].joints.as_dict().items() if k in h.guard_names}
        legs = h.guard.legs(h.link, target)
        if len(legs) != 1:  # the straight sweep is not safe: stop and go instead
            return level, []
        planned = plan_level or level
        first = scan_exposure(h.planned_level(points[rest[0]], planned) or planned, h.capture)
        choice = self._speed(joint, step, first)
        if self.speed is None and self._stopping_is_faster(joint, angles, choice.speed_deg_s, first, planned):
            self._stops_through = rest[-1]
            h._event("scan_stopped", f"points {points[start].index} to {points[rest[-1]].index}: stopping at each "
                     f"is faster than scanning within the blur bound ({choice.speed_deg_s:.3g} deg/s); measured at "
                     "rest", joint=joint, speed_deg_s=choice.speed_deg_s, first_index=points[start].index)  # fmt: skip
            return level, []
        speed = link.set_speed({joint: choice.speed_deg_s})[joint]
        h._event("scan_speed", f"points {points[start].index} to {points[rest[-1]].index}: {joint} swept at "
                 f"{speed:.4g} deg/s ({_WHY[choice.bound]})", joint=joint, speed_deg_s=speed, bound=choice.bound,
                 first_index=points[start].index, points=len(rest), step_deg=step)  # fmt: skip
        # The arm comes to rest on the device's whole count or step nearest the run's end, which may fall short of
        # it: the last frame is aimed there, or the arm would be waited for until the move times out.
        end = link.stops_at(legs[0])[joint]
        measured: list[int] = []
        warned = False
        try:
            h.link.move_to(legs[0])
            h._sides = {}  # no one-sided approach during a scan: its play stays in the uncertainty
            for pos in rest:
                # Planned ahead where a model or an earlier pass predicts this point, else from the last frame.
                exposure = scan_exposure(h.planned_level(points[pos], planned) or planned, h.capture)
                blur = speed * exposure
                if blur > BLUR_FRACTION * step and not warned:
                    warned = True
                    self._too_fast(blur, step, exposure, speed)
                aim = float(points[pos].joints.as_dict()[joint])
                if pos == rest[-1]:
                    short = self._last_frame_short(joint, blur, exposure, speed, step)
                    if direction * (end - aim) < short:
                        aim = end - direction * short
                self._reach(joint, aim - direction * blur / 2, direction, speed)
                got = self._frame(pos, points[pos], level, exposure, (joint, direction * speed))
                if got is None:  # clipped (point mode), or no tile to read: this point and the rest at rest
                    break
                reading, planned = got
                h.observed(points[pos], reading)
                level = reading.level
                measured.append(pos)
        finally:
            h.link.wait_in_position(timeout_s=h.options.move_timeout_s)
            link.set_speed(None)
        return level, measured

    def _speed(self, joint: str, step: float, exposure: float) -> SpeedChoice:
        """The run's speed (deg/s): the sweep's as given, else the fastest the axis, the blur of a frame exposed
        ``exposure`` (s) over the smallest ``step`` (deg) and the camera's pace allow."""
        if self.speed is not None:
            return SpeedChoice(self.speed, "given")
        timing = self.host.capture.timing
        return chosen_speed_deg_s(step, exposure, self._limit(joint, "max_speed_deg_s"),
                                  dark_frames=self.host.capture.dark_frames,
                                  overhead_s=float(timing.overhead_s))  # fmt: skip

    def _stopping_is_faster(self, joint: str, angles: list[float], speed: float, exposure: float,
                            level: Level) -> bool:  # fmt: skip
        """Whether stopping at each of a run's points (moves, settling, a reading planned from ``level``) takes less
        time than scanning them at ``speed`` (deg/s) with frames of ``exposure`` (s)."""
        cap, h = self.host.capture, self.host
        top, accel = self._limit(joint, "max_speed_deg_s"), self._limit(joint, "max_accel_deg_s2")
        scan = run_time_s(angles, speed, accel, frame_time_s(exposure, cap.dark_frames, cap.timing.overhead_s))
        return stops_time_s(angles, top, accel, h.options.settle_s + rest_reading_s(level, cap)) < scan

    def _last_frame_short(self, joint: str, blur: float, exposure: float, speed: float, step: float) -> float:
        """How far short (deg) of where the arm comes to rest a run's last frame is aimed.

        The arm slows to rest over speed^2 / (2 accel): a frame across the arrival is placed off by up to a quarter
        of its blur, one across the slowing by accel x exposure^2 / 8, since the read-backs around it are joined
        by a straight line. Where that is more than a count of the read-back, the frame ends where the arm begins
        to slow (up to half a step short of its point: the record holds the angles the frame saw).
        """
        accel, count = self._limit(joint, "max_accel_deg_s2"), 1.0 / self._limit(joint, "units_per_joint_degree")
        if max(blur / 4, accel * exposure**2 / 8) <= count:
            return END_SLACK_DEG
        return min(blur / 2 + speed**2 / (2 * accel), step / 2) + END_SLACK_DEG

    def _limit(self, joint: str, key: str) -> float:
        """The joint's axis ``key`` (a limit in deg/s or deg/s^2, or units per degree): the rig file's axis, else the
        link's (inf: unknown)."""
        axis = getattr(self.host, "axes_by_name", {}).get(joint) or getattr(self.host.link, "axes", {}).get(joint)
        return float(getattr(axis, key, math.inf))

    def _too_fast(self, blur: float, step: float, exposure: float, speed: float) -> None:
        ok = BLUR_FRACTION * step / exposure
        message = (f"continuous scan too fast for its exposure: {exposure:.3g} s at {speed:.3g} deg/s blurs each "
                   f"frame over {blur:.3g} deg, more than {BLUR_FRACTION:g} of the {step:.3g} deg step; "
                   f"scan_speed_deg_s <= {ok:.3g} keeps it within bounds (the blur is in the directions' "
                   "uncertainty)")  # fmt: skip
        warnings.warn(message, ScanTooFast, stacklevel=3)
        self.host._event("scan_too_fast", message, blur_deg=blur, speed_within_deg_s=ok)

    def _reach(self, joint: str, angle: float, direction: float, speed: float) -> None:
        """Wait (clock time) until the read-back of ``joint`` passes ``angle`` (deg), or the arm stops short."""
        clock = self.host.clock
        deadline = clock.now() + self.host.options.move_timeout_s
        while clock.now() < deadline:
            remaining = direction * (angle - float(self.host.link.read_positions()[joint]))
            if remaining <= 0:
                return
            clock.sleep(min(max(remaining / speed, 1e-4), POLL_S))

    def _frame(self, pos: int, point: PlannedPoint, level: Level, exposure: float,
               velocity: tuple[str, float]) -> tuple[Reading, Level] | None:  # fmt: skip
        """One frame at ``exposure`` (s) while ``velocity`` (joint, deg/s) moves the arm, journaled as ``point``:
        its reading and the level the next frame is planned from; None if it is to be measured at rest instead."""
        h = self.host
        camera = _Stamped(h.camera, self._stamp, h.clock)
        settings = dataclasses.replace(h.capture, exposures_s=(exposure,))
        shot: ImageShot | None = None
        if h.capture.image is None:
            reading = h._read(level, settings, cast(Camera, camera))
        else:  # image mode: the window of the tiles at the point, a tile wider where the frame's pose differs
            pose = aligned_pose(h.geometry, point.joints, h.alignment)
            shot = plan_shot(cast(Camera, camera), settings, h.geometry, pose, margin_px=h.capture.image.tile_px)
            if shot is None:
                return None
            with whole_frames(h.camera):
                reading = h._read(level, shot.capture, shot.camera)
        before, end, frame, after = camera.light[-1]
        if shot is None and self._clipped(reading):
            h._event("scan_clipped", f"point {point.index}: a scan frame clipped; measured at rest instead")
            return None
        t0 = end - frame.exposure_s
        mid = interpolate(before, after, 0.5 * (t0 + end))
        joints = Joints.from_dict({**{k: float(v) for k, v in point.joints.as_dict().items()}, **mid})
        # The travel during the exposure: variance (speed x exposure)^2 / 12. From the device's speed: two
        # read-backs a short frame apart often read the same encoder count.
        travel = {**mid, velocity[0]: mid[velocity[0]] + velocity[1] * frame.exposure_s}
        d = aligned_forward(h.geometry, joints, h.alignment)
        offset = h.now() - h.clock.now()
        record = {**h.point_head(point, pos, d, joints), **h._reading_fields(reading), "image": None,
                  **h._times(t0 + offset, end + offset)}  # fmt: skip
        plan_next = reading.level
        if shot is None:  # the blur is the pose's: _uncertainty reads the travel
            record.update({**h._uncertainty(joints, travel, d), **h._distance(joints)})
        else:  # the blur is each tile's, along its own directions; the pose's own errors as at a stop
            shot, plan_next = self._tiles(shot, joints, travel, reading, point)
            record.update({**h._uncertainty(joints, mid, d), **h._distance(joints), **shot.record(reading)})
        h.store.append({**record, "scan": {"before": [before.t_s, before.joints], "after": [after.t_s, after.joints],
                                           "exposure_start_s": t0, "exposure_end_s": end,
                                           "speed_deg_s": abs(velocity[1])}})  # fmt: skip
        return reading, plan_next

    def _clipped(self, reading: Reading) -> bool:
        """Whether a point-mode frame clipped in its ROI."""
        flags = reading.hdr.flags
        if self.host.capture.roi is not None:
            x0, y0, x1, y1 = self.host.capture.roi
            flags = flags[y0:y1, x0:x1]
        return bool(np.any(flags & HdrFlag.SATURATED))

    def _tiles(self, shot: ImageShot, joints: Joints, travel: Mapping[str, float], reading: Reading,
               point: PlannedPoint) -> tuple[ImageShot, Level]:  # fmt: skip
        """The frame's tiles seen from mid-exposure with the blur in their covariances, and the next plan's level."""
        h = self.host
        image = h.capture.image
        assert image is not None
        shot = shot.seen_from(h.geometry, aligned_pose(h.geometry, joints, h.alignment))
        blur = travel_variance_deg2(joints.as_dict(), travel)
        shot = dataclasses.replace(shot, tiles=with_spread(
            shot.tiles, *motion_covariance(h.geometry, joints, h.alignment, image, shot.tiles, blur)))
        clipped = [b for b in shot.frame_boxes() if np.any(reading.hdr.flags[b[1]:b[3], b[0]:b[2]] & HdrFlag.SATURATED)]
        if clipped:  # as at a stop: a tile clipped in every frame (here, its one) is a lower bound
            h._event("scan_clipped_tiles", f"point {point.index}: {len(clipped)} of {shot.tiles.count} tiles of a "
                     "scan frame clipped: kept as lower bounds; the next frame is planned shorter", tiles=len(clipped))
        return shot, shot.brightest_level(reading)
