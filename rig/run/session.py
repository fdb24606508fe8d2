"""From a rig file and a sweep file to a finished run: the plan, the instruments, the store, the runner.

``make_plan`` is what ``gonio plan`` prints. ``start_run`` creates a run directory (manifest with both files'
validated tables) and runs it; ``resume_run`` reopens one, rebuilds the same plan from its manifest and
runs the points its journal lacks. Instruments come from the backend the rig file's ``[link] kind`` names,
found by registration (:mod:`rig.run.backends.base`): gonio's Dynamixel and GRBL links with a real camera
(:mod:`rig.run.backends.hardware`), the simulated rig (registered by the simulator, which nothing in rig imports),
or a lab's own.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rig.instrument.alignment import aligned_inverse
from rig.instrument.axis import AxisLimitError
from rig.instrument.calibration_file import GeometryCalibration
from rig.instrument.kinematics import forward, inverse, require
from rig.instrument.kinematics_types import UnreachableError
from rig.run.config.files import (
    ConfigError,
    RigConfig,
    SweepConfig,
    as_table,
    parse,
    rig_config,
    saved_rig,
    sweep_config,
)
from rig.run.config.schema import SweepFile, run_metadata
from rig.run.storage.journal import check_records
from rig.run.storage.store import JOURNAL, RunStore, RunStoreError

# What only measuring needs (the runner, the HDR merge and numba behind it, the planner, the backends) is
# imported inside the functions that measure: gonio analyze rebuilds a run's configuration through configs_of
# and should not pay seconds of imports for a run it only reads.
if TYPE_CHECKING:
    from rig.run.backends.base import Instruments, StartPose
    from rig.run.measuring.measure import CaptureSettings
    from rig.run.measuring.mode_choice import ModeChoice
    from rig.run.measuring.runner import ReferenceSettings, RunOptions, RunSummary
    from rig.run.measuring.tiles import ImageSettings
    from rig.run.planning.plan import Plan
    from rig.run.planning.scans import ScanTiming


class RunFinished(RunStoreError):
    """``resume_run`` on a run that finished: there is nothing to measure (the command line says so and exits 0)."""


def capture_settings(rig: RigConfig, sweep: SweepConfig) -> CaptureSettings:
    """The capture settings of a run from the rig's camera and the sweep's [capture] table."""
    from acquisition.exposure.spec import CameraTiming
    from rig.run.calibrate import camera_flat_field, camera_noise
    from rig.run.measuring.exposure_sources import load_sources
    from rig.run.measuring.measure import CaptureSettings

    cam, cap = rig.file.camera, sweep.file.capture
    return CaptureSettings(
        noise=camera_noise(rig),
        timing=CameraTiming(cam.min_exposure_s, cam.max_exposure_s, overhead_s=cam.overhead_s),
        target_snr=cap.target_snr,
        exposures_s=tuple(cap.exposures_s) if cap.exposures_s else None,
        max_frames=cap.max_frames,
        dark_frames=cap.dark_frames,
        first_exposure_s=cap.first_exposure_s,
        # The simulated camera renders only the ROI, so what it delivers is the ROI already.
        roi=cam.roi if cam.backend != "simulated" else None,
        flat_field=camera_flat_field(rig),
        image=_image_settings(rig, sweep),
        motion=cap.motion,
        scan_speed_deg_s=cap.scan_speed_deg_s,  # None in continuous motion: chosen per scan run
        exposure_sources=load_sources(sweep.path, cap.exposure_from, cap.exposure_model),
    )


def _image_settings(rig: RigConfig, sweep: SweepConfig) -> ImageSettings | None:
    """Image mode's tiles (``[capture] mode = "image"``) on the rig's sensor, None in point mode."""
    from rig.run.measuring.tiles import DEFAULT_TILE_PX, ImageSettings

    cap = sweep.file.capture
    if cap.mode != "image":
        return None
    return ImageSettings(
        tile_px=cap.tile_px or DEFAULT_TILE_PX, resolution=rig.file.camera.resolution, shape=rig.sample_shape
    )


def reference_settings(rig: RigConfig) -> ReferenceSettings | None:
    """The reference schedule from the rig's [reference] table, None for kind 'none'."""
    from rig.run.measuring.runner import ReferenceSettings

    ref = rig.file.reference
    if ref.kind == "none":
        return None
    try:
        joints = require(inverse(rig.geometry, ref.theta_i_deg, 0.0, ref.theta_o_deg, 180.0))
        if not rig.alignment.is_zero:
            d = forward(rig.geometry, joints)
            joints, _ = aligned_inverse(rig.geometry, d.wi, d.wo, rig.alignment)
        for axis in rig.axes:  # the pose may be reachable by the geometry but outside an axis's limits
            axis.check(float(joints.as_dict()[axis.name]))
    except (UnreachableError, AxisLimitError) as exc:
        raise ConfigError(
            f"{rig.path}: [reference] theta_i_deg = {ref.theta_i_deg!r}, theta_o_deg = {ref.theta_o_deg!r}: "
            f"the reference pose is unreachable on this rig ({exc}); expected a pose the rig reaches"
        ) from None
    return ReferenceSettings(ref.albedo, ref.albedo_std_error, ref.theta_i_deg, ref.theta_o_deg, joints,
                             every=ref.every, drift_sigma=ref.drift_sigma, target_snr=ref.target_snr)  # fmt: skip


def _per_point_exposure_s(rig: RigConfig, sweep: SweepConfig) -> float:
    cap = sweep.file.capture
    frames = tuple(cap.exposures_s) if cap.exposures_s else (cap.first_exposure_s,) * min(3, cap.max_frames)
    darks = len(set(frames)) * cap.dark_frames * max(frames)
    overhead = (len(frames) + cap.dark_frames) * rig.file.camera.overhead_s
    return float(sum(frames) + darks + overhead)


#: A plan of more points than this shows its stages on a progress bar (ordering 10^4 points is slow enough to show).
PROGRESS_POINTS = 10_000


@contextlib.contextmanager
def _plan_bar(points: int, shown: bool) -> Iterator[Callable[[str], None] | None]:
    """A tqdm bar on stderr over the planner's stages, for a plan large enough to take a while."""
    if not shown or points <= PROGRESS_POINTS:
        yield None
        return
    import sys

    from tqdm.auto import tqdm

    from rig.run.planning.plan import PLAN_STAGES

    with tqdm(total=len(PLAN_STAGES), desc=f"planning {points} points", unit="stage", file=sys.stderr,
              dynamic_ncols=True) as bar:  # fmt: skip

        def stage(name: str) -> None:
            if bar.n or name != PLAN_STAGES[0]:
                bar.update(1)
            bar.set_postfix_str(name, refresh=True)

        yield stage
        bar.update(bar.total - bar.n)


def make_plan(rig: RigConfig, sweep: SweepConfig, *, progress: bool = False) -> Plan:
    """The ordered plan with unreachable points listed and a time estimate (nothing moves).

    ``progress``: a bar on stderr over the planner's stages when the sweep has more than PROGRESS_POINTS points.
    """
    from rig.run.backends.base import backend
    from rig.run.planning.plan import plan_sweep

    ref = reference_settings(rig)
    per_point = _per_point_exposure_s(rig, sweep)
    with _plan_bar(len(sweep.directions_deg), progress) as stage:
        return plan_sweep(
            sweep.directions_deg, rig.geometry, rig.axes, settle_s=rig.file.link.settle_s,
            exposure_s_per_point=per_point, overhead_s_per_point=_approach_s(rig),
            reference_every=ref.every if ref else 0, reference_s=per_point if ref else 0.0,
            reference_joints=ref.joints if ref else None, order=sweep.file.sweep.order,
            isotropic=sweep.file.sweep.isotropic,
            coordinated=backend(rig.file.link.kind).for_file(rig.file).coordinated, alignment=rig.alignment,
            on_stage=stage, scan=_scan_timing(rig, sweep),
        )  # fmt: skip


def _scan_timing(rig: RigConfig, sweep: SweepConfig) -> ScanTiming | None:
    """How the plan times continuous scans (None: stop and go): the given speed, else the runner's rule with a
    frame exposed as the estimate's stops are (a fixed exposure's longest, else first_exposure_s)."""
    from rig.run.planning.scans import ScanTiming

    cap = sweep.file.capture
    if cap.motion != "continuous":
        return None
    exposure = max(cap.exposures_s) if cap.exposures_s else cap.first_exposure_s
    return ScanTiming(cap.scan_speed_deg_s, exposure, cap.dark_frames, rig.file.camera.overhead_s)


def _approach_s(rig: RigConfig) -> float:
    """Time (s) a pose's anti-backlash approach adds: out past it and back, the slowest axis's two trapezoids."""
    from rig.run.planning.order import trapezoid_time_s

    a = rig.file.link.backlash_approach_deg
    if not a or not rig.axes:
        return 0.0
    return max(2.0 * float(trapezoid_time_s(a, ax.max_speed_deg_s, ax.max_accel_deg_s2)) for ax in rig.axes)


def instruments(rig: RigConfig, start: StartPose | None = None) -> contextlib.AbstractContextManager[Instruments]:
    """Open the rig's link, camera and reference for a run through its registered backend (see RigBackend)."""
    from rig.run.backends.base import backend

    return backend(rig.file.link.kind).open(rig, start=start)


def last_pose(store: RunStore) -> StartPose | None:
    """The joints (degrees) of the journal's last point or reference reading, where a resumed rig stands."""
    for record in reversed(store.records()):
        if record.get("kind") in ("point", "reference") and "joints_deg" in record:
            return {k: float(v) for k, v in record["joints_deg"].items()}
    return None


def manifest(rig: RigConfig, sweep: SweepConfig, plan: Plan, run_options: RunOptions) -> dict[str, Any]:
    """The run's manifest: both files' validated tables (so a resume needs neither file), plan and options."""
    return {
        "rig": as_table(rig.file), "rig_path": str(rig.path),
        "sweep": as_table(sweep.file), "sweep_path": str(sweep.path),
        "points": len(plan.points), "unreachable": [
            {"index": s.index, "directions_deg": list(s.directions_deg), "reason": s.reason, "detail": s.detail}
            for s in plan.skipped
        ],
        "estimate_s": plan.estimate.total_s if math.isfinite(plan.estimate.total_s) else None,
        "options": {"move_timeout_s": run_options.move_timeout_s, "on_stop": run_options.on_stop,
                    "save_images": run_options.save_images, "include_cosine": run_options.include_cosine},
        "geometry_calibration": rig.calibration.snapshot() if rig.calibration is not None else None,
        "metadata": run_metadata(rig.file, sweep.file),
    }  # fmt: skip


def options_for(rig: RigConfig, sweep: SweepConfig, progress: bool) -> RunOptions:
    """Run options from the rig's [link] and the sweep's [capture] tables."""
    from rig.run.measuring.runner import RunOptions

    link, cap = rig.file.link, sweep.file.capture
    return RunOptions(move_timeout_s=link.move_timeout_s, settle_s=link.settle_s, on_stop=link.on_stop,
                      save_images=cap.save_images, include_cosine=cap.include_cosine, progress=progress,
                      capture_timeout_s=rig.file.camera.capture_timeout_s,
                      backlash_approach_deg=link.backlash_approach_deg)  # fmt: skip


def check_rig(rig: RigConfig) -> None:
    """Read what a run reads from the rig file's other files and tables (camera calibration and flat field, the
    reference pose) once, so a mistake there is a ConfigError before any run directory exists."""
    from rig.run.calibrate import camera_flat_field, camera_noise

    camera_noise(rig)
    camera_flat_field(rig)
    reference_settings(rig)


def _run(
    store: RunStore, rig: RigConfig, sweep: SweepConfig, plan: Plan, progress: bool,
    capture: CaptureSettings | None = None,
) -> RunSummary:  # fmt: skip
    from rig.run.measuring.runner import Runner

    capture = capture or capture_settings(rig, sweep)
    with instruments(rig, start=last_pose(store)) as inst:
        runner = Runner(
            plan, store, inst.link, inst.camera, inst.clock, rig.geometry, capture,
            reference=reference_settings(rig) if inst.target is not None else None, target=inst.target,
            options=options_for(rig, sweep, progress), calibration=rig.calibration, axes=rig.axes,
        )  # fmt: skip
        return runner.run()


def resolve_mode(rig: RigConfig, sweep: SweepConfig, plan: Plan) -> tuple[SweepConfig, ModeChoice | None]:
    """The sweep with ``[capture] mode = "auto"`` decided (``rig.run.measuring.mode_choice``) and the choice;
    any other sweep unchanged, with None."""
    from rig.run.measuring.mode_choice import choose_image

    cap = sweep.file.capture
    if cap.mode != "auto":
        return sweep, None
    choice = choose_image(rig, plan, cap.tile_px, cap.motion)
    # The decided table is what the manifest keeps: a resume measures the same way without deciding again.
    keys = {"mode": choice.mode, "tile_px": cap.tile_px if choice.mode == "image" else None}
    decided = sweep.file.model_copy(update={"capture": cap.model_copy(update=keys)})
    return dataclasses.replace(sweep, file=decided), choice


def start_run(
    rig: RigConfig, sweep: SweepConfig, out: str | Path, *, progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> RunSummary:  # fmt: skip
    """Plan, create the run directory ``out`` and measure; raises RunStopped if it stops early.

    ``log`` receives what the run decided before it starts (``mode = "auto"``'s choice).
    """
    # Every input is read before the directory exists: a mistake found after would leave a run that is not
    # one, which a retry calls "already holds a run" and a resume fails on again.
    check_rig(rig)
    plan = make_plan(rig, sweep, progress=progress)
    if not plan.points:
        raise ConfigError(f"{sweep.path}: no reachable point on this rig ({len(plan.skipped)} unreachable)")
    sweep, choice = resolve_mode(rig, sweep, plan)
    capture = capture_settings(rig, sweep)
    doc = manifest(rig, sweep, plan, options_for(rig, sweep, progress))
    if choice is not None:
        doc["capture_mode"] = {"asked": "auto", **choice.as_dict()}
        if log is not None:
            log(choice.describe())
    with RunStore.create(out, doc) as store:
        return _run(store, rig, sweep, plan, progress, capture)


def configs_of(store: RunStore) -> tuple[RigConfig, SweepConfig]:
    """The rig and sweep a run was started with, rebuilt from its manifest."""
    m = store.manifest
    snap = m.get("geometry_calibration")
    cal = GeometryCalibration.from_snapshot(snap) if snap else None
    rig = rig_config(saved_rig(m["rig"], f"{store.path}/manifest.json rig"), m["rig_path"], calibration=cal)
    sweep = sweep_config(parse(m["sweep"], SweepFile, f"{store.path}/manifest.json sweep"), m["sweep_path"])
    return rig, sweep


def resume_run(path: str | Path, *, progress: bool = True) -> RunSummary:
    """Continue a stopped or killed run from its journal; ends with the table an uninterrupted run writes."""
    with RunStore.open(path) as store:
        previous = getattr(store, "previous_status", None) or store.status()
        if previous.get("state") == "finished":
            raise RunFinished(f"{path}: the run is finished ({store.path / 'samples.csv'}); nothing to resume")
        check_records(store.records(), store.path / JOURNAL)  # before anything is opened or moved
        rig, sweep = configs_of(store)
        plan = make_plan(rig, sweep, progress=progress)
        if len(plan.points) != store.manifest["points"]:
            raise RunStoreError(f"{path}: the plan rebuilt from the manifest has {len(plan.points)} points, "
                             f"the run had {store.manifest['points']}: was gonio upgraded in between?")  # fmt: skip
        return _run(store, rig, sweep, plan, progress)
