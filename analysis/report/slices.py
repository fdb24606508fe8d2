"""In-plane slices and polar lobes of the report, and the angles they are cut by.

Slices need samples in the plane of incidence: a sample belongs to the slice at incidence theta_i when its
theta_i is within the slice's tolerance and its outgoing direction lies within ``PLANE_TOL_DEG`` of that
plane; the caption says how many samples that leaves. Incidence angles come from the data when they
cluster (a sweep measures a few), otherwise (random MERL bins) from a fixed grid. Signed theta_o > 0 lies
forward of the light (:func:`in_plane_directions`), as in the sweep files and ``gonio models``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from matplotlib import rc_context
from matplotlib.artist import Artist
from matplotlib.axes import Axes
from matplotlib.lines import Line2D
from matplotlib.ticker import FixedLocator, FuncFormatter, LogLocator, MaxNLocator, NullLocator

from analysis.report.files import FigureFile, Slice
from analysis.report.layout import (
    CANDIDATE_COLOURS,
    CHANNEL_COLOURS,
    Margins,
    eval_channels,
    legend_below,  # fmt: skip
    panel_figure,
    save_figure,
)
from analysis.result import Analysis
from model.geometry import degrees_to_vector, to_half_diff, vector_to_spherical

Array = npt.NDArray[np.float64]

PLANE_TOL_DEG = 2.0
MAX_SLICES = 6
#: Incidences used when the data's theta_i do not cluster (degrees), with their half-width.
GRID_THETA_I_DEG, GRID_TOL_DEG = (15.0, 30.0, 45.0, 60.0, 75.0), 1.5
LOG_RANGE = 50.0
#: On a log axis a 2-sigma bar reaching zero stops at this fraction of the value.
LOG_BAR_FLOOR = 0.1
PHI_D_SNAP_DEG = 0.5


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


def in_plane_directions(theta_i_deg: float, signed_theta_o_deg: npt.ArrayLike) -> tuple[Array, Array]:
    """wi (3,) at phi_i = 0 and wo (n, 3) across the plane of incidence for signed theta_o in degrees.

    The one sign convention of gonio (the sweep files' ``in_plane``, the report's slices, ``gonio models``):
    theta_o > 0 lies forward of the light (phi_o = phi_i + 180, the side of the mirror direction), < 0 on its side.
    """
    to = np.asarray(signed_theta_o_deg, dtype=np.float64)
    wo = degrees_to_vector(np.abs(to), np.where(to > 0, 180.0, 0.0)).astype(np.float64)
    return degrees_to_vector(theta_i_deg, 0.0).astype(np.float64), wo


def _slice_dirs(theta_i_deg: float, n: int = 357) -> tuple[Array, Array, Array]:
    """Signed theta_o (deg) across the plane of incidence at phi_i = 0, wi (3,) and wo (n, 3)."""
    to = np.linspace(-89.0, 89.0, n)
    wi, wo = in_plane_directions(theta_i_deg, to)
    return to, wi, wo


class _InViewLogLocator(LogLocator):
    """LogLocator's ticks within the view only: it adds one beyond each end, which matplotlib builds a tick (a
    dozen objects, with its label formatted) for and then does not draw."""

    def tick_values(self, vmin: float, vmax: float) -> Sequence[float]:
        """The ticks (1/sr) between vmin and vmax, ends included to well within matplotlib's own tolerance."""
        ticks = np.asarray(super().tick_values(vmin, vmax), dtype=np.float64)
        lo, hi = sorted((vmin, vmax))
        if not (lo > 0 and np.isfinite(hi)):
            return list(ticks)
        margin = 1e-6 * (math.log10(hi) - math.log10(lo))
        log_t = np.log10(np.where(ticks > 0, ticks, np.nan))
        keep = (log_t >= math.log10(lo) - margin) & (log_t <= math.log10(hi) + margin)
        return list(ticks[keep])


def _y_scale(values: Array, y_scale: str) -> bool:
    if y_scale != "auto":
        return y_scale == "log"
    pos = values[np.isfinite(values) & (values > 0)]
    return bool(pos.size and pos.max() / pos.min() > LOG_RANGE)


def _error_bars(y: Array, e: Array, log: bool) -> tuple[Array, Array, npt.NDArray[np.bool_]]:
    """Lower and upper 2-sigma bar lengths, and which lower bars were cut short.

    On a log axis a bar reaching zero or below would run off the bottom of the plot and hide how large the value
    is; it stops at a tenth of the value instead (``LOG_BAR_FLOOR``) and the caption says so.
    """
    lower, upper = 2 * e, 2 * e
    cut = np.zeros(y.shape, dtype=bool)
    if log:
        floor = y * LOG_BAR_FLOOR
        cut = y - lower < floor
        lower = np.where(cut, y - floor, lower)
    return np.maximum(lower, 0.0), upper, cut


def plot_slices(a: Analysis, ang: Angles, cuts: tuple[Slice, ...], out: Path, y_scale: str, svg: bool) -> FigureFile:
    """Write slices.png (f_r in 1/sr against signed theta_o in degrees): data with 2-sigma bars, every candidate."""
    # Grids from the start: ax.grid() on each of up to 18 panels restyled every tick it had made; made with the
    # grid on, each tick is drawn so once.
    with rc_context({"axes.grid": True, "grid.alpha": 0.3}):
        return _plot_slices(a, ang, cuts, out, y_scale, svg)


def _plot_slices(a: Analysis, ang: Angles, cuts: tuple[Slice, ...], out: Path, y_scale: str, svg: bool) -> FigureFile:
    s, sel = a.samples, a.selection
    c = s.channels
    fig, axes, _ = panel_figure((4.2 * len(cuts) + 1.5, 3.1 * c + 1.2), c, len(cuts),
                                Margins(left=0.85, top=0.35, hgap=0.4, wgap=0.75, bottom=0.55, legend=0.5),
                                sharex=True)  # fmt: skip
    names = ["r", "g", "b"] if c == 3 else [str(i) for i in range(c)]
    chosen = a.chosen
    curves = {}
    for j, cut in enumerate(cuts):
        to, wi, wo = _slice_dirs(cut.theta_i_deg)
        curves[j] = {cand.name: eval_channels(cand.result.model, wi, wo, c) for cand in sel.candidates if cand.result}
        curves[j] |= {f"ref:{r.label}": eval_channels(r.brdf, wi, wo, c) for r in a.references}
    used = np.concatenate([cut.index for cut in cuts]) if cuts else np.zeros(0, dtype=np.intp)
    scale_values = np.concatenate([s.value[used].ravel(), *(v[chosen.name].ravel() for v in curves.values())])
    log = _y_scale(scale_values, y_scale)
    handles: dict[str, Artist] = {}
    n_cut = 0
    for j, cut in enumerate(cuts):
        to, _, _ = _slice_dirs(cut.theta_i_deg)
        idx = cut.index
        lower = s.lower_bound[idx]
        dense = len(idx) > 40  # caps and big markers would hide the curves under hundreds of MERL bins
        for ch in range(c):
            ax: Axes = axes[ch, j]
            for k, cand in enumerate(cd for cd in sel.candidates if cd.result is not None):
                is_chosen = cand.name == chosen.name
                (line,) = ax.plot(to, curves[j][cand.name][:, ch], color="black" if is_chosen else
                                  CANDIDATE_COLOURS[k % 6], lw=2.2 if is_chosen else 1.0, ls="-" if is_chosen else
                                  "--", zorder=3 if is_chosen else 2)  # fmt: skip
                handles.setdefault(f"{cand.name}{' (chosen)' if is_chosen else ''}", line)
            for r in a.references:
                (line,) = ax.plot(to, curves[j][f"ref:{r.label}"][:, ch], color="0.45", lw=1.0, ls=":")
                handles.setdefault(r.label, line)
            x, y, e = ang.signed_theta_o[idx], s.value[idx, ch], s.std_error[idx, ch]
            lo_bar, hi_bar, cut_short = _error_bars(y[~lower], e[~lower], log)
            n_cut += int(cut_short.sum())
            colour = CHANNEL_COLOURS[ch % 3]
            # Bars above the curves and drawn at least 0.8 pt wide, so they stay visible beside the markers;
            # hundreds of them are rasterised (an SVG of vector bars for a MERL table is megabytes and slow).
            ax.errorbar(x[~lower], y[~lower], yerr=np.stack([lo_bar, hi_bar]), fmt="o", ms=2 if dense else 3.5,
                        capsize=0 if dense else 2, elinewidth=0.8, ecolor=colour, alpha=0.8 if dense else 1.0,
                        zorder=4, color=colour, rasterized=dense)  # fmt: skip
            if lower.any():
                ax.plot(x[lower], y[lower], "^", ms=6, mfc="none", color=colour, rasterized=dense)
                handles.setdefault("saturated: lower bound", Line2D([], [], ls="none", marker="^", mfc="none",
                                                                    color="0.3", ms=6))  # fmt: skip
            top = max(float(np.nanmax(curves[j][chosen.name][:, ch])), float(np.max(y + 2 * e, initial=0.0))) or 1.0
            # Few ticks: each one is a dozen matplotlib objects, and ticks were most of the slices' drawing time.
            ax.xaxis.set_major_locator(FixedLocator([-90.0, -60.0, -30.0, 0.0, 30.0, 60.0, 90.0]))
            if log:
                ax.set_yscale("log")
                pos = np.concatenate([y[y > 0] * LOG_BAR_FLOOR, curves[j][chosen.name][:, ch]])
                pos = pos[pos > 0]
                bottom = max(float(pos.min()) / 1.5 if pos.size else 1e-6, top * 1e-6)
                ax.set_ylim(bottom, top * 3)
                # Plain labels (the default mathtext ones are laid out glyph by glyph), at 1-2-5 over up to two
                # decades and at the decades beyond.
                subs = (1.0, 2.0, 5.0) if top * 3 / bottom <= 150 else (1.0,)
                ax.yaxis.set_major_locator(_InViewLogLocator(subs=subs, numticks=8))
                ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
                ax.yaxis.set_minor_locator(NullLocator())
            else:
                ax.set_ylim(0.0, 1.15 * top if top > 0 else 1.0)
                ax.yaxis.set_major_locator(MaxNLocator(5))
            ax.set_title(f"θi = {cut.theta_i_deg:.3g}° ({len(idx)} samples), channel {names[ch]}", fontsize=9)
            if j == 0:
                ax.set_ylabel("f_r (1/sr)")
            if ch == c - 1:
                ax.set_xlabel("signed θo (deg; > 0 forward of the light)")
    data = Line2D([], [], ls="none", marker="o", color="0.3", ms=4)
    labels = [*handles, "data ± 2σ (in its channel's colour)"]
    # One legend for the figure, below the panels: inside an axes it covered the data it explains.
    legend_below(fig, [*handles.values(), data], labels, ncol=min(len(labels), 4))
    png, svg_path = save_figure(fig, out, "slices", svg)
    n = sum(len(cut.index) for cut in cuts)
    cap = (f"In-plane slices: data with 2σ error bars ({n} of {s.n} samples within {PLANE_TOL_DEG:g}° of the plane "
           f"of incidence), every fitted candidate (chosen: black){', references dotted' if a.references else ''}; "
           f"{'log' if log else 'linear'} y axis.")  # fmt: skip
    if n_cut:
        cap += (f" On the log axis {n_cut} lower bars that would reach zero stop at a tenth of the value "
                "(the value is within 2σ of zero there).")  # fmt: skip
    return FigureFile("slices", png, svg_path, cap)


def _polar_frame(ax: Axes, rmax: float) -> None:
    """A half-disc polar frame on ordinary axes: rim, three radii labelled under the horizon, spokes every 30 deg.

    Drawn as a handful of lines and labels: matplotlib's polar axes built a hundred tick artists per panel (most
    of the figure's time) and set their radial labels on top of each other.
    """
    arc = np.radians(np.linspace(-90.0, 90.0, 181))
    radii = [r for r in MaxNLocator(3).tick_values(0.0, rmax) if 0 < r < rmax * 0.999]
    for r in (*radii, rmax):
        ax.plot(r * np.sin(arc), r * np.cos(arc), color="0.55" if r == rmax else "0.85", lw=0.8, zorder=1)
    for r in radii:  # below the horizon, where no data can lie over them
        ax.text(-r, -0.03 * rmax, f"{r:.2g}", ha="center", va="top", fontsize=7, color="0.35")
    for deg in (-90, -60, -30, 0, 30, 60, 90):
        t = np.radians(deg)
        ax.plot([0.0, rmax * np.sin(t)], [0.0, rmax * np.cos(t)], color="0.85", lw=0.8, zorder=1)
        ax.text(1.07 * rmax * np.sin(t), 1.07 * rmax * np.cos(t), f"{deg}°", ha="center", va="center", fontsize=7)
    ax.set(xlim=(-1.2 * rmax, 1.2 * rmax), ylim=(-0.13 * rmax, 1.15 * rmax), aspect="equal")
    ax.set_axis_off()


def plot_polar(a: Analysis, ang: Angles, cuts: tuple[Slice, ...], out: Path, svg: bool) -> FigureFile:
    """Write polar.png: f_r cos theta_o (1/sr) against theta_o per slice, data and the chosen model per channel.

    The normal points up and signed theta_o > 0 (forward of the light) lies to its right.
    """
    s = a.samples
    c = s.channels
    names = ["r", "g", "b"] if c == 3 else [str(i) for i in range(c)]
    fig, axes, _ = panel_figure((4.0 * len(cuts) + 0.5, 2.7), 1, len(cuts),
                                Margins(left=0.2, right=0.2, top=0.35, bottom=0.05, wgap=0.3, legend=0.35))
    for j, cut in enumerate(cuts):
        ax: Axes = axes[0, j]
        to, wi, wo = _slice_dirs(cut.theta_i_deg)
        f = eval_channels(a.selection.chosen.model, wi, wo, c) * np.cos(np.radians(to))[:, None]
        idx = cut.index[~s.lower_bound[cut.index]]
        y = s.value[idx] * np.cos(np.radians(ang.theta_o[idx]))[:, None]
        rmax = max(float(f.max()), float(y.max(initial=0.0))) * 1.1 or 1.0
        _polar_frame(ax, rmax)
        t_curve, t_data = np.radians(to), np.radians(ang.signed_theta_o[idx])
        for ch in range(c):
            colour = CHANNEL_COLOURS[ch % 3]
            ax.plot(f[:, ch] * np.sin(t_curve), f[:, ch] * np.cos(t_curve), color=colour, lw=1.5, zorder=3)
            ax.plot(y[:, ch] * np.sin(t_data), y[:, ch] * np.cos(t_data), "o", ms=3, color=colour, zorder=4,
                    rasterized=len(idx) > 40)  # fmt: skip
        ti = np.radians(cut.theta_i_deg)
        ax.annotate("", xy=(0.0, 0.0), xytext=(-rmax * np.sin(ti), rmax * np.cos(ti)),
                    arrowprops={"arrowstyle": "->", "color": "0.4"})  # fmt: skip
        ax.set_title(f"θi = {cut.theta_i_deg:.3g}°: f_r cos θo (1/sr)", fontsize=9)
    # The legend says what the line and the dots are, and which colour is which channel.
    kinds = [Line2D([], [], color="0.2", lw=1.5), Line2D([], [], ls="none", marker="o", ms=3, color="0.2")]
    chans = [Line2D([], [], color=CHANNEL_COLOURS[ch % 3], lw=4) for ch in range(c)]
    legend_below(fig, [*kinds, *chans], [f"chosen model ({a.selection.chosen_name})", "data",
                                         *(f"channel {n}" for n in names)], ncol=2 + c)  # fmt: skip
    png, svg_path = save_figure(fig, out, "polar", svg)
    cap = (
        "Polar lobes in the plane of incidence: f_r cos θo against θo (light arriving along the grey arrow), "
        f"data points and the chosen model ({a.selection.chosen_name}), one colour per channel."
    )
    return FigureFile("polar", png, svg_path, cap)
