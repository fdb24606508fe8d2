"""Simulated capture: time per capture (render plus bracket) and the reading's error, over spp, variant and crop.

1. Dials, one pose (theta_i 30, theta_o 20, in plane: 10 deg off the mirror direction), Lambert 0.5 and a
   GGX aluminium conductor (alpha 0.3): samples per pixel 1-64 on the default 64 x 64 camera's ROI crop;
   ROI crop against the full frame at 64, 256 and 1024 pixels square (4 spp); scalar_rgb and, where
   libLLVM loads, llvm_ad_rgb. Times are medians over renders with distinct seeds, so the render cache
   never answers them; its hit cost is timed apart (a bracket renders once and hits twice). A capture is
   one render plus a 3-frame bracket (sensor model), the linear merge and the ROI reading.
   Errors: the render's ROI mean against the model at the sample centre (``model.predict_radiance``,
   point light at the light arm radius) and against the model integrated over the ROI's pixel footprints
   (what a perfect renderer gives, so this is the render's own error); the merged bracket's ROI reading
   in counts/s against the centre prediction times ``optics.counts_per_radiance``.
2. A whole simulated sweep (``bench._sim_sweep``): ``SimulatedRig`` on its ManualClock, the real
   ``DynamixelLink`` over the pty, per point one move, 3 captures, the merge and the ROI reading.

Anchor: the scalar_rgb render of the 64 x 64 camera's ROI crop at 1 spp, Lambert (the cheapest render the
default rig does); the sweep's anchor is the goal, 100 points in 60 s with scalar_rgb on 2 cores.

Run: ``.venv/bin/python -m bench.simulator [--quick] [--no-write] [--points N]``.
"""

from __future__ import annotations

import argparse
import datetime
import itertools
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import drjit as dr
import mitsuba as mi
import numba
import numpy as np

import model as m
from acquisition.exposure.bracket import fixed_bracket
from acquisition.hdr.merge import merge_linear
from acquisition.noise import SensorNoise
from acquisition.roi import reduce_roi
from bench import _sim_sweep as sweep
from bench._common import DEFAULT_OUT, format_table, machine_description, markdown_table, publish, timed_calls
from model.base import Model
from model.mitsuba.materials import to_mitsuba
from model.mitsuba.variant import unavailable_reason
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import forward, inverse, require, world_pose
from simulator.camera.simulated import CameraOptics, SimulatedCamera
from simulator.render.renderer import RadianceRenderer, roi_mean
from simulator.render.spec import CameraSpec, LightSpec

ROOT = Path(__file__).resolve().parent.parent
FIGURE = ROOT / "docs" / "figures" / "simulator.png"
SCALAR, LLVM = sweep.VARIANTS
MATERIALS: dict[str, Model] = {
    "Lambert": m.Lambert(0.5),
    # Aluminium at 550 nm (Mitsuba's ior table), one channel: grey, so every channel errs alike.
    "GGX": m.CookTorrance(alpha=0.3, eta=0.959, k=6.687),
}
POSE_DEG = (30.0, 0.0, 20.0, 180.0)
NOISE, OPTICS, LIGHT = SensorNoise(), CameraOptics(), LightSpec(intensity=1.0)


def _best(fn: Callable[[], object], repeats: int) -> float:
    # Best of: on a machine shared with other jobs noise only adds time (see bench._common.best_time). The
    # load-dependent costs (the merge's worker wake-up) show in the sweep, which is timed end to end.
    return min(timed_calls(fn, repeats))


def measure(variant: str, material: str, res: int, crop: str, spp: int, repeats: int) -> sweep.Dial:
    """Time one setting's render (cache miss), cache hit, bracket and capture, and their readings' errors."""
    geo, brdf = RigGeometry(), MATERIALS[material]
    cam = CameraSpec(resolution=(res, res), spp=spp, variant=variant)
    renderer = RadianceRenderer(geo, LIGHT, cam)
    mat, key = to_mitsuba(brdf), repr(brdf)
    joints = require(inverse(geo, *POSE_DEG))
    pose, d = world_pose(geo, joints), forward(geo, joints)
    t0 = time.perf_counter()
    roi = renderer.roi(pose)  # computed once per pose, then cached with the renders
    roi_s = time.perf_counter() - t0
    box = roi if crop == "ROI" else None
    origin = (roi[0], roi[1]) if box else (0, 0)
    # The ROI inside the delivered image: all of a crop, the ROI box of a full frame.
    in_image = (0, 0, roi[2] - roi[0], roi[3] - roi[1]) if box else roi
    seeds = itertools.count(1)
    state = {"seed": 0}
    images: list[np.ndarray] = []

    def render() -> np.ndarray:
        return renderer.render(pose, mat, crop=box, key=key, seed=state["seed"])

    def miss() -> None:
        state["seed"] = next(seeds)
        images.append(render())

    render_s = _best(miss, repeats)
    hit_s = _best(render, repeats)
    centre = np.broadcast_to(m.predict_radiance(brdf, d.wi, d.wo, m.PointLight(1.0, geo.light_radius_m)), (3,))
    exact = sweep.analytic_roi_mean(geo, pose, LIGHT, cam, brdf, roi)
    reads = np.array([roi_mean(img, roi, origin) for img in images])
    counts = OPTICS.counts_per_radiance(NOISE)
    t_long = sweep.PEAK_FRACTION * NOISE.saturation_dn() / float(centre.max() * counts)
    exposures = fixed_bracket(t_long / 4.0, sweep.FRAMES, sweep.STOPS)
    camera = SimulatedCamera(lambda: np.asarray(render()), noise=NOISE, optics=OPTICS, seed=spp)
    brackets: list[Any] = []
    merges: list[float] = []

    def bracket() -> None:
        frames = []
        for t in exposures:
            camera.set_exposure(t)
            frames.append(camera.capture())
        t0 = time.perf_counter()
        hdr = merge_linear(frames, NOISE)
        brackets.append(reduce_roi(hdr.radiance, hdr.variance, in_image, flags=hdr.saturated))
        merges.append(time.perf_counter() - t0)

    bracket_s = _best(bracket, repeats)  # the last seed's render stays cached: every frame hits

    def capture() -> None:
        state["seed"] = next(seeds)
        bracket()

    merge_s = min(merges[1:])  # the bracket calls' merges, after the warm-up
    capture_s = _best(capture, repeats)
    # The same capture with the merge's numba kernel serial: on a loaded machine, waking the parallel
    # kernel's second worker for a few hundred pixels costs up to a scheduler time slice.
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        serial_s = _best(capture, repeats)
    finally:
        numba.set_num_threads(threads)
    misses = renderer.stats.misses
    if misses != 3 * (repeats + 1):
        raise RuntimeError(f"{misses} render cache misses, expected {3 * (repeats + 1)}: timings would be wrong")
    bmeans = np.array([np.asarray(r.mean) for r in brackets]) / (centre * counts) - 1.0
    bse = np.array([np.asarray(r.std_error) / np.asarray(r.mean) for r in brackets])
    return sweep.Dial(variant, material, res, crop, spp, int(np.prod(images[0].shape[:2])), roi_s, render_s, hit_s,
                bracket_s, merge_s, capture_s, serial_s, float(np.mean(reads / centre - 1.0)),
                float(np.sqrt(np.mean((reads / exact - 1.0) ** 2))), float(np.mean(bmeans)),
                float(np.median(bse)))  # fmt: skip


def first_calls(variants: list[str]) -> list[list[str]]:
    """Once-per-process costs: the merge kernel's load, each variant's load and first render; switch costs."""
    camera = SimulatedCamera(lambda: np.full((8, 8, 3), 1e4), seed=1)
    t0 = time.perf_counter()
    merge_linear([camera.capture()], NOISE)
    label = "first merge_linear call (an 8 x 8 x 3 crop: the numpy pass, numba not loaded)"
    rows = [[label, f"{1e3 * (time.perf_counter() - t0):.0f}"]]
    geo = RigGeometry()
    pose = world_pose(geo, require(inverse(geo, *POSE_DEG)))
    mat = to_mitsuba(MATERIALS["Lambert"])
    renderers = {v: RadianceRenderer(geo, LIGHT, CameraSpec(variant=v)) for v in variants}
    for v, r in renderers.items():
        t0 = time.perf_counter()
        mi.set_variant(v)
        r.roi_radiance(pose, mat)
        rows.append([f"{v}: set the variant, first ROI render", f"{1e3 * (time.perf_counter() - t0):.0f}"])
    seeds = itertools.count(1)
    for v, other in itertools.permutations(variants, 2):
        # The renderer restores the previously active variant after each render: with the other variant
        # left active (by a probe, a test, a comparison), every render pays two switches.
        mi.set_variant(other)
        t = _best(lambda v=v: renderers[v].roi_radiance(pose, mat, seed=next(seeds)), 3)  # type: ignore[misc]
        rows.append([f"{v} ROI render while {other} is the active variant", f"{1e3 * t:.1f}"])
    return rows


DIAL_HEADERS = ["variant", "material", "frame", "render", "spp", "pixels", "render ms", "/ anchor", "hit us",
                "bracket ms", "(merge ms)", "capture ms", "/ anchor", "capture ms, serial merge", "ROI box ms",
                "render vs centre", "render vs ROI model", "bracket vs centre", "bracket SE"]  # fmt: skip


def dial_row(r: sweep.Dial, anchor: float) -> list[str]:
    """One row of the dial table."""
    ms = [f"{1e3 * t:.2f}" for t in (r.render_s, r.bracket_s, r.merge_s, r.capture_s, r.serial_s)]
    return [r.variant, r.material, f"{r.res}x{r.res}", r.crop, str(r.spp), str(r.pixels), ms[0],
            f"{r.render_s / anchor:.2f}", f"{1e6 * r.hit_s:.0f}", *ms[1:4], f"{r.capture_s / anchor:.2f}", ms[4],
            f"{1e3 * r.roi_s:.1f}", f"{100 * r.err_centre:+.3f} %", f"{100 * r.err_render:.4f} %",
            f"{100 * r.err_bracket:+.3f} %", f"{100 * r.se_bracket:.3f} %"]  # fmt: skip


def summary(dials: dict[tuple[str, str, int, str, int], sweep.Dial], results: list[sweep.SweepResult]) -> list[str]:
    """Findings computed from this run's figures, one line each (terminal and docs)."""
    out = []
    variants = sorted({k[0] for k in dials}, reverse=True)
    spps, big = sorted({k[4] for k in dials}), max(k[2] for k in dials)
    for v in variants:
        lo, hi = dials[(v, "GGX", 64, "ROI", spps[0])], dials[(v, "GGX", 64, "ROI", spps[-1])]
        out.append(f"- {v}, GGX, 64x64 ROI crop: {hi.spp} spp renders in {hi.render_s / lo.render_s:.1f}x the time of "
                   f"{lo.spp} spp (capture {hi.capture_s / lo.capture_s:.1f}x); the render against the ROI model: "
                   f"{100 * lo.err_render:.4f} % at {lo.spp} spp, {100 * hi.err_render:.4f} % at {hi.spp}; against "
                   f"the centre prediction {100 * lo.err_centre:+.3f} % and {100 * hi.err_centre:+.3f} %.")  # fmt: skip
        d = dials[(v, "GGX", 64, "ROI", 4)]
        out.append(
            f"- {v}, GGX, 64x64 ROI crop, 4 spp: render {1e3 * d.render_s:.2f} ms, cache hit {1e6 * d.hit_s:.0f} us, "
            f"bracket {1e3 * d.bracket_s:.2f} ms (its merge {1e3 * d.merge_s:.2f} ms), capture {1e3 * d.capture_s:.2f} "
            f"ms, capture with the merge serial {1e3 * d.serial_s:.2f} ms (best of separate calls)."
        )
        roi, full = dials[(v, "GGX", big, "ROI", 4)], dials[(v, "GGX", big, "full", 4)]
        out.append(
            f"- {v}, {big}x{big}, 4 spp: ROI crop ({roi.pixels} px) render {1e3 * roi.render_s:.1f} ms, "
            f"full frame {1e3 * full.render_s:.1f} ms ({full.render_s / roi.render_s:.1f}x); capture "
            f"{1e3 * roi.capture_s:.1f} against {1e3 * full.capture_s:.1f} ms "
            f"({full.capture_s / roi.capture_s:.1f}x); the ROI box costs {1e3 * roi.roi_s:.1f} ms per new pose."
        )
    if LLVM in variants:
        pairs = [(res, crop, dials[(LLVM, "GGX", res, crop, 4)], dials[(SCALAR, "GGX", res, crop, 4)])
                 for res, crop in ((64, "ROI"), (64, "full"), (big, "ROI"), (big, "full"))]  # fmt: skip
        ratios = [f"{res}x{res} {crop} {fast.render_s / slow.render_s:.2f}" for res, crop, fast, slow in pairs]
        out.append(f"- Render time {LLVM} / {SCALAR} (GGX, 4 spp): {', '.join(ratios)}.")
    for r in results:
        share = {st: 100 * r.stages.get(st, 0.0) / r.total_s for st in ("motion", "render", "merge")}
        out.append(
            f"- Sweep {r.variant}{' ' + r.note if r.note else ''}: {r.total_s:.2f} s for {r.points} points, "
            f"{r.total_s * 100 / r.points / sweep.GOAL_S:.3f} of the goal per 100 points; motion "
            f"{share['motion']:.0f} %, render {share['render']:.0f} %, merge {share['merge']:.0f} % of it."
        )
    return out


def main(argv: Sequence[str] | None = None) -> None:
    """Measure the dials and the sweep, print the tables, write the figure and the docs section."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("--quick", action="store_true", help="fewer repeats, settings and points (smoke run)")
    ap.add_argument("--no-write", action="store_true", help="leave docs/ alone (figure to out/bench)")
    ap.add_argument("--points", type=int, default=None, help="sweep points (default 100, 10 with --quick)")
    args = ap.parse_args(argv)
    points = args.points or (10 if args.quick else 100)
    repeats = 2 if args.quick else 7
    sweep_runs = 1 if args.quick else 3
    spps = (1, 4) if args.quick else (1, 4, 16, 64)
    sizes = (64, 256) if args.quick else (64, 256, 1024)
    today, machine, t_run = datetime.date.today().isoformat(), machine_description(), time.perf_counter()
    load_start = os.getloadavg()[0]
    variants = [SCALAR]
    t0 = time.perf_counter()
    llvm_reason = unavailable_reason(LLVM)  # the probe loads the variant, and leaves it active
    probe_ms = 1e3 * (time.perf_counter() - t0)
    if llvm_reason is None:
        variants.append(LLVM)
    llvm_text = ".".join(str(v) for v in dr.detail.llvm_version()) if llvm_reason is None else "none"
    mi_version, dr_version = getattr(mi, "__version__", "?"), getattr(dr, "__version__", "?")
    versions = f"Mitsuba {mi_version}, drjit {dr_version}, libLLVM {llvm_text}, numba {numba.__version__}"
    print(f"# simulator, {today}\nMachine: {machine}; {versions}")
    if llvm_reason is not None:
        print(f"Skipping {LLVM}: {llvm_reason}")
    once = [[f"probe {LLVM} (loads it)", f"{probe_ms:.0f}"], *first_calls(variants)]
    print("\n## Once per process (ms)\n" + format_table(["what", "ms"], once))

    dials: dict[tuple[str, str, int, str, int], sweep.Dial] = {}
    settings = [(v, mat, 64, "ROI", spp) for v in variants for mat in MATERIALS for spp in spps]
    settings += [(v, "GGX", res, crop, 4) for v in variants for res in sizes for crop in ("ROI", "full")]
    for v in variants:
        mi.set_variant(v)  # keep it active for its settings: see the switch rows above
        for s in settings:
            if s[0] == v and s not in dials:
                dials[s] = measure(*s, repeats=repeats)
    rows = list(dials.values())
    anchor = dials[(SCALAR, "Lambert", 64, "ROI", 1)].render_s
    table = [dial_row(r, anchor) for r in rows]
    print(f"\n## Dials (best of {repeats} per cell; anchor: {SCALAR} Lambert 64x64 ROI render at 1 spp, "
          f"{1e3 * anchor:.2f} ms)\n" + format_table(DIAL_HEADERS, table))  # fmt: skip

    geo = RigGeometry()
    pts = sweep.sweep_points(geo, points)
    results = [sweep.repeated_sweep(v, MATERIALS["GGX"], pts, sweep_runs) for v in variants]
    # Diagnostic: the merge's parallel numba kernel on a tiny ROI crop, serial.
    threads = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        results.append(sweep.repeated_sweep(SCALAR, MATERIALS["GGX"], pts, sweep_runs, note="(numba 1 thread)"))
    finally:
        numba.set_num_threads(threads)
    sweep_table = [sweep.sweep_row(r) for r in results]
    print(f"\n## Sweep: {points} points, 3-frame brackets, GGX; the median of {sweep_runs} runs; ratio to the goal of "
          f"{sweep.GOAL_S:.0f} s\n"
          + format_table(sweep.SWEEP_HEADERS, sweep_table))  # fmt: skip
    for r in results:
        if r.kernels != "-":
            print(f"{r.variant}: {r.kernels}")
    verdict = next(r for r in results if r.variant == SCALAR)
    print(
        f"Goal (100 points < 60 s, {SCALAR}): {verdict.total_s:.2f} s for {points} points, "
        f"{'met' if verdict.total_s * 100 / points < sweep.GOAL_S else 'NOT met'}"
    )
    findings = summary(dials, results)
    findings.append(
        f"- Load average (1 min) of the machine: {load_start:.2f} at the start, {os.getloadavg()[0]:.2f} at the end."
    )
    print("\n## Findings\n" + "\n".join(findings))
    print(f"Whole run: {time.perf_counter() - t_run:.0f} s")

    figure = DEFAULT_OUT / "simulator.png" if args.no_write else FIGURE
    sweep.plot(figure, rows, results)
    print(f"Figure: {figure}")
    if not args.no_write:
        cmd = (
            "`.venv/bin/python -m bench.simulator"
            + (" --quick" if args.quick else "")
            + (f" --points {points}`" if args.points else "`")
        )
        body = markdown(today, machine, versions, cmd, repeats, anchor, table, once, sweep_table, results, findings)
        publish("simulator", body)


def markdown(today: str, machine: str, versions: str, cmd: str, repeats: int, anchor: float,
             table: list[list[str]], once: list[list[str]], sweep_table: list[list[str]],
             results: list[sweep.SweepResult], findings: list[str]) -> str:  # fmt: skip
    """The docs/benchmarks.md section (the prose after the tables is NOTES, kept in this file)."""
    kernels = [f"{r.variant}: {r.kernels}." for r in results if r.kernels != "-"]
    return "\n".join([
        "## Simulated capture and sweep (`bench/simulator.py`)",
        "",
        f"Command: {cmd} (figure `docs/figures/simulator.png`). Run on {today}.",
        f"Machine: {machine}; {versions}.",
        "",
        SETUP,
        "",
        f"Best of {repeats} per cell; anchor: {SCALAR}, Lambert, 64x64 ROI crop, 1 spp render = "
        f"{1e3 * anchor:.2f} ms.",
        "",
        markdown_table(DIAL_HEADERS, table),
        "",
        "Once per process, and the variant-switch trap (ms):",
        "",
        markdown_table(["what", "ms"], once),
        "",
        f"Sweep, {results[0].points} points, end to end (rig start to rig close), GGX; the run with the median "
        "total of the runs shown; per-point columns in ms:",
        "",
        markdown_table(sweep.SWEEP_HEADERS, sweep_table),
        "",
        *kernels,
        "",
        "Findings, computed from the figures above:",
        "",
        *findings,
        "",
        NOTES,
        "",
        "![simulator benchmark](figures/simulator.png)",
    ])  # fmt: skip


SETUP = (
    "Pose theta_i 30, theta_o 20 deg in plane (10 deg off the mirror direction); point light 1 W/sr at 0.5 m; "
    "Lambert 0.5 and GGX alpha 0.3 aluminium (eta 0.959, k 6.687). *render*: one Mitsuba render with a fresh "
    "seed (a cache miss); *hit*: the render cache answering; *bracket*: 3 frames 2 stops apart (sensor model, "
    "render cached), linear merge, ROI reading; *capture* = a bracket whose first frame renders. Errors: "
    "render ROI mean against the model at the sample centre (signed mean over seeds), against the model "
    "integrated over the ROI pixels' footprints (RMS over seeds: the render's own error), and the merged "
    "bracket's reading against the centre prediction in counts/s, with its reported standard error."
)
NOTES = """How to read it:

- Samples per pixel buy almost nothing here. A flat sample under a point light, rendered by the `direct`
  integrator with one emitter sample, has no Monte Carlo noise beyond the sub-pixel position (spp only
  antialiases), and an ROI mean over hundreds of pixels has all but converged at 1 spp: the render agrees
  with the model integrated over the ROI within 0.02 % at every spp, falling with spp as sub-pixel sampling
  noise does. What the spp column changes is time.
- The GGX rows read about half a percent below the centre prediction at every spp, in both variants, in the
  render and in the merged bracket alike: the lobe curves across the ROI (the ROI mean is not the value at
  the centre). It is a property of comparing an ROI mean with one direction's prediction, not a render error;
  the ROI-model column, which integrates the model over the same pixels, shows the render itself is right.
- A render of the default 64x64 camera's ROI at its default 4 spp costs about a millisecond, mostly
  per-render overhead (scene load, film, kernel launch), so `llvm_ad_rgb` does not pay off there; it wins from
  thousands of pixels up (the full-frame and large-ROI rows). `llvm_ad_rgb` compiles one kernel per film
  size, and the default ROI changes size with the pose: a sweep over sizes not seen before compiles tens of
  kernels of about 55-80 ms each (29 kernels, 2.1 s, once while this benchmark was written); drjit keeps
  them in its disk cache (`~/.drjit`), and the kernel line under the sweep table says what this run saw.
- The switch rows are a trap: the renderer restores the previously active Mitsuba variant after every
  render, so a process that has the other variant active (the llvm probe leaves it active in a fresh
  process; so does any comparison or test that used it) pays two variant switches per render, tens of
  times the render itself. The sweeps here set their variant first.
- The sweep's time is mostly motion: the link polls every 10 ms of simulated time until the servos are in
  position, and each poll is a SYNC_READ round trip over the pty. Rendering is a small share (findings).
- The merge's share of the sweep depends on the load: `merge_linear` runs a parallel numba kernel even on a
  few hundred pixels, and each call waits for its second worker; with the other core busy (other jobs
  shared this machine) that wait can reach a scheduler time slice. In most sweeps run while this benchmark
  was written the merge cost 4.6 to 30 ms per point with numba's 2 threads against 0.5-0.6 ms with one; in
  others it did not stall. The `merge ms/pt` column of the plain rows against the `(numba 1 thread)` row
  shows what this run saw; the dial table's best-of times miss such stalls by construction.
- Dial times are the best of N calls; sweep totals the median of whole runs, with their range. The machine
  has 2 cores shared with other jobs (load average under the findings). The errors are deterministic for a
  given seed."""


if __name__ == "__main__":
    main()
