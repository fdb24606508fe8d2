"""Helpers of ``bench.simulator``: the end-to-end simulated sweep, the analytic ROI reference, the figure.

Each point runs what a controller runs: one move through ``DynamixelLink`` (SYNC_WRITE, then polls until in
position), a 3-frame bracket 2 stops apart exposed from the model's predicted reading, the linear merge and
the ROI reading. Wall time is split into motion (the link), render (Mitsuba, cache misses and hits),
capture (sensor model, pose read-back, ROI box), merge and ROI, and planning (kinematics, prediction).
"""

from __future__ import annotations

import itertools
import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import drjit as dr
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import mitsuba as mi
import numpy as np
import numpy.typing as npt
from matplotlib.ticker import NullLocator

import model as m
from acquisition.exposure.bracket import fixed_bracket
from acquisition.hdr.merge import merge_linear
from acquisition.roi import reduce_roi
from bench._common import save_figure
from model.base import Model
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Joints, RigPose, forward, inverse, require, world_pose
from rig.instrument.kinematics_types import Unreachable
from simulator.render.spec import Box, CameraSpec, LightSpec
from simulator.render.view import camera_view, pixel_on_sample
from simulator.rig import SimRigSpec, SimulatedRig

FloatArray = npt.NDArray[np.float64]

#: Bracket: 3 frames 2 stops apart; the longest puts the predicted ROI level at half of saturation.
FRAMES = 3
STOPS = 2.0
PEAK_FRACTION = 0.5
GOAL_S = 60.0
VARIANTS = ("scalar_rgb", "llvm_ad_rgb")
#: Sweep grid (degrees): incidence, exitance zenith, and exitance azimuth (the light at phi_i = 0).
THETA_I = tuple(range(0, 71, 10))
THETA_O = tuple(range(0, 71, 10))
PHI_O = (180.0, 135.0, 90.0)


def sweep_points(geometry: RigGeometry, n: int) -> list[tuple[float, float, float, float]]:
    """n reachable BRDF points (theta_i, phi_i, theta_o, phi_o) in degrees, spread evenly over the grid."""
    grid = []
    for a, phi_o in enumerate(PHI_O):
        for b, ti in enumerate(THETA_I):
            # Serpentine order: neighbouring points are neighbouring poses, as a planned sweep would be.
            tos = THETA_O if (a * len(THETA_I) + b) % 2 == 0 else THETA_O[::-1]
            for to in tos:
                if to == 0 and phi_o != PHI_O[0]:
                    continue  # theta_o = 0 is one direction whatever phi_o: measure it once
                if not isinstance(inverse(geometry, ti, 0.0, to, phi_o), Unreachable):
                    grid.append((float(ti), 0.0, float(to), phi_o))
    if n <= len(grid):
        return [grid[int(i)] for i in np.linspace(0, len(grid) - 1, n).round()]
    return [grid[i % len(grid)] for i in range(n)]  # more points than the grid: revisit (renders cached)


@dataclass
class SweepResult:
    """Wall times in seconds of one simulated sweep, split by stage, and its readings' relative errors."""

    variant: str
    points: int
    note: str = ""
    total_s: float = 0.0
    startup_s: float = 0.0
    stages: dict[str, float] = field(default_factory=dict)
    renders: int = 0
    render_misses: int = 0
    err_centre: list[float] = field(default_factory=list)
    err_roi: list[float] = field(default_factory=list)
    z_roi: list[float] = field(default_factory=list)
    sim_time_s: float = 0.0
    kernels: str = "-"
    totals: list[float] = field(default_factory=list)

    def per_point_ms(self, stage: str) -> float:
        """Milliseconds per point spent in one stage."""
        return 1e3 * self.stages.get(stage, 0.0) / self.points


def analytic_roi_mean(
    geometry: RigGeometry,
    pose: RigPose,
    light: LightSpec,
    camera: CameraSpec,
    material: Model,
    roi: Box,
    max_samples: int = 1_000_000,
) -> FloatArray:
    """The model's mean radiance (3,) in W/(m^2 sr) over the ROI's pixel footprints on the sample (point light).

    What a perfect renderer gives for the ROI: per pixel the average over a sub-pixel grid (the film's box
    filter) of f(wi, wo) I cos(theta_i) / r^2 at the point the ray meets, with wi, wo and r from that point.
    """
    x0, y0, x1, y1 = roi
    sub = int(np.clip(np.sqrt(max_samples / ((x1 - x0) * (y1 - y0))), 1, 8))
    off = (np.arange(sub) + 0.5) / sub
    px, py = np.meshgrid((np.arange(x0, x1)[:, None] + off).ravel(), (np.arange(y0, y1)[:, None] + off).ravel())
    view = camera_view(geometry, pose, camera)
    p, uv = pixel_on_sample(view, pose, px, py)
    on = (np.abs(uv[..., 0]) <= 0.5 * geometry.sample_width_m) & (np.abs(uv[..., 1]) <= 0.5 * geometry.sample_height_m)
    frame = np.stack([pose.sample_tangent, pose.sample_bitangent, pose.sample_normal]).reshape(3, 3)
    to_light = np.asarray(pose.light_position_m).reshape(3) - p
    r2 = np.sum(to_light**2, axis=-1)
    wi = (to_light / np.sqrt(r2)[..., None]) @ frame.T
    to_cam = view.origin - p
    wo = (to_cam / np.linalg.norm(to_cam, axis=-1, keepdims=True)) @ frame.T
    f = np.asarray(material.eval(wi, wo), dtype=np.float64)
    if f.shape == wi.shape[:-1]:
        f = f[..., None]
    e = np.asarray(light.rgb()) * (np.maximum(wi[..., 2], 0.0) / r2)[..., None]
    rad = np.where(on[..., None], np.nan_to_num(f) * e, 0.0)
    out: FloatArray = rad.reshape(-1, 3).mean(axis=0)
    return out


@contextmanager
def _stopwatch(stages: dict[str, float], name: str) -> Iterator[None]:
    t0 = time.perf_counter()
    try:
        yield
    finally:
        stages[name] = stages.get(name, 0.0) + time.perf_counter() - t0


def _timed(fn: Callable[..., Any], stages: dict[str, float], name: str) -> Callable[..., Any]:
    """fn wrapped so its wall time adds to ``stages[name]``."""

    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with _stopwatch(stages, name):
            return fn(*args, **kwargs)

    return wrapper


def _kernel_summary() -> str:
    """Compiled and disk-cached llvm kernels since the last call (drjit's kernel history)."""
    jit = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    compiled = [k for k in jit if not k["cache_hit"]]
    disk = sum(1 for k in jit if k["cache_hit"] and k["cache_disk"])
    codegen_ms = sum(float(k.get("codegen_time", 0.0)) + float(k.get("backend_time", 0.0)) for k in compiled)
    return f"{len(jit)} kernel launches: {len(compiled)} compiled ({codegen_ms:.0f} ms), {disk} from the disk cache"


def run_sweep(variant: str, material: Model, points: list[tuple[float, float, float, float]], *, seed: int = 0,
              note: str = "") -> SweepResult:  # fmt: skip
    """One simulated sweep over ``points`` (degrees) on ``variant``; wall times in seconds, errors relative."""
    # Keep this sweep's variant active: the renderer restores the previously active one after every render,
    # which costs two switches (tens of ms) per render when another variant was left active by a probe.
    mi.set_variant(variant)
    llvm = variant.startswith("llvm")
    if llvm:
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()  # drop what came before
    res = SweepResult(variant, len(points), note)
    st = res.stages
    spec = SimRigSpec(material=material, camera=CameraSpec(variant=variant), seed=seed)
    held_all: list[tuple[Joints, Joints, Any]] = []
    t_start = time.perf_counter()
    rig = SimulatedRig(spec)
    rig.renderer.render = _timed(rig.renderer.render, st, "render")  # type: ignore[method-assign]
    with rig, rig.open_link() as link:
        assert rig.camera is not None
        cam, geo, noise = rig.camera, spec.geometry, spec.noise
        light = m.PointLight(intensity=spec.light.rgb()[0], distance=geo.light_radius_m)
        counts = cam.optics.counts_per_radiance(noise)
        res.startup_s = time.perf_counter() - t_start
        near: Joints | None = None
        for ti, pi, to, po in points:
            with _stopwatch(st, "plan"):
                target = require(inverse(geo, ti, pi, to, po, near=near))
                d = forward(geo, target)
                rate = float(np.max(m.predict_radiance(material, d.wi, d.wo, light))) * counts
                t_long = PEAK_FRACTION * noise.saturation_dn() / rate if rate > 0 else 0.1
                exposures = fixed_bracket(t_long / 2.0 ** (STOPS * (FRAMES - 1) / 2), FRAMES, STOPS)
            with _stopwatch(st, "motion"):
                link.move_to({k: float(v) for k, v in target.as_dict().items()})
                near = Joints.from_dict(link.wait_in_position(timeout_s=30.0))
            with _stopwatch(st, "capture"):
                frames = []
                for t in exposures:
                    cam.set_exposure(t)
                    frames.append(cam.capture())
            with _stopwatch(st, "merge"):
                hdr = merge_linear(frames, noise)
                h, w = hdr.radiance.shape[:2]
                reading = reduce_roi(hdr.radiance, hdr.variance, (0, 0, w, h), flags=hdr.saturated)
            held_all.append((near, rig.joints_now(), reading))  # checked after the clock stops
        res.sim_time_s = rig.clock.now()
    res.total_s = time.perf_counter() - t_start
    # The render wrapper runs inside each capture: count it once.
    st["capture"] = st.get("capture", 0.0) - st.get("render", 0.0)
    st["other"] = res.total_s - res.startup_s - sum(st.values())
    stats = rig.renderer.stats
    res.renders, res.render_misses = stats.hits + stats.misses, stats.misses
    if llvm:
        res.kernels = _kernel_summary()
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    for read_back, physical, reading in held_all:
        # Centre: the model at the directions the link read back, all a controller knows. ROI: the model
        # integrated over the ROI at the pose the servos physically hold, what the render should give.
        dh = forward(geo, read_back)
        centre = np.asarray(m.predict_radiance(material, dh.wi, dh.wo, light)) * counts
        pose = world_pose(geo, physical)
        roi = rig.renderer.roi(pose)
        exact = analytic_roi_mean(geo, pose, spec.light, spec.camera, material, roi) * counts
        mean, se = np.asarray(reading.mean), np.asarray(reading.std_error)
        res.err_centre.append(float(np.max(np.abs(mean / centre - 1.0))))
        res.err_roi.append(float(np.max(np.abs(mean / exact - 1.0))))
        res.z_roi.append(float(np.max(np.abs((mean - exact) / se))))
    return res


def repeated_sweep(variant: str, material: Model, points: list[tuple[float, float, float, float]], runs: int,
                   note: str = "") -> SweepResult:  # fmt: skip
    """The run with the median total time (seconds) of ``runs`` identical sweeps, all totals attached."""
    results = [run_sweep(variant, material, points, note=note) for _ in range(runs)]
    chosen = sorted(results, key=lambda r: r.total_s)[len(results) // 2]
    chosen.totals = [r.total_s for r in results]
    chosen.kernels = results[0].kernels  # the first run is the one that may compile
    return chosen


STAGES = ("motion", "render", "capture", "merge", "plan", "other")
SWEEP_HEADERS = ["variant", "points", "total s", "runs: min-max s", "/ 60 s goal", "startup s",
                 *(f"{s} ms/pt" for s in STAGES), "renders (misses)", "err vs centre med / max",
                 "err vs ROI model med / max", "max abs z", "simulated s"]  # fmt: skip


def sweep_row(r: SweepResult) -> list[str]:
    """One row of the sweep table."""
    spread = f"{min(r.totals):.2f}-{max(r.totals):.2f} ({len(r.totals)})" if r.totals else "-"
    return [f"{r.variant} {r.note}".strip(), str(r.points), f"{r.total_s:.2f}", spread, f"{r.total_s / GOAL_S:.3f}",
            f"{r.startup_s:.2f}", *(f"{r.per_point_ms(s):.1f}" for s in STAGES), f"{r.renders} ({r.render_misses})",
            f"{_pct(statistics.median(r.err_centre))} / {_pct(max(r.err_centre))}",
            f"{_pct(statistics.median(r.err_roi))} / {_pct(max(r.err_roi))}", f"{max(r.z_roi):.1f}",
            f"{r.sim_time_s:.0f}"]  # fmt: skip


def _pct(x: float) -> str:
    return f"{100 * x:.2f} %"


@dataclass
class Dial:
    """One setting's times in seconds and relative errors (signed means, RMS over seeds)."""

    variant: str
    material: str
    res: int
    crop: str
    spp: int
    pixels: int
    roi_s: float
    render_s: float
    hit_s: float
    bracket_s: float
    merge_s: float
    capture_s: float
    serial_s: float
    err_centre: float
    err_render: float
    err_bracket: float
    se_bracket: float


def plot(path: Path, dials: list[Dial], sweeps: list[SweepResult]) -> None:
    """Times against spp and against pixels rendered, render error against spp, the sweep's time per point."""
    fig, ax = plt.subplots(2, 2, figsize=(12, 9))
    spp_rows = [d for d in dials if d.res == 64 and d.crop == "ROI"]
    materials = list(dict.fromkeys(d.material for d in dials))
    combos = list(itertools.product(VARIANTS, materials))
    for k, (v, mat) in enumerate(combos):
        rows = sorted((d for d in spp_rows if d.variant == v and d.material == mat), key=lambda d: d.spp)
        if not rows:
            continue
        x, c, mk = [d.spp for d in rows], f"C{k}", "o" if v == VARIANTS[0] else "s"
        ax[0, 0].plot(x, [1e3 * d.render_s for d in rows], "-", marker=mk, color=c, label=f"{v}, {mat}: render")
        ax[0, 0].plot(x, [1e3 * d.capture_s for d in rows], ":", marker=mk, color=c, label=f"{v}, {mat}: capture")
        ax[1, 0].plot(x, [100 * d.err_render for d in rows], "-", marker=mk, color=c, label=f"{v}, {mat}: ROI model")
        ax[1, 0].plot(x, [100 * abs(d.err_centre) for d in rows], ":", marker=mk, color=c, label=f"{v}, {mat}: centre")
    for a, what in ((ax[0, 0], "ms"), (ax[1, 0], "|relative error| of the ROI mean (%)")):
        a.set(xscale="log", yscale="log", xlabel="samples per pixel", ylabel=what)
        a.set_xticks(sorted({d.spp for d in spp_rows}), [str(s) for s in sorted({d.spp for d in spp_rows})])
        a.xaxis.set_minor_locator(NullLocator())
    ax[0, 0].set_title("64x64 camera, ROI crop: render, and capture\n(render + 3 frames + merge)", fontsize=10)
    ax[1, 0].set_title(
        "Render against the ROI model (solid, RMS)\nand against the centre prediction (dotted)", fontsize=10
    )
    for k, (v, crop) in enumerate(itertools.product(VARIANTS, ("ROI", "full"))):
        rows = sorted((d for d in dials if d.variant == v and d.crop == crop and d.spp == 4 and d.material == "GGX"),
                      key=lambda d: d.pixels)  # fmt: skip
        if rows:
            px, c = [d.pixels for d in rows], f"C{k}"
            ax[0, 1].plot(px, [1e3 * d.render_s for d in rows], "-o", color=c, label=f"{v}, {crop}: render")
            ax[0, 1].plot(px, [1e3 * d.capture_s for d in rows], ":o", color=c, label=f"{v}, {crop}: capture")
            for d in rows:
                ax[0, 1].annotate(f"{d.res}", (d.pixels, 1e3 * d.render_s), fontsize=7)
    ax[0, 1].set(xscale="log", yscale="log", xlabel="pixels rendered", ylabel="ms")
    ax[0, 1].set_title("ROI crop against full frame, GGX, 4 spp\n(labels: frame side in pixels)", fontsize=10)
    bottom = np.zeros(len(sweeps))
    names = [f"{s.variant}{chr(10) + s.note if s.note else ''}" for s in sweeps]
    for stage in STAGES:
        vals = np.array([s.per_point_ms(stage) for s in sweeps])
        ax[1, 1].barh(names, vals, left=bottom, label=stage)
        bottom += vals
    ax[1, 1].axvline(1e3 * GOAL_S / 100, color="k", ls=":", label="goal: 60 s per 100 points")
    ax[1, 1].set(xlabel="ms per point")
    ax[1, 1].set_title(f"Simulated sweep of {sweeps[0].points} points, wall time per point", fontsize=10)
    for a in ax.flat:
        a.legend(fontsize=6)
    save_figure(fig, path, dpi=100)
