"""The analysis report's figures: in-plane slices, polar lobes, residual maps and coverage of the BRDF domain.

Slices need samples in the plane of incidence: a sample belongs to the slice at incidence theta_i when its
theta_i is within the slice's tolerance and its outgoing direction lies within ``PLANE_TOL_DEG`` of that
plane; the caption says how many samples that leaves. Incidence angles come from the data when they
cluster (a sweep measures a few), otherwise (random MERL bins) from a fixed grid. Residuals are the chosen
model's (model - data) / std error, combined over channels as a signed RMS (the sign of the mean), so a
channel-coloured bias does not cancel out; the colour scale is clipped at +-5 sigma. Coverage counts the
occupied cells of a coarse grid over Rusinkiewicz's (theta_h, theta_d) and (theta_h, phi_d), phi_d folded
into [0, 180) by reciprocity as in MERL tables.

Drawn on matplotlib's Agg canvas directly (no pyplot state). Scatter layers are rasterised, so the SVG
copies stay small even for 20,000 MERL samples.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from matplotlib import rc_context
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import ListedColormap, Normalize
from matplotlib.figure import Figure
from matplotlib.patches import Circle
from matplotlib.projections.polar import PolarAxes
from matplotlib.ticker import FuncFormatter, LogLocator, NullLocator

from acquisition.files.atomic import write_atomic
from analysis.report_uncertainty import uncertainty_figure
from analysis.result import Analysis
from model.base import BRDF
from model.geometry import degrees_to_vector, to_half_diff, vector_to_spherical

Array = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

PLANE_TOL_DEG = 2.0
CLIP_SIGMA = 5.0
MAX_SLICES = 6
#: Incidences used when the data's theta_i do not cluster (degrees), with their half-width.
GRID_THETA_I_DEG, GRID_TOL_DEG = (15.0, 30.0, 45.0, 60.0, 75.0), 1.5
#: Coverage grid cells (degrees) in theta_h, theta_d and phi_d.
CELL_THETA_DEG, CELL_PHI_D_DEG = 10.0, 20.0
#: Okabe-Ito colours: channels r, g, b, then candidates.
CHANNEL_COLOURS = ("#D55E00", "#009E73", "#0072B2")
CANDIDATE_COLOURS = ("#E69F00", "#56B4E9", "#CC79A7", "#F0E442", "#999999", "#882255")
LOG_RANGE = 50.0
PHI_D_SNAP_DEG = 0.5
#: Salt of the SVG element ids (any fixed string: ids must not change between runs).
SVG_SALT = "gonio"


@dataclass(frozen=True)
class Angles:
    """Per-sample angles in degrees: directions, signed theta_o, distance from the plane of incidence, half/diff."""

    theta_i: Array
    phi_i: Array
    theta_o: Array
    phi_o: Array
    signed_theta_o: Array
    off_plane: Array
    theta_h: Array
    theta_d: Array
    phi_d: Array


def angles_of(wi: Array, wo: Array) -> Angles:
    """Angles (degrees) of direction pairs (N, 3); signed theta_o > 0 forward of the light (specular side)."""
    ti, pi = (np.degrees(a) for a in vector_to_spherical(wi))
    to, po = (np.degrees(a) for a in vector_to_spherical(wo))
    side = np.where(np.cos(np.radians(po - pi)) < 0, 1.0, -1.0)
    normal = np.stack([-np.sin(np.radians(pi)), np.cos(np.radians(pi)), np.zeros_like(pi)], axis=-1)
    off = np.degrees(np.arcsin(np.clip(np.abs(np.sum(wo * normal, axis=-1)), 0.0, 1.0)))
    th, _, td, pd = (np.degrees(a) for a in to_half_diff(wi, wo))
    pd = np.mod(pd, 180.0)
    # An in-plane pair a servo tick off the plane lands at phi_d = 180 - eps, the same azimuth as 0 + eps.
    pd = np.where(pd > 180.0 - PHI_D_SNAP_DEG, pd - 180.0, pd)
    return Angles(ti, pi, to, po, side * to, off, th, td, np.maximum(pd, 0.0))


@dataclass(frozen=True)
class Slice:
    """The samples (indices) in the plane of incidence at ``theta_i_deg`` +- ``tol_deg``."""

    theta_i_deg: float
    tol_deg: float
    index: IntArray


def slices(ang: Angles, plane_tol_deg: float = PLANE_TOL_DEG, max_slices: int = MAX_SLICES) -> tuple[Slice, ...]:
    """In-plane slices at the data's clustered incidences (or a fixed grid when they do not cluster)."""
    ti = np.sort(ang.theta_i)
    groups = np.split(ti, np.flatnonzero(np.diff(ti) > 1.0) + 1) if ti.size else []
    if groups and len(groups) <= 2 * max_slices and all(g[-1] - g[0] <= 2.0 for g in groups):
        centres = [(float(np.median(g)), max(0.5, float(g[-1] - g[0]) / 2 + 0.1)) for g in groups]
    else:
        centres = [(t, GRID_TOL_DEG) for t in GRID_THETA_I_DEG]
    if len(centres) > max_slices:  # keep evenly spread incidences, the first and the last among them
        centres = [centres[int(i)] for i in np.round(np.linspace(0, len(centres) - 1, max_slices))]
    in_plane = ang.off_plane <= plane_tol_deg
    return tuple(Slice(t, tol, np.flatnonzero(in_plane & (np.abs(ang.theta_i - t) <= tol))) for t, tol in centres)


@dataclass(frozen=True)
class Coverage:
    """Occupied cells of coarse grids over (theta_h, theta_d) and (theta_h, phi_d), with the cell sizes (deg)."""

    occupied_hd: npt.NDArray[np.bool_]
    occupied_hp: npt.NDArray[np.bool_]
    cell_theta_deg: float = CELL_THETA_DEG
    cell_phi_d_deg: float = CELL_PHI_D_DEG

    @property
    def fraction_hd(self) -> float:
        """Fraction of (theta_h, theta_d) cells holding at least one sample."""
        return float(self.occupied_hd.mean())

    @property
    def fraction_hp(self) -> float:
        """Fraction of (theta_h, phi_d) cells holding at least one sample."""
        return float(self.occupied_hp.mean())

    def text(self) -> str:
        """One sentence for the report."""
        c, p = self.cell_theta_deg, self.cell_phi_d_deg
        hd, hp = self.occupied_hd, self.occupied_hp
        return (f"{int(hd.sum())} of {hd.size} (theta_h, theta_d) cells of {c:g}° x {c:g}° hold a sample "
                f"({self.fraction_hd:.0%}); {int(hp.sum())} of {hp.size} (theta_h, phi_d) cells of {c:g}° x {p:g}° "
                f"({self.fraction_hp:.0%}).")  # fmt: skip


def _edges() -> tuple[Array, Array]:
    return np.arange(0.0, 90.0 + CELL_THETA_DEG / 2, CELL_THETA_DEG), np.arange(0.0, 180.0 + 1e-9, CELL_PHI_D_DEG)


def coverage(ang: Angles) -> Coverage:
    """Which cells of the coarse (theta_h, theta_d) and (theta_h, phi_d) grids the samples reach."""
    et, ep = _edges()
    hd, _, _ = np.histogram2d(ang.theta_h, ang.theta_d, bins=(et, et))
    hp, _, _ = np.histogram2d(ang.theta_h, ang.phi_d, bins=(et, ep))
    return Coverage(hd > 0, hp > 0)


@dataclass(frozen=True)
class FigureFile:
    """A written figure: its PNG, its SVG (or None) and a one-line caption."""

    name: str
    png: Path
    svg: Path | None
    caption: str


@dataclass(frozen=True)
class Figures:
    """Every figure of the report, the slices they drew and the coverage numbers."""

    files: tuple[FigureFile, ...]
    slices: tuple[Slice, ...]
    coverage: Coverage


def _eval(brdf: BRDF, wi: Array, wo: Array, channels: int) -> Array:
    f = np.asarray(brdf.eval(np.broadcast_to(wi, wo.shape), wo), dtype=np.float64)
    f = f[:, None] if f.ndim == 1 else f
    if f.shape[1] == channels:
        return f
    return np.broadcast_to(f.mean(axis=1, keepdims=True) if channels == 1 else f[:, :1], (f.shape[0], channels))


def _slice_dirs(theta_i_deg: float, n: int = 357) -> tuple[Array, Array, Array]:
    """Signed theta_o (deg) across the plane of incidence at phi_i = 0, wi (3,) and wo (n, 3)."""
    to = np.linspace(-89.0, 89.0, n)
    wo = degrees_to_vector(np.abs(to), np.where(to >= 0, 180.0, 0.0)).astype(np.float64)
    return to, degrees_to_vector(theta_i_deg, 0.0).astype(np.float64), wo


def _save(fig: Figure, out: Path, name: str) -> tuple[Path, Path]:
    png, svg = out / f"{name}.png", out / f"{name}.svg"
    write_atomic(png, lambda tmp: fig.savefig(tmp, format="png", dpi=100))
    fig.set_layout_engine("none")  # the layout is done; the SVG needs no second pass of it
    # The same figure gives the same bytes: no date in the metadata, element ids hashed with a fixed salt
    # (matplotlib salts them with a random UUID otherwise), so a batch writes exactly what gonio analyze does.
    with rc_context({"svg.hashsalt": SVG_SALT}):
        write_atomic(svg, lambda tmp: fig.savefig(tmp, format="svg", metadata={"Date": None}))
    return png, svg


def _y_scale(values: Array, y_scale: str) -> bool:
    if y_scale != "auto":
        return y_scale == "log"
    pos = values[np.isfinite(values) & (values > 0)]
    return bool(pos.size and pos.max() / pos.min() > LOG_RANGE)


def _plot_slices(a: Analysis, ang: Angles, cuts: tuple[Slice, ...], out: Path, y_scale: str) -> FigureFile:
    s, sel = a.samples, a.selection
    c = s.channels
    fig = Figure(figsize=(4.2 * len(cuts) + 1.5, 3.3 * c + 0.6), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(c, len(cuts), squeeze=False, sharex=True)
    names = ["r", "g", "b"] if c == 3 else [str(i) for i in range(c)]
    chosen = a.chosen
    curves = {}
    for j, cut in enumerate(cuts):
        to, wi, wo = _slice_dirs(cut.theta_i_deg)
        curves[j] = {cand.name: _eval(cand.result.model, wi, wo, c) for cand in sel.candidates if cand.result}
        curves[j] |= {f"ref:{r.label}": _eval(r.brdf, wi, wo, c) for r in a.references}
    used = np.concatenate([cut.index for cut in cuts]) if cuts else np.zeros(0, dtype=np.intp)
    scale_values = np.concatenate([s.value[used].ravel(), *(v[chosen.name].ravel() for v in curves.values())])
    log = _y_scale(scale_values, y_scale)
    for j, cut in enumerate(cuts):
        to, _, _ = _slice_dirs(cut.theta_i_deg)
        idx = cut.index
        lower = s.lower_bound[idx]
        for ch in range(c):
            ax: Axes = axes[ch, j]
            for k, cand in enumerate(cd for cd in sel.candidates if cd.result is not None):
                is_chosen = cand.name == chosen.name
                ax.plot(to, curves[j][cand.name][:, ch], color="black" if is_chosen else CANDIDATE_COLOURS[k % 6],
                        lw=2.2 if is_chosen else 1.0, ls="-" if is_chosen else "--", zorder=3 if is_chosen else 2,
                        label=f"{cand.name}{' (chosen)' if is_chosen else ''}")  # fmt: skip
            for r in a.references:
                ax.plot(to, curves[j][f"ref:{r.label}"][:, ch], color="0.45", lw=1.0, ls=":", label=r.label)
            x, y, e = ang.signed_theta_o[idx], s.value[idx, ch], s.std_error[idx, ch]
            dense = len(idx) > 40  # caps and big markers would hide the curves under hundreds of MERL bins
            ax.errorbar(x[~lower], y[~lower], yerr=2 * e[~lower], fmt="o", ms=2 if dense else 3.5, capsize=0 if dense
                        else 2, elinewidth=0.5 if dense else 1.0, zorder=4, color=CHANNEL_COLOURS[ch % 3],
                        label="data (2σ)")  # fmt: skip
            if lower.any():
                ax.plot(x[lower], y[lower], "^", ms=6, mfc="none", color=CHANNEL_COLOURS[ch % 3],
                        label="saturated: lower bound")  # fmt: skip
            top = max(float(np.nanmax(curves[j][chosen.name][:, ch])), float(np.max(y + 2 * e, initial=0.0))) or 1.0
            if log:
                ax.set_yscale("log")
                # Plain labels at 1-2-5: the default mathtext labels of minor ticks cost seconds per figure.
                ax.yaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
                ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
                ax.yaxis.set_minor_locator(NullLocator())
                pos = np.concatenate([y[y > 0], curves[j][chosen.name][:, ch]])
                pos = pos[pos > 0]
                ax.set_ylim(max(float(pos.min()) / 3 if pos.size else 1e-6, top * 1e-6), top * 3)
            else:
                ax.set_ylim(0.0, 1.15 * top if top > 0 else 1.0)
            ax.grid(alpha=0.3)
            ax.set_title(f"θi = {cut.theta_i_deg:.3g}° ({len(idx)} samples), channel {names[ch]}", fontsize=9)
            if j == 0:
                ax.set_ylabel("f_r (1/sr)")
            if ch == c - 1:
                ax.set_xlabel("signed θo (deg; > 0 forward of the light)")
    axes[0, 0].legend(fontsize=7, loc="best")
    png, svg = _save(fig, out, "slices")
    n = sum(len(cut.index) for cut in cuts)
    cap = (f"In-plane slices: data with 2σ error bars ({n} of {s.n} samples within {PLANE_TOL_DEG:g}° of the plane "
           f"of incidence), every fitted candidate (chosen: black){', references dotted' if a.references else ''}; "
           f"{'log' if log else 'linear'} y axis.")  # fmt: skip
    return FigureFile("slices", png, svg, cap)


def _plot_polar(a: Analysis, ang: Angles, cuts: tuple[Slice, ...], out: Path) -> FigureFile:
    s = a.samples
    c = s.channels
    fig = Figure(figsize=(4.0 * len(cuts) + 0.5, 2.9), layout="constrained")
    FigureCanvasAgg(fig)
    for j, cut in enumerate(cuts):
        ax: PolarAxes = fig.add_subplot(1, len(cuts), j + 1, projection="polar")  # type: ignore[assignment]
        ax.set_theta_zero_location("N")
        ax.set_theta_direction(-1)  # positive (forward) angles to the right of the normal
        ax.set_thetamin(-90)
        ax.set_thetamax(90)
        to, wi, wo = _slice_dirs(cut.theta_i_deg)
        f = _eval(a.selection.chosen.model, wi, wo, c) * np.cos(np.radians(to))[:, None]
        idx = cut.index[~s.lower_bound[cut.index]]
        y = s.value[idx] * np.cos(np.radians(ang.theta_o[idx]))[:, None]
        for ch in range(c):
            colour = CHANNEL_COLOURS[ch % 3]
            ax.plot(np.radians(to), f[:, ch], color=colour, lw=1.5, label="chosen model" if ch == 0 else None)
            ax.plot(np.radians(ang.signed_theta_o[idx]), y[:, ch], "o", ms=3, color=colour,
                    label="data" if ch == 0 else None)  # fmt: skip
        rmax = max(float(f.max()), float(y.max(initial=0.0))) * 1.1 or 1.0
        ax.set_rmax(rmax)
        ax.annotate("", xy=(0.0, 0.0), xytext=(np.radians(-cut.theta_i_deg), rmax),
                    arrowprops={"arrowstyle": "->", "color": "0.4"})  # fmt: skip
        ax.set_title(f"θi = {cut.theta_i_deg:.3g}°: f_r cos θo (1/sr)", fontsize=9)
        ax.tick_params(labelsize=7)
        if j == 0:
            ax.legend(fontsize=7, loc="lower left")
    png, svg = _save(fig, out, "polar")
    cap = (
        "Polar lobes in the plane of incidence: f_r cos θo against θo (light arriving along the grey arrow), "
        f"data points and the chosen model ({a.selection.chosen_name}) per channel."
    )
    return FigureFile("polar", png, svg, cap)


def signed_rms(residuals: Array) -> Array:
    """Per sample over channels: RMS of the normalised residuals with the sign of their mean."""
    r = np.asarray(residuals, dtype=np.float64).reshape(residuals.shape[0], -1)
    return np.sign(r.mean(axis=1)) * np.sqrt(np.mean(r**2, axis=1))


def _plot_residuals(a: Analysis, ang: Angles, out: Path) -> FigureFile:
    s = a.samples
    used = ~s.lower_bound
    resid = signed_rms((_eval(a.selection.chosen.model, s.wi, s.wo, s.channels) - s.value) / s.std_error)[used]
    norm = Normalize(-CLIP_SIGMA, CLIP_SIGMA, clip=True)
    size, edge = (3, "none") if used.sum() > 2000 else (26, "0.4")  # an edge keeps pale (good) points visible
    fig = Figure(figsize=(10.5, 4.4), layout="constrained")
    FigureCanvasAgg(fig)
    left, right = fig.subplots(1, 2)
    order = np.argsort(np.abs(resid))  # largest residuals on top
    th, td = ang.theta_h[used][order], ang.theta_d[used][order]
    sc = left.scatter(th, td, c=resid[order], cmap="RdBu_r", norm=norm, s=size, edgecolors=edge, linewidths=0.4,
                      rasterized=True)  # fmt: skip
    left.set(xlim=(0, 90), ylim=(0, 90), xlabel="θh (deg)", ylabel="θd (deg)", title="over (θh, θd)")
    dphi = np.radians(ang.phi_o - ang.phi_i)[used][order]
    rho = np.sin(np.radians(ang.theta_o[used][order]))
    right.add_patch(Circle((0.0, 0.0), 1.0, fill=False, color="0.5", lw=0.8))
    right.scatter(-rho * np.cos(dphi), rho * np.sin(dphi), c=resid[order], cmap="RdBu_r", norm=norm, s=size,
                  edgecolors=edge, linewidths=0.4, rasterized=True)  # fmt: skip
    right.set(xlim=(-1.05, 1.05), ylim=(-1.05, 1.05), aspect="equal", title="over the projected outgoing hemisphere",
              xlabel="sin θo, towards the forward side (azimuth relative to the light)", ylabel="")  # fmt: skip
    for ax in (left, right):
        ax.grid(alpha=0.3)
    fig.colorbar(sc, ax=[left, right], label=f"(model − data) / σ, clipped at ±{CLIP_SIGMA:g}")
    png, svg = _save(fig, out, "residuals")
    big = int(np.sum(np.abs(resid) > 3))
    cap = (
        f"Normalised residuals of {a.selection.chosen_name} at {int(used.sum())} samples ({big} beyond 3σ); "
        "red: the model is above the data, blue: below. Saturated lower bounds left out."
    )
    return FigureFile("residuals", png, svg, cap)


def _plot_coverage(a: Analysis, ang: Angles, cov: Coverage, out: Path) -> FigureFile:
    et, ep = _edges()
    shade = ListedColormap(["white", "#CFE8F3"])
    size = 2 if a.samples.n > 2000 else 14
    fig = Figure(figsize=(10.5, 4.2), layout="constrained")
    FigureCanvasAgg(fig)
    left, right = fig.subplots(1, 2)
    left.pcolormesh(et, et, cov.occupied_hd.T.astype(float), cmap=shade, vmin=0, vmax=1, rasterized=True)
    left.scatter(ang.theta_h, ang.theta_d, s=size, color="#0072B2", rasterized=True)
    left.set(xlim=(0, 90), ylim=(0, 90), xlabel="θh (deg)", ylabel="θd (deg)",
             title=f"(θh, θd): {cov.fraction_hd:.0%} of cells occupied")  # fmt: skip
    right.pcolormesh(et, ep, cov.occupied_hp.T.astype(float), cmap=shade, vmin=0, vmax=1, rasterized=True)
    right.scatter(ang.theta_h, ang.phi_d, s=size, color="#0072B2", rasterized=True)
    right.set(xlim=(0, 90), ylim=(0, 180), xlabel="θh (deg)", ylabel="φd (deg, folded into [0, 180))",
              title=f"(θh, φd): {cov.fraction_hp:.0%} of cells occupied")  # fmt: skip
    for ax in (left, right):
        ax.grid(alpha=0.3)
    png, svg = _save(fig, out, "coverage")
    cap = (
        f"Coverage of the BRDF domain by the {a.samples.n} samples in Rusinkiewicz's half/difference angles "
        f"(shaded: occupied cells of {CELL_THETA_DEG:g}° in θ, {CELL_PHI_D_DEG:g}° in φd)."
    )
    return FigureFile("coverage", png, svg, cap)


def _plot_uncertainty(a: Analysis, out: Path) -> FigureFile:
    fig, cap = uncertainty_figure(a)
    png, svg = _save(fig, out, "uncertainty")
    return FigureFile("uncertainty", png, svg, cap)


def write_figures(
    a: Analysis, out: str | Path, *, y_scale: str = "auto", log: Callable[[str], None] | None = None
) -> Figures:
    """Write slices, polar, residuals and coverage as PNG and SVG into ``out``; y_scale "auto", "log" or "linear"."""
    if y_scale not in ("auto", "log", "linear"):
        raise ValueError(f"y scale {y_scale!r}: expected 'auto', 'log' or 'linear'")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ang = angles_of(a.samples.wi, a.samples.wo)
    cuts, cov = slices(ang), coverage(ang)
    files = []
    for draw in (lambda: _plot_slices(a, ang, cuts, out, y_scale), lambda: _plot_polar(a, ang, cuts, out),
                 lambda: _plot_residuals(a, ang, out), lambda: _plot_coverage(a, ang, cov, out),
                 lambda: _plot_uncertainty(a, out)):  # fmt: skip
        files.append(draw())
        if log:
            log(f"wrote {files[-1].png}")
    return Figures(tuple(files), cuts, cov)
