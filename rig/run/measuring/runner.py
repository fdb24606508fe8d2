"""The runner: measure every planned point, journal it before the next move, and always leave the rig safe.

For each point: one synchronous move of all axes, a poll until in position (tolerance, timeout; never a
fixed sleep), the joint angles read back and turned into the directions actually measured, a reading
(``rig.run.measuring.measure``), and a journal record (fsynced) before the next move. Reference readings are taken
before the first point, every ``reference.every`` points and after the last, with a drift check. Points
already in the journal are skipped, so the same call resumes a killed run.

Time: every record carries the rig clock (``rig_time_s``), the run time (``run_time_s``, continuous across
resumes: see ``Runner._continue_time``), the run time at the middle of its reading (``reading_time_s``, the
drift correction's time base in ``rig.run.tables.samples``) and UTC (``utc``, ISO 8601).

Faults: a move that times out is re-issued once; a capture that fails is retried once; anything else
from the link (a servo fault, a dead bus) or a second failure stops the run. Ctrl-C stops it too. In every
case the axes are stopped and the link shut down by the torque policy (``torque_off`` or ``hold``), the
journal keeps everything measured, and the run's status says why it stopped.

Progress: the merge is loaded as a step before the first point (its compiled passes, for images larger than
an ROI crop, at the first such merge, after a notice where they compile), and the bar's ETA
(``rig.run.measuring.progress``) leaves the first point's one-time costs out. The file stays whole past 400
lines: the loop, its fault handling and its records are one sequence; what stands alone (camera deadlines,
motion guard, gear play and its approach, progress, warm-up) lives beside it.
"""

from __future__ import annotations

import dataclasses
import datetime
import gc
import math
import sys
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from tqdm import tqdm

from acquisition.frame import Camera
from acquisition.roi import channel_list
from model.errors import EXIT_INTERRUPTED, CameraFault, GonioError, HardwareFault
from rig.instrument.alignment import Alignment, aligned_forward, aligned_pose, light_distance_m
from rig.instrument.axis import Axis
from rig.instrument.calibration_file import GeometryCalibration
from rig.instrument.clock import Clock
from rig.instrument.direction_uncertainty import direction_covariances, travel_variance_deg2
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Joints
from rig.instrument.kinematics_types import Directions
from rig.instrument.links.base import HomingLink, LinkError, MotionLink, MoveTimeout
from rig.run.backends.bounded_camera import BoundedCamera
from rig.run.backends.reference import ReferenceTarget
from rig.run.measuring.backlash import SIDES, Backlash
from rig.run.measuring.exposure_ahead import ExposureAhead, target_of
from rig.run.measuring.image_capture import TILE_KEYS, plan_shot, whole_frames
from rig.run.measuring.measure import CaptureSettings, Level, Reading, take_reading
from rig.run.measuring.motion_guard import MotionGuard, UnsafeMove
from rig.run.measuring.progress import Eta, format_eta
from rig.run.measuring.scan import Scanner
from rig.run.measuring.warm_up import COMPILING, notify_before_compiling, warm_up
from rig.run.planning.plan import Plan, PlannedPoint
from rig.run.storage.journal import check_records
from rig.run.storage.store import JOURNAL, RunStore
from rig.run.tables.parquet import write_beside
from rig.run.tables.samples import build_rows

TorquePolicy = Literal["torque_off", "hold"]


class RunStopped(GonioError, RuntimeError):
    """The run stopped early; the journal holds every point measured. ``cause`` says why, ``exit_code`` whose it is."""

    def __init__(self, message: str, cause: Literal["interrupted", "hardware", "camera"]) -> None:
        super().__init__(message)
        self.cause = cause
        self.exit_code = {"interrupted": EXIT_INTERRUPTED, "hardware": HardwareFault.exit_code,
                          "camera": CameraFault.exit_code}[cause]  # fmt: skip


class DriftWarning(UserWarning):
    """The reference reading changed by more than its noise allows between two reference captures."""


@dataclass(frozen=True)
class ReferenceSettings:
    """The reference target: albedo (one or per channel), its error, where and how often it is read."""

    albedo: float | tuple[float, ...]
    albedo_std_error: float
    theta_i_deg: float
    theta_o_deg: float
    joints: Joints
    every: int = 50
    drift_sigma: float = 4.0
    #: SNR goal of reference readings (None: the points'). Every point between two references shares
    #: their error, so a higher goal pays for itself after a few points.
    target_snr: float | None = None


@dataclass(frozen=True)
class RunOptions:
    """Motion timeouts and settling (s), torque policy on stop, images kept, progress bar shown."""

    move_timeout_s: float = 60.0
    settle_s: float = 0.0
    on_stop: TorquePolicy = "torque_off"
    save_images: bool = False
    include_cosine: bool = False
    progress: bool = True
    #: Wall seconds a camera call may take beyond twice its exposure before it is a camera fault.
    capture_timeout_s: float = 60.0
    #: Anti-backlash approach (deg of joint): overshoot every pose by this much and come back from one side.
    backlash_approach_deg: float = 0.0


@dataclass(frozen=True)
class RunSummary:
    """What a run did: points measured now and before, references, warnings, and the table's path."""

    measured: int
    already: int
    references: int
    drift_warnings: int
    table: str
    #: Rig time this call spent, by the instruments' clock (s): simulated time on the simulated rig.
    rig_time_s: float = 0.0


#: A reading's per-channel numbers as a list (np.atleast_1d(a).tolist(), without numpy's call for an array).
_as_list = channel_list


def _f(x: float) -> float:
    """``x`` rounded to 9 decimals as ``np.round`` does it (times 1e9, to the nearest even, over 1e9), -0.0 as 0.0.

    In Python floats: numpy's per-call cost, twelve times a point, for one float. The same bits (rig/run tests
    compare).
    """
    y = float(x) * 1e9
    if not math.isfinite(y):  # round() has no integer for it; numpy's answer is inf or nan
        return float(np.round(float(x), 9)) + 0.0
    return float(round(y)) / 1e9 + 0.0


class Runner:
    """Runs one plan into one run store with one link and one camera; see the module docstring."""

    def __init__(
        self,
        plan: Plan,
        store: RunStore,
        link: MotionLink,
        camera: Camera,
        clock: Clock,
        geometry: RigGeometry,
        capture: CaptureSettings,
        *,
        reference: ReferenceSettings | None = None,
        target: ReferenceTarget | None = None,
        options: RunOptions | None = None,
        calibration: GeometryCalibration | None = None,
        axes: Sequence[Axis] = (),
        wall_clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if reference is not None and target is None:
            raise ValueError("a reference schedule needs a ReferenceTarget to put the tile in view")
        self.options = options or RunOptions()
        if not isinstance(camera, BoundedCamera):  # every wait on the camera is bounded
            camera = BoundedCamera(camera, slack_s=self.options.capture_timeout_s)
        self.plan, self.store, self.link, self.camera, self.clock = plan, store, link, camera, clock
        self.geometry, self.capture, self.reference, self.target = geometry, capture, reference, target
        self._measured = self._references = self._drift = 0
        self._offset = 0.0  # run time = clock time + offset (see _continue_time)
        #: The rig's geometry calibration: read-backs become the true directions, its covariance their error.
        self.calibration = calibration
        self.alignment = calibration.alignment if calibration is not None else Alignment()
        #: Encoder resolution per joint (deg): a count's uniform error, variance count^2 / 12.
        self._resolution = {a.name: 1.0 / a.units_per_joint_degree for a in axes}
        #: The axes by joint: a scan's chosen speed stays within their top speed, its last frame ends before they slow.
        self.axes_by_name = {a.name: a for a in axes}
        allowed = [p.joints for p in plan.points] + [v for p in plan.points for v in p.via]
        if reference is not None:
            allowed.append(reference.joints)
        #: The joints' gear play and the one-sided approach that takes it up (``rig.run.measuring.backlash``).
        self.backlash = Backlash(axes, self.options.backlash_approach_deg)
        if self.backlash.active:  # the guard checks the overshoot legs like any other move
            allowed += self.backlash.pre_poses(allowed)
        self._sides: dict[str, int] = {}  # per joint, the flank its load rests on after the last move
        self.guard = MotionGuard(plan.paths, allowed)
        #: Time to go, in wall seconds (the progress bar's), without the first point's one-time costs.
        self.eta = Eta(wall_clock)
        self._guard_names: frozenset[str] | None = None
        #: Wall seconds the kernel warm-up took before the first point (0 if nothing was left to measure).
        self.warm_up_s = 0.0
        self._wall = wall_clock
        #: Levels predicted ahead (``[capture] exposure_model`` / ``exposure_from``); None: the previous level plans.
        self.ahead = ExposureAhead(capture.exposure_sources) if capture.exposure_sources else None
        self._planned_from: dict[int, str] = {}  # per point index, what planned its exposure (for its record)

    # -- run time -------------------------------------------------------------------------------------
    def now(self) -> float:
        """Run time in seconds: continuous across resumes, the time base of the drift correction."""
        return self.clock.now() + self._offset

    def _continue_time(self, records: list[dict[str, Any]]) -> None:
        """Set run time so it continues where the journal stopped.

        A simulated clock (one that can be advanced) is simply moved on to the last record's time: the
        simulation did not age while the process was dead, so a resumed run sees the lamp, the noise and
        the time stamps an uninterrupted run saw. A real clock cannot be moved: run time continues from the
        last record plus the real time (UTC) that passed since, since a lamp drifts while nobody watches.
        """
        last = next((r for r in reversed(records) if r.get("kind") in ("point", "reference")), None)
        now = self.clock.now()
        if last is None:
            self._offset = 0.0 if hasattr(self.clock, "advance") else -now
            return
        base = float(last.get("run_time_s", last.get("rig_time_s", 0.0)))
        if hasattr(self.clock, "advance") and now <= base:
            self.clock.advance(base - now)
            self._offset = 0.0
            return
        gap = 0.0
        if not hasattr(self.clock, "advance") and "utc" in last:
            gap = max(0.0, time.time() - datetime.datetime.fromisoformat(last["utc"]).timestamp())
        self._offset = base + gap - now

    def _return_to_last_pose(self, records: list[dict[str, Any]]) -> None:
        """On resume, a link that homes (GRBL) first returns to the last record's pose, as if it never left."""
        if not isinstance(self.link, HomingLink):
            return  # servos stand where they stood: nothing to find
        last = next((r for r in reversed(records) if r.get("kind") in ("point", "reference")), None)
        if last is None:
            return
        if last["kind"] == "reference":
            if self.reference is None:
                return
            self._move(self.reference.joints)
            return
        planned = next((p for p in self.plan.points if p.index == last["index"]), None)
        if planned is not None:
            self._move(planned.joints)

    # -- the loop -------------------------------------------------------------------------------------
    def run(self) -> RunSummary:
        """Measure every point not yet in the journal, then write the table; stops safely on any fault."""
        started = self.clock.now()
        records = self.store.records()
        check_records(records, self.store.path / JOURNAL)
        done = {r["index"] for r in records if r["kind"] == "point"}
        ref_done = {r["slot"]: r for r in records if r["kind"] == "reference"}
        points = [r for r in records if r["kind"] == "point"]
        level = Level.from_dict(max(points, key=lambda r: r["position"])["level"]) if points else None
        if self.ahead is not None:  # what the sources learnt from the points measured so far
            self.ahead.replay(points)
        # The plan holds the reference schedule, so its time estimate and the run agree on it.
        slots = set(self.plan.reference_before) if self.reference else set()
        last_ref = max(ref_done.values(), key=lambda r: r["slot"]) if ref_done else None
        if len(done) < len(self.plan.points):
            self._warm_up()
        # tqdm's own rate would count the first point's one-time costs: the bar shows ours instead.
        bar = tqdm(total=len(self.plan.points), initial=len(done), unit="pt", disable=not self.options.progress,
                   file=sys.stderr, dynamic_ncols=True,
                   bar_format="{l_bar}{bar}| {n_fmt}/{total_fmt} [{elapsed}{postfix}]")  # fmt: skip
        # Objects alive now (the camera's renderer, compiled kernels, the plan) live as long as the run: a full
        # collection walking them costs the controller's thread and frees none of them. Frozen, collections walk
        # only what the run itself makes. Not if someone froze first.
        freeze = gc.get_freeze_count() == 0
        if freeze:
            gc.freeze()
        try:
            # Inside the try: a fault on the way back stops the run safely like any other.
            if len(done) < len(self.plan.points):
                self._return_to_last_pose(records)
            self._continue_time(records)
            self.eta.start(len(self.plan.points) - len(done))
            scan = Scanner(self, self.capture.scan_speed_deg_s) if self.capture.motion == "continuous" else None
            swept: set[int] = set()  # indices a scan measured in this call
            for pos, point in enumerate(self.plan.points):
                if pos in slots and pos not in ref_done and point.index not in done:
                    last_ref = self._reference(pos, last_ref)
                if point.index in done or point.index in swept:
                    continue
                reading, plan_level = self._point(pos, point, self.planned_level(point, level))
                self.observed(point, reading)
                level, scanned = reading.level, [pos]
                if scan is not None:  # continuous motion: the points a scan from here reaches, measured moving
                    level, more = scan.follow(pos, level, done, slots, plan_level)
                    swept.update(self.plan.points[p].index for p in more)
                    self._measured += len(more)  # each a point record, as a stop's is
                    scanned += more
                for _ in scanned:
                    self.eta.point_done()
                if self.options.progress:  # the bar's text, only where there is a bar to show it
                    bar.set_postfix_str(f"{format_eta(self.eta.remaining_s())}, {self._postfix(point, reading)}",
                                        refresh=False)  # fmt: skip
                bar.update(len(scanned))
            end = len(self.plan.points)
            if end in slots and end not in ref_done:
                self._reference(end, last_ref)
            table = self._finish()
        except KeyboardInterrupt:
            self._stop("interrupted by the operator (Ctrl-C or SIGTERM)")
            raise RunStopped(
                f"{self.store.path}: interrupted; `gonio resume {self.store.path}` continues", "interrupted"
            ) from None
        except LinkError as exc:
            self._stop(f"link fault: {exc}")
            raise RunStopped(f"{self.store.path}: stopped on a link fault: {exc}", "hardware") from exc
        except _CameraFailed as exc:
            self._stop(f"camera fault: {exc}")
            raise RunStopped(f"{self.store.path}: stopped on a camera fault: {exc}", "camera") from exc
        except BaseException as exc:
            self._stop(f"error: {type(exc).__name__}: {exc}")
            raise
        finally:
            if freeze:
                gc.unfreeze()
            bar.close()
            self._shutdown()
        return RunSummary(self._measured, len(done), self._references, self._drift, str(table),
                          self.clock.now() - started)  # fmt: skip

    def _warm_up(self) -> None:
        """Load the merge as a step of its own, before the first point (its compiled passes: where needed)."""
        if self.options.progress:  # shown when a large image first needs the compiled passes, if uncached
            notify_before_compiling(lambda: tqdm.write(COMPILING, file=sys.stderr))
        t0 = self._wall()
        warm_up(self.capture.noise)
        self.warm_up_s = self._wall() - t0

    def _postfix(self, point: PlannedPoint, reading: Reading) -> str:
        ti, _, to, _ = point.directions_deg
        return f"θi {ti:.0f}° θo {to:.0f}° reading {float(np.mean(reading.roi.mean)):.4g} DN/s"

    # -- motion ---------------------------------------------------------------------------------------
    def _move(self, joints: Joints, via: tuple[Joints, ...] = ()) -> Joints:
        """Move through ``via`` to ``joints``; the joints the loads hold (deg), gear play taken out where known."""
        driven = self.guard_names
        for stop in via:
            self._legs({k: float(v) for k, v in stop.as_dict().items() if k in driven})
        target = {k: float(v) for k, v in joints.as_dict().items() if k in driven}
        if self.backlash.active:
            held = self._approach(target)
        else:
            held, self._sides = self._legs(target), {}
        if self.options.settle_s > 0:
            self.clock.sleep(self.options.settle_s)
        held = self.backlash.load_angles(held, self._sides)
        names = Joints.__dataclass_fields__
        return Joints.from_dict({**{k: float(v) for k, v in joints.as_dict().items()},
                                 **{k: v for k, v in held.items() if k in names}})  # fmt: skip

    def _legs(self, target: dict[str, float]) -> dict[str, float]:
        """Move to ``target`` (deg) in the legs the guard makes safe; the joints read back after the last."""
        held: dict[str, float] = {}
        # Every leg is checked from where the arms are now (the guard), never assumed from the plan.
        for leg in self.guard.legs(self.link, target):
            held = self._leg(leg)
        return held

    def _approach(self, target: dict[str, float]) -> dict[str, float]:
        """Reach ``target`` from one side through its overshoot pose (from below, else above); joints read back."""
        for side in SIDES:
            pre = self.backlash.pre_pose(target, side)
            try:
                self._legs(pre)
            except UnsafeMove:
                continue  # the arms would come too close on this side: try the other
            held = self._legs(target)
            self._sides = self.backlash.sides(pre, target)
            return held
        self._event("approach_skipped", f"no overshoot pose of {target} keeps the arms apart: moved straight "
                    "there; its joints' play stays in their uncertainty")  # fmt: skip
        self._sides = {}
        return self._legs(target)

    @property
    def guard_names(self) -> frozenset[str]:
        """Joints the link drives (the others have no axis and stay where the plan holds them)."""
        if self._guard_names is None:  # the plan does not change: worked out once, not for every joint of a move
            paths = self.plan.paths
            self._guard_names = frozenset(paths.names if paths is not None else Joints.__dataclass_fields__)
        return self._guard_names

    def _leg(self, target: dict[str, float]) -> dict[str, float]:
        """One move to ``target`` (deg), re-issued once after a timeout; the joints read back."""
        for attempt in (1, 2):
            self.link.move_to(target)
            try:
                return self.link.wait_in_position(timeout_s=self.options.move_timeout_s)
            except MoveTimeout as exc:
                self._event("move_timeout", str(exc), attempt=attempt)
                if attempt == 2:
                    raise
        raise AssertionError("unreachable")

    def _read(self, previous: Level | None, capture: CaptureSettings | None = None,
              camera: Camera | None = None) -> Reading:  # fmt: skip
        for attempt in (1, 2):
            try:
                return take_reading(camera or self.camera, capture or self.capture, previous)
            except (OSError, RuntimeError, ValueError) as exc:
                self._event("camera_error", f"{type(exc).__name__}: {exc}", attempt=attempt)
                if attempt == 2:
                    raise _CameraFailed(f"{type(exc).__name__}: {exc}") from exc
        raise AssertionError("unreachable")

    # -- one point, one reference ---------------------------------------------------------------------
    def _point(self, pos: int, point: PlannedPoint, level: Level | None) -> tuple[Reading, Level]:
        """Measure ``point`` at rest: its reading, and the level a scan from it plans its first frame from."""
        actual = self._move(point.joints, point.via)
        d = aligned_forward(self.geometry, actual, self.alignment)
        t0 = self.now()
        if self.capture.image:
            reading, tiles, plan_level = self._read_image(actual, level)
        else:
            reading = self._read(level)
            tiles, plan_level = {}, reading.level
        t1 = self.now()
        fault: LinkError | None = None
        try:  # where the axes stood at the end: how far they moved during the frames
            after: Mapping[str, float] = self.backlash.load_angles(self.link.read_positions(), self._sides)
        except LinkError as exc:  # the reading is taken: keep it, then stop on the fault
            after, fault = {k: float(v) for k, v in actual.as_dict().items()}, exc
        image = None
        if self.options.save_images:
            image = str(self.store.save_image(f"point_{point.index:05d}", reading.hdr.radiance,
                                              variance=reading.hdr.variance).name)  # fmt: skip
        self.store.append({
            **self.point_head(point, pos, d, actual), **self._reading_fields(reading), "image": image,
            **self._times(t0, t1),
            **self._uncertainty(actual, after, d), **self._distance(actual), **tiles,
        })  # fmt: skip
        self._measured += 1
        if fault is not None:
            raise fault
        return reading, plan_level

    def _read_image(self, actual: Joints, level: Level | None) -> tuple[Reading, dict[str, Any], Level]:
        """Image mode's reading of the whole footprint, its tiles' journal table (``image_capture``), and the
        level of its brightest tile (a scan's first frame is planned from it)."""
        image = self.capture.image
        assert image is not None
        shot = plan_shot(self.camera, self.capture, self.geometry, aligned_pose(self.geometry, actual, self.alignment))
        if shot is None:  # no whole tile on the sample (a grazing view): the point's ROI, and no samples
            reading = self._read(level, dataclasses.replace(self.capture, image=None))
            empty = {"tiles": {k: [] for k in TILE_KEYS}, "tile_px": image.tile_px, "tiles_grazing": 0}
            return reading, empty, reading.level
        with whole_frames(self.camera):
            reading = self._read(level, shot.capture, shot.camera)
        scanning = self.capture.motion == "continuous"  # only a scan plans from it
        return reading, shot.record(reading), shot.brightest_level(reading) if scanning else reading.level

    def point_head(self, point: PlannedPoint, pos: int, d: Directions, joints: Joints) -> dict[str, Any]:
        """A point record's first fields: its index, target and measured directions (deg), joints (deg), and what
        planned its exposure where the run predicts levels ahead."""
        head = {
            "kind": "point", "index": point.index, "position": pos,
            "target_deg": [_f(v) for v in point.directions_deg],
            "theta_i_deg": _f(float(d.theta_i)), "phi_i_deg": _f(float(d.phi_i)),
            "theta_o_deg": _f(float(d.theta_o)), "phi_o_deg": _f(float(d.phi_o)),
            "joints_deg": {k: _f(float(v)) for k, v in joints.as_dict().items()},
        }  # fmt: skip
        if point.index in self._planned_from:
            head["exposure_planned_from"] = self._planned_from.pop(point.index)
        return head

    # -- exposure planned ahead (rig.run.measuring.exposure_ahead) -------------------------------------
    def planned_level(self, point: PlannedPoint, previous: Level | None) -> Level | None:
        """The level (counts/s) to plan ``point``'s exposure from: predicted ahead where a source can, else
        ``previous``; what gave it goes into the point's record."""
        if self.ahead is None:
            return previous
        level, source = self.ahead.plan(_target(point), previous)
        self._planned_from[point.index] = source
        return level

    def observed(self, point: PlannedPoint, reading: Reading) -> None:
        """Teach the sources ``point``'s measured level; a prediction off by more than OFF_FACTOR is an event."""
        if self.ahead is None:
            return
        usable = not reading.roi.lower_bound and not reading.roi.dark
        for miss in self.ahead.observe(_target(point), reading.level, usable):
            self._event("exposure_prediction_off", f"point {point.index}: the {miss.source}'s level was off by "
                        f"x{miss.factor:.3g} (predicted {_rounded(miss.predicted)}, measured {_rounded(miss.measured)} "
                        f"counts/s); the next point falls back", index=point.index, source=miss.source,
                        factor=miss.factor)  # fmt: skip

    def _uncertainty(self, before: Joints, after: Mapping[str, float], measured: Directions) -> dict[str, Any]:
        """The directions' covariances (rig.instrument.direction_uncertainty) for the journal."""
        travel = travel_variance_deg2(before.as_dict(), after)
        variance = {name: (self._resolution.get(name, 0.0) ** 2 / 12.0 + moved
                           + self.backlash.variance_deg2(name, self._sides))
                    for name, moved in travel.items()}  # fmt: skip
        cal = self.calibration
        angles, tangent = direction_covariances(
            self.geometry, before, self.alignment, variance, cal.names if cal else (),
            cal.covariance if cal is not None and cal.covariance.size else None, measured=measured,
        )  # fmt: skip
        return {"angle_cov_deg2": np.round(angles, 15).tolist(), "direction_cov": np.round(tangent, 18).tolist()}

    def _times(self, start: float, end: float) -> dict[str, Any]:
        """Time stamps of a record: rig clock, run time (s) at the record and at the reading's middle, UTC."""
        utc = datetime.datetime.now(datetime.UTC).isoformat(timespec="microseconds")
        return {"rig_time_s": self.clock.now(), "run_time_s": self.now(), "reading_time_s": 0.5 * (start + end),
                "utc": utc}  # fmt: skip

    def _distance(self, joints: Joints) -> dict[str, Any]:
        """The light's distance (m) to the viewed point, where a calibrated sample offset moves it off the axis.

        Irradiance falls as its inverse square, so the table scales each reading by (d / d_ref)^2; a rig
        without a calibration journals none, and its table stays as it was.
        """
        if self.alignment.is_zero and self.capture.image is None:  # image mode: every tile has its own distance
            return {}
        return {"light_distance_m": _f(light_distance_m(self.geometry, joints, self.alignment))}

    def _reading_fields(self, reading: Reading) -> dict[str, Any]:
        r = reading.roi
        return {
            "reading": _as_list(r.mean), "reading_std_error": _as_list(r.std_error),
            "n_pixels": r.n_pixels, "n_flagged": _as_list(r.n_flagged), "lower_bound": r.lower_bound,
            "dark": r.dark, "n_dark": _as_list(r.n_dark),
            "exposures_s": list(reading.exposures_s), "dark_exposures_s": list(reading.dark_exposures_s),
            "test_exposures_s": list(reading.test_exposures_s), "level": reading.level.as_dict(),
            "notes": list(reading.notes),
        }  # fmt: skip

    def _reference(self, slot: int, last: Mapping[str, Any] | None) -> dict[str, Any]:
        assert self.reference is not None and self.target is not None
        ref = self.reference
        held = self._move(ref.joints)
        self.target.present(slot)
        try:
            previous = Level.from_dict(last["level"]) if last is not None else None
            snr = ref.target_snr or self.capture.target_snr
            t0 = self.now()
            reading = self._read(previous, dataclasses.replace(self.capture, target_snr=snr))
            t1 = self.now()
        finally:
            self.target.withdraw()
        record: dict[str, Any] = {
            "kind": "reference", "slot": slot, "theta_i_deg": ref.theta_i_deg, "theta_o_deg": ref.theta_o_deg,
            "joints_deg": {k: _f(float(v)) for k, v in held.as_dict().items()},
            "target": self.target.description, **self._reading_fields(reading), **self._times(t0, t1),
            **self._distance(held),
        }  # fmt: skip
        if reading.roi.lower_bound:
            raise _CameraFailed("the reference reading saturated in every frame; lower the light or the exposure")
        if reading.roi.dark:
            raise _CameraFailed("the reference reading is dark even after metering: is the lamp on, the lens cap off?")
        if last is not None:
            a, b = np.asarray(last["reading"]), np.asarray(record["reading"])
            se = np.hypot(np.asarray(last["reading_std_error"]), np.asarray(record["reading_std_error"]))
            z = float(np.max(np.abs(b - a) / np.where(se > 0, se, math.inf)))
            record["drift_z"] = z
            if z > ref.drift_sigma:
                self._drift += 1
                message = (f"reference drifted by {float(np.max(np.abs(b / a - 1))):.2%} ({z:.1f} sigma > "
                           f"{ref.drift_sigma:g}) between positions {last['slot']} and {slot}: the lamp or the "
                           "camera is not stable; the table interpolates between references")  # fmt: skip
                warnings.warn(message, DriftWarning, stacklevel=2)
                self._event("drift", message, z=z)
        self.store.append(record)
        self._references += 1
        return record

    # -- endings --------------------------------------------------------------------------------------
    def _event(self, what: str, message: str, **extra: Any) -> None:
        self.store.append({"kind": "event", "event": what, "message": message, **extra})

    def _finish(self) -> str:
        ref = self.reference
        records = self.store.records_to_read()  # check_records and build_rows only read them
        check_records(records, self.store.path / JOURNAL)
        rows = build_rows(records, self.geometry.joint_names,
                          albedo=ref.albedo if ref else None, albedo_std_error=ref.albedo_std_error if ref else 0.0,
                          include_cosine=self.options.include_cosine)  # fmt: skip
        path = self.store.write_table(rows)
        # samples.schema.json and samples.parquet, with the run's [metadata]
        write_beside(path, rows, self.store.manifest.get("metadata"))
        self.store.mark_finished({"points": len(rows), "skipped": len(self.plan.skipped)})
        return str(path)

    def _stop(self, reason: str) -> None:
        """Halt motion first (the part that keeps the rig safe), then write down why."""
        try:
            self.link.stop()
        except Exception as exc:  # a dead bus must not keep the rest of the shutdown from running
            reason += f"; stopping the axes failed: {exc}"
        try:
            self.store.mark_stopped(reason)
        except Exception as exc:
            print(f"gonio: could not record the stop in {self.store.path}: {exc}", file=sys.stderr)

    def _shutdown(self) -> None:
        try:
            self.link.shutdown(keep_torque=self.options.on_stop == "hold")
        except LinkError as exc:
            print(f"gonio: warning: {exc}", file=sys.stderr)


def _target(point: PlannedPoint) -> tuple[float, float, float, float]:
    """The point's target directions (deg) as its record holds them: a resume replays the journal's
    (ExposureAhead.replay), and must see the very numbers the run planned with."""
    return target_of({"target_deg": [_f(v) for v in point.directions_deg]})


def _rounded(values: Sequence[float]) -> str:
    return "[" + ", ".join(f"{v:.4g}" for v in values) + "]"


class _CameraFailed(CameraFault, RuntimeError):
    """A capture failed twice at one point (or the reference cannot be read)."""
