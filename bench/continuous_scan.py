"""Continuous scans against stop-and-go: samples per rig-hour, fitted-BRDF error at equal rig time, honest errors.

For the three materials of bench/sweep_tradeoff (rough gold, glossy plastic, matte; a flat 50 mm sample) the
simulated Dynamixel rig measures, end to end (servos on the pty, Mitsuba camera, HDR merge, references):

- stop-and-go, the anchor: bench/image_mode's anchor, sweep_tradeoff's regular grid of ``--points`` points at
  SNR 100, one 4 px ROI reading per point of a 512 px camera, in the planner's order;
- the *scan sweep* (``scan_design``): poses in runs along the camera joint (light arm, tilt and roll held, the
  camera stepping ``STEP_DEG`` across everything it reaches up to 70 deg), runs in serpentine order and kept in
  that order (``order = false``), so ``rig.run.measuring.scan.scan_run`` finds runs to scan. Measured at rest
  (``motion = "stop"``: what the sweep itself costs) and with ``[capture] motion = "continuous"`` at each
  ``scan_speed_deg_s`` of ``SPEEDS`` (the dial);
- the same on a denser scan sweep (``DENSE_STEP_DEG``: four times the points per run), at rest and at
  ``DENSE_SPEEDS``;
- a rig that settles (``[link] settle_s = SETTLE_S`` after every stop), the scan sweep at rest and scanned at
  ``SETTLE_SPEED``: what a real rig's settling adds to stop-and-go and a scan avoids;
- continuous + image mode (``mode = "image"``, ``IMAGE_TILE_PX`` px tiles on image_mode's camera) at
  ``IMAGE_SPEED``, if the capture table accepts the pair (else a printed note and no row);
- the scan sweep on the simulated GRBL rig, at rest and scanned at ``GRBL_SPEED``, if its scans run (else a note).

Rig time, equal rig time, fits, scores and the honesty rule are bench/image_mode's (``bench._modes``): each run is
cut in time order at the anchor's rig time and the points measured by then are fitted with effective errors and
scored against the truth. Within 1/2/3 SE (of the truth's mean over each reading's footprint and blur,
``model.fit.footprint``): with the readings' errors alone, and with the directions' angular
variance at the true material added (ROI footprint and, for a scanned point, its motion blur). Scanned: points
whose journal record has a ``scan`` key (the rest were measured at rest: every run's first point, and any point a
scan fell back on). ScanTooFast: the warnings a run raised (at most one per scan run) and the largest blur named.

    .venv/bin/python -m bench.continuous_scan [--quick] [--no-docs] [--seed N] [--points N]

``--quick``: two speeds, no dense, settling or GRBL rows, image rows on image_mode's quick camera.
"""

from __future__ import annotations

import csv
import math
import tempfile
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from analysis.batch.tradeoff import MATERIALS, MAX_THETA, SNR, Material, grid_design
from bench._common import bench_parser, format_table, load_average, machine_description, markdown_table
from bench._continuous_scan_report import record_section, verdicts
from bench._modes import POINT_RESOLUTION, cut_at, honest, mode_rig, pct, point_times, score
from bench.image_mode import QUICK_RESOLUTION, RESOLUTION
from model.fit.design import ErrorPairs, error_pairs
from rig.instrument.kinematics import Joints, forward, solve_degrees
from rig.run.adaptive.sweep import measure_points
from rig.run.config.files import ConfigError, RigConfig, parse, sweep_config
from rig.run.config.schema import SweepFile
from rig.run.measuring.scan import ScanTooFast, scan_run
from rig.run.session import make_plan, start_run
from rig.run.storage.store import RunStore

#: Scan speeds (deg/s of the camera joint) of the dial; ``[capture] scan_speed_deg_s`` allows up to 30. None: left
#: out, the speed each scan run chooses (rig.run.planning.scans: the axis, the frames' blur, the camera's pace).
SPEEDS: tuple[float | None, ...] = (None, 2.0, 5.0, 10.0, 20.0, 30.0)
QUICK_SPEEDS: tuple[float | None, ...] = (None, 20.0)
#: The scan sweep: camera step (deg), the dense variant's, and the light-arm angles and tilts each run holds.
STEP_DEG = 20.0
DENSE_STEP_DEG = 5.0
DENSE_SPEEDS: tuple[float | None, ...] = (None, 5.0, 20.0)
LIGHTS_DEG = (15.0, 40.0, 65.0)
TILTS_DEG = (0.0, -35.0)
#: One count of the simulated XM430 (deg): the scan sweep's joint angles are whole counts (see scan_design).
COUNT_DEG = 360.0 / 4096
#: The settling rig's [link] settle_s (s) and the speed it scans at.
SETTLE_S = 0.5
SETTLE_SPEED = 20.0
#: Stands for the directory of the scan sweep's run at rest (the first run after the anchor) in a capture table.
FIRST_PASS = "<the pass at rest>"
#: Continuous + image mode: tile side (px) and speed; GRBL's speed.
IMAGE_TILE_PX = 16
IMAGE_SPEED = 10.0
GRBL_SPEED = 10.0


@dataclass
class Outcome:
    """One mode and dial on one material: throughput over the whole run, error and honesty at equal rig time."""

    mode: str
    sweep: str
    dial: str
    captures: int
    samples: int
    rig_time_s: float
    kept_captures: int
    kept_samples: int
    scores: dict[str, Any]
    scanned: int
    too_fast: list[float] = field(default_factory=list)
    cpu_s: float = 0.0

    @property
    def per_hour(self) -> float:
        """Samples per hour of rig time (whole run)."""
        return self.samples / self.rig_time_s * 3600.0


def _snap(angles: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(angles, dtype=np.float64) / COUNT_DEG) * COUNT_DEG


def scan_design(rig: RigConfig, step_deg: float) -> np.ndarray:
    """The scan sweep (N, 4) in degrees: runs along the camera joint, one per (tilt, light) pair, serpentine.

    Each run holds the light arm at one of LIGHTS_DEG and the stage at one of TILTS_DEG (roll 0: the materials are
    isotropic) while the camera steps ``step_deg`` over every angle clockwise of the light where both zeniths stay
    within MAX_THETA and the pose is reachable. Joint angles are whole servo counts: the arm then comes to rest on
    the run's last pose itself rather than a rounding short of it, which a scan would wait for until its move
    times out (rig.run.measuring.scan ``Scanner._reach``).
    """
    g = rig.geometry
    runs, flip = [], False
    for tilt in TILTS_DEG:
        for light in LIGHTS_DEG:
            cams = _snap(np.arange(70.0, -70.0 - 1e-9, -step_deg))
            n = len(cams)
            d = forward(g, Joints(light=_snap(np.full(n, light)), camera=cams, tilt=_snap(np.full(n, tilt)),
                                  roll=np.zeros(n)))  # fmt: skip
            pts = np.stack([np.asarray(a, dtype=np.float64) for a in (d.theta_i, d.phi_i, d.theta_o, d.phi_o)], -1)
            ok = (pts[:, 0] <= MAX_THETA) & (pts[:, 2] <= MAX_THETA) & (cams < light - g.min_separation_deg - 1.0)
            ok &= np.asarray(solve_degrees(g, pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 3]).reachable, dtype=bool)
            if ok.sum() >= 2:
                runs.append(pts[ok][::-1] if flip else pts[ok])
                flip = not flip
    return np.concatenate(runs)


def points_in_runs(rig: RigConfig, points: np.ndarray, order: bool) -> int:
    """How many of ``points`` a continuous sweep would scan (all but each run's first), from the plan alone."""
    table = {"sweep": {"kind": "list", "points": points.tolist(), "order": order}}
    plan = make_plan(rig, sweep_config(parse(table, SweepFile, "<plan>"), "<plan>"))
    slots, driven, pos, count = set(plan.reference_before), frozenset(rig.geometry.joint_names), 0, 0
    while pos < len(plan.points):
        run = scan_run(plan.points, pos, set(), slots, driven)
        count += len(run[1]) if run else 0
        pos = run[1][-1] + 1 if run else pos + 1
    return count


def capture_table(motion: str, speed: float | None, tile_px: int | None) -> dict[str, Any]:
    """The ``[capture]`` table of a run: SNR 100, ``motion`` at ``speed`` (deg/s), image mode if ``tile_px``."""
    cap: dict[str, Any] = {"target_snr": SNR, "motion": motion}
    if speed is not None:
        cap["scan_speed_deg_s"] = speed
    if tile_px is not None:
        cap.update(mode="image", tile_px=tile_px)
    return cap


def refused(capture: dict[str, Any]) -> str | None:
    """Why the capture table is refused (the parser's message), or None if it is accepted."""
    try:
        parse({"sweep": {"kind": "list", "points": [[30.0, 0.0, 30.0, 180.0]]}, "capture": capture}, SweepFile, "<c>")
    except ConfigError as exc:
        return str(exc)
    return None


Table = list[dict[str, Any]]


def run_sweep(rig: RigConfig, points: np.ndarray, capture: dict[str, Any],
              out: Path) -> tuple[Table, float, list[float]]:
    """Run the points (N, 4) in degrees in order: the table's rows, the rig time (s), each ScanTooFast's blur (deg)."""
    table = {"name": f"continuous-scan bench {out.name}", "capture": capture,
             "sweep": {"kind": "list", "points": points.tolist(), "order": False}}  # fmt: skip
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ScanTooFast)
        summary = start_run(rig, sweep_config(parse(table, SweepFile, "<scan sweep>"), "<scan sweep>"), out,
                            progress=False)  # fmt: skip
    warned = sum(issubclass(w.category, ScanTooFast) for w in caught)
    blur = [float(r["blur_deg"]) for r in RunStore.read(out).records()
            if r["kind"] == "event" and r.get("event") == "scan_too_fast"]  # fmt: skip
    assert len(blur) == warned, (blur, warned)  # each warning is journaled with its blur
    with open(summary.table, newline="") as fh:
        return list(csv.DictReader(fh)), summary.rig_time_s, blur


def _scanned(run: Path) -> int:
    return sum("scan" in r for r in RunStore.read(run).records() if r["kind"] == "point")


def _safe_score(rig: RigConfig, material: Material, rows: list[dict[str, Any]], pairs: ErrorPairs) -> dict[str, Any]:
    """``bench._modes.score``, or NaNs where the cut left too few rows to fit."""
    try:
        return score(rig, material, rows, pairs)
    except Exception as exc:  # a fit of a handful of rows may fail in any of several ways
        print(f"  (no fit of {len(rows)} rows: {type(exc).__name__}: {exc})", flush=True)
        nan = [math.nan] * 3
        return {"error": math.nan, "shape": math.nan, "within_readings": nan, "within_footprint": nan, "n_z": 0}


@dataclass(frozen=True)
class Run:
    """One run after the anchor: its mode, sweep label, points (N, 4) in degrees, rig and ``[capture]`` table.

    ``group``: runs that stand or fall together: when one fails, the group's other rows are left out too.
    """

    mode: str
    sweep: str
    points: np.ndarray
    rig: RigConfig
    capture: dict[str, Any]
    group: str = ""


def bench_plan(material: Material, seed: int, quick: bool) -> tuple[list[Run], list[str]]:
    """The runs of one material after the anchor, and notes on the rows left out."""
    rig = mode_rig(material, seed, POINT_RESOLUTION)
    sweep, dense = scan_design(rig, STEP_DEG), scan_design(rig, DENSE_STEP_DEG)
    label, dense_label = f"scan sweep, {STEP_DEG:g} deg steps", f"dense scan sweep, {DENSE_STEP_DEG:g} deg steps"
    rest = capture_table("stop", None, None)
    runs = [Run("stop-and-go", label, sweep, rig, rest)]
    runs += [Run("continuous", label, sweep, rig, capture_table("continuous", v, None))
             for v in (QUICK_SPEEDS if quick else SPEEDS)]  # fmt: skip
    # Exposures planned ahead from the at-rest pass just measured (runs[0]): what a lab's first pass buys a scan.
    ahead = {**capture_table("continuous", None, None), "exposure_from": FIRST_PASS}
    runs.append(Run("continuous", f"{label}, exposure from the pass at rest", sweep, rig, ahead))
    notes: list[str] = []
    if not quick:
        runs.append(Run("stop-and-go", dense_label, dense, rig, rest))
        runs += [Run("continuous", dense_label, dense, rig, capture_table("continuous", v, None)) for v in DENSE_SPEEDS]
        settling = mode_rig(material, seed, POINT_RESOLUTION, link={"settle_s": SETTLE_S})
        settled = f"{label}, settle_s {SETTLE_S:g} s"
        runs.append(Run("stop-and-go", settled, sweep, settling, rest))
        runs.append(Run("continuous", settled, sweep, settling, capture_table("continuous", SETTLE_SPEED, None)))
    image = capture_table("continuous", IMAGE_SPEED, IMAGE_TILE_PX)
    why = refused(image)
    if why is None:
        image_rig = mode_rig(material, seed, QUICK_RESOLUTION if quick else RESOLUTION)
        tiled = f"{label}, {IMAGE_TILE_PX} px tiles"
        runs.append(Run("image", tiled, sweep, image_rig, capture_table("stop", None, IMAGE_TILE_PX)))
        runs += [Run("continuous + image", tiled, sweep, image_rig, capture_table("continuous", v, IMAGE_TILE_PX))
                 for v in (None, IMAGE_SPEED)]  # fmt: skip
    else:
        notes.append(f"continuous + image mode left out: the capture table is refused ({why})")
    if not quick:
        grbl = mode_rig(material, seed, POINT_RESOLUTION, simulation={"link": "grbl"})
        on_grbl = f"{label}, GRBL rig"
        runs.append(Run("continuous", on_grbl, sweep, grbl, capture_table("continuous", GRBL_SPEED, None), "GRBL"))
        runs.append(Run("stop-and-go", on_grbl, sweep, grbl, rest, "GRBL"))
    return runs, notes


def stalls(rig: RigConfig, run: Path) -> int:
    """Points of ``run`` that took the link's whole move timeout or more: a scan that waited for a pose in vain."""
    ends = sorted(point_times(run).values())
    return int(np.sum(np.diff(ends) >= rig.file.link.move_timeout_s)) if len(ends) > 1 else 0


def measure_material(material: Material, seed: int, n_points: int, quick: bool, work: Path,
                     pairs: ErrorPairs) -> tuple[list[Outcome], list[str]]:  # fmt: skip
    """The anchor then every run of ``bench_plan`` on one material: outcomes (anchor first) and notes."""
    rig = mode_rig(material, seed, POINT_RESOLUTION)
    grid = grid_design(rig, n_points)
    cpu = time.process_time()
    rows, anchor_s = measure_points(rig, grid, work / "anchor", SNR)
    s = score(rig, material, rows, pairs)
    out = [Outcome("stop-and-go", f"grid of {len(grid)}, planner's order", "anchor", len(grid), len(rows), anchor_s,
                   len(grid), len(rows), s, 0, cpu_s=time.process_time() - cpu)]  # fmt: skip
    runs, notes = bench_plan(material, seed, quick)
    notes.append(f"the anchor's grid in the planner's order has {points_in_runs(rig, grid, True)} of {len(grid)} "
                 "points in runs along one joint (what a continuous sweep of that grid would scan)")  # fmt: skip
    failed: set[str] = set()
    for k, r in enumerate(runs):
        if r.group and r.group in failed:
            continue
        cpu = time.process_time()
        run = work / f"run{k}"
        speed = r.capture.get("scan_speed_deg_s")
        moving = r.capture.get("motion") == "continuous"
        dial = ("auto speed" if speed is None else f"{speed:g} deg/s") if moving else "at rest"
        what = f"{r.mode}, {r.sweep}, {dial}"
        capture = {k: str(work / "run0") if v == FIRST_PASS else v for k, v in r.capture.items()}
        try:
            rows, rig_s, blur = run_sweep(r.rig, r.points, capture, run)
            stalled = stalls(r.rig, run)
            if stalled:
                raise RuntimeError(f"{stalled} point(s) waited out the {r.rig.file.link.move_timeout_s:g} s move "
                                   f"timeout ({rig_s:.0f} s of rig time in all): the scan waited for a pose the arm "
                                   "did not reach")  # fmt: skip
        except Exception as exc:  # a mode another branch is still building may fail any way
            failed.add(r.group)
            notes.append(f"{what} left out{' with its group' if r.group else ''}: the run failed "
                         f"({type(exc).__name__}: {exc})")  # fmt: skip
            print(f"  note: {notes[-1]}", flush=True)
            out = [o for o in out if not (r.group and o.sweep == r.sweep)]
            continue
        kept, n_kept, _ = cut_at(run, rows, anchor_s)
        s = _safe_score(r.rig, material, kept, pairs)
        out.append(Outcome(r.mode, r.sweep, dial, len(point_times(run)), len(rows), rig_s, n_kept, len(kept), s,
                           _scanned(run), blur, time.process_time() - cpu))  # fmt: skip
        print(f"  {what}: {len(rows)} samples, {rig_s:.1f} s rig time, {out[-1].scanned} scanned", flush=True)
    return out, notes


HEAD = ["material", "mode", "sweep", "dial", "captures", "samples", "rig time (s)", "samples / rig-h",
        "x anchor", "captures at equal time", "error at equal time", "x anchor", "shape error",
        "within 1/2/3 SE, readings (%)", "within 1/2/3 SE, + angular (%)", "honest", "scanned",
        "ScanTooFast (max blur, deg)", "CPU (s)"]  # fmt: skip


def _ratio(a: float, b: float, fmt: str) -> str:
    return "-" if not (math.isfinite(a) and math.isfinite(b)) or b == 0 else format(a / b, fmt)


def table_rows(label: str, outcomes: list[Outcome]) -> list[list[str]]:
    """The table's rows of one material: the anchor, then every other run, each with its ratios to the anchor."""
    anchor = outcomes[0]
    rows = []
    for o in outcomes:
        s = o.scores
        rows.append([label, o.mode, o.sweep, o.dial, str(o.captures), str(o.samples), f"{o.rig_time_s:.1f}",
                     f"{o.per_hour:.3g}", _ratio(o.per_hour, anchor.per_hour, ".2f"), str(o.kept_captures),
                     f"{s['error']:.3g}", _ratio(s["error"], anchor.scores["error"], ".2f"), f"{s['shape']:.3g}",
                     pct(s["within_readings"]), pct(s["within_footprint"]),
                     "yes" if honest(s["within_readings"], s["n_z"]) else "no",
                     f"{o.scanned}/{o.captures} ({o.scanned / max(o.captures, 1):.0%})",
                     f"{len(o.too_fast)} ({max(o.too_fast):.3g})" if o.too_fast else "0",
                     f"{o.cpu_s:.0f}"])  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> int:
    """Measure every mode on every material; print the table and notes; write the docs section."""
    parser = bench_parser(__doc__)
    parser.add_argument("--quick", action="store_true",
                        help=f"speeds {QUICK_SPEEDS} only; no dense, settling or GRBL rows")  # fmt: skip
    parser.add_argument("--points", type=int, default=30, help="the anchor's grid points (default 30)")
    parser.add_argument("--seed", type=int, default=1, help="simulator seed (default 1)")
    args = parser.parse_args(argv)
    machine, load = machine_description(), load_average()
    print(f"{machine}\n{load} before the run", flush=True)
    pairs = error_pairs(4000, max_theta_deg=MAX_THETA)
    rows: list[list[str]] = []
    notes: list[str] = []
    lines: list[str] = []
    wall = time.perf_counter()
    for material in MATERIALS:
        print(material.name, flush=True)
        with tempfile.TemporaryDirectory(prefix="gonio-continuous-scan-") as tmp:
            outcomes, got = measure_material(material, args.seed, args.points, args.quick, Path(tmp), pairs)
        rows += table_rows(material.name, outcomes)
        lines += verdicts(material.name, list(outcomes))
        notes += [f"{material.name}: {n}" for n in got]
        print(format_table(HEAD, table_rows(material.name, outcomes)), flush=True)
    elapsed = time.perf_counter() - wall
    print("\n" + format_table(HEAD, rows))
    print("\n".join(lines))
    print("\n".join(f"note: {n}" for n in notes))
    print(f"wall time {elapsed:.0f} s; {load_average()} after the run")
    if not args.no_docs:
        record_section(args, f"{machine}, shared with other work ({load} before the run; wall time {elapsed:.0f} s)",
                       markdown_table(HEAD, rows), notes, lines)  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
