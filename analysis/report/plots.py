"""The analysis report's figures: in-plane slices and polar lobes (analysis/report/slices.py), residual maps,
coverage of the BRDF domain, the z-scores (analysis/report/uncertainty.py) and, for a simulated run, the
comparison with the truth (analysis/report/truth.py); :func:`write_figures` writes them all. Residuals are the chosen
model's (model - data) / std error, combined over channels as a signed RMS (the sign of the mean), so a
channel-coloured bias does not cancel out; the colour scale is clipped at +-5 sigma. Coverage counts the
occupied cells of a coarse grid over Rusinkiewicz's (theta_h, theta_d) and (theta_h, phi_d), phi_d folded
into [0, 180) by reciprocity as in MERL tables.

Drawn on matplotlib's Agg canvas directly (no pyplot state). Scatter layers are rasterised, so the SVG
copies stay small even for 20,000 MERL samples.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager
from pathlib import Path

import numpy as np
import numpy.typing as npt
from matplotlib import rc_context
from matplotlib.colors import ListedColormap, Normalize
from matplotlib.patches import Circle

from analysis.figure_pool import PendingDraws, start_draws
from analysis.progress import stage_bar
from analysis.report.files import CELL_PHI_D_DEG, CELL_THETA_DEG, Coverage, FigureFile, Figures
from analysis.report.layout import Margins, eval_channels, panel_figure, save_figure
from analysis.report.slices import Angles, Slice, angles_of, in_plane_directions, plot_polar, plot_slices, slices
from analysis.report.truth import compare_truth, truth_figure
from analysis.report.uncertainty import uncertainty_figure
from analysis.result import Analysis

Array = npt.NDArray[np.float64]
#: Re-exported: the report's angles and slices are imported from here by the tests and the batch.
__all__ = ["Angles", "Coverage", "FigureFile", "Figures", "PendingFigures", "Slice", "angles_of", "coverage",
           "in_plane_directions", "signed_rms", "slices", "start_figures", "write_figures"]

CLIP_SIGMA = 5.0


def _edges() -> tuple[Array, Array]:
    return np.arange(0.0, 90.0 + CELL_THETA_DEG / 2, CELL_THETA_DEG), np.arange(0.0, 180.0 + 1e-9, CELL_PHI_D_DEG)


def coverage(ang: Angles) -> Coverage:
    """Which cells of the coarse (theta_h, theta_d) and (theta_h, phi_d) grids the samples reach."""
    et, ep = _edges()
    hd, _, _ = np.histogram2d(ang.theta_h, ang.theta_d, bins=(et, et))
    hp, _, _ = np.histogram2d(ang.theta_h, ang.phi_d, bins=(et, ep))
    return Coverage(hd > 0, hp > 0)


def _layout() -> str:
    """The layout engine of every report figure."""
    return "constrained"


def signed_rms(residuals: Array) -> Array:
    """Per sample over channels: RMS of the normalised residuals with the sign of their mean."""
    r = np.asarray(residuals, dtype=np.float64).reshape(residuals.shape[0], -1)
    return np.sign(r.mean(axis=1)) * np.sqrt(np.mean(r**2, axis=1))


def _plot_residuals(a: Analysis, ang: Angles, out: Path, svg: bool) -> FigureFile:
    s = a.samples
    used = ~s.lower_bound
    resid = signed_rms((eval_channels(a.selection.chosen.model, s.wi, s.wo, s.channels) - s.value) / s.std_error)[used]
    norm = Normalize(-CLIP_SIGMA, CLIP_SIGMA, clip=True)
    size, edge = (3, "none") if used.sum() > 2000 else (26, "0.4")  # an edge keeps pale (good) points visible
    fig, axes, cax = panel_figure((10.5, 4.4), 1, 2, Margins(left=0.7, bottom=0.6, top=0.35, wgap=0.8, colorbar=0.18))
    left, right = axes[0]
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
    fig.colorbar(sc, cax=cax, label=f"(model − data) / σ, clipped at ±{CLIP_SIGMA:g}")
    png, svg_path = save_figure(fig, out, "residuals", svg)
    big = int(np.sum(np.abs(resid) > 3))
    cap = (
        f"Normalised residuals of {a.selection.chosen_name} at {int(used.sum())} samples ({big} beyond 3σ); "
        "red: the model is above the data, blue: below. Saturated lower bounds left out."
    )
    return FigureFile("residuals", png, svg_path, cap)


def _plot_coverage(a: Analysis, ang: Angles, cov: Coverage, out: Path, svg: bool) -> FigureFile:
    et, ep = _edges()
    shade = ListedColormap(["white", "#CFE8F3"])
    size = 2 if a.samples.n > 2000 else 14
    fig, axes, _ = panel_figure((10.5, 4.2), 1, 2, Margins(left=0.7, bottom=0.6, top=0.35, wgap=0.9))
    left, right = axes[0]
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
    png, svg_path = save_figure(fig, out, "coverage", svg)
    cap = (
        f"Coverage of the BRDF domain by the {a.samples.n} samples in Rusinkiewicz's half/difference angles "
        f"(shaded: occupied cells of {CELL_THETA_DEG:g}° in θ, {CELL_PHI_D_DEG:g}° in φd)."
    )
    return FigureFile("coverage", png, svg_path, cap)


def _plot_uncertainty(a: Analysis, out: Path, svg: bool) -> FigureFile:
    fig, cap = uncertainty_figure(a)
    png, svg_path = save_figure(fig, out, "uncertainty", svg)
    return FigureFile("uncertainty", png, svg_path, cap)


def _plot_truth(a: Analysis, out: Path, svg: bool) -> FigureFile | None:
    cmp = compare_truth(a)
    if cmp is None:
        return None
    fig, cap = truth_figure(cmp)
    png, svg_path = save_figure(fig, out, "truth", svg)
    return FigureFile("truth", png, svg_path, cap)


def write_figures(
    a: Analysis, out: str | Path, *, y_scale: str = "auto", log: Callable[[str], None] | None = None,
    svg: bool = False, progress: bool = False, names: Sequence[str] | None = None, jobs: int = 1,
) -> Figures:
    """Write slices, polar, residuals, coverage and uncertainty as PNG (and SVG if ``svg``) into ``out``.

    ``y_scale``: "auto", "log" or "linear" for the slices; ``progress``: a bar with ETA on stderr (tqdm.auto: the
    notebook widget in Jupyter); ``names``: only these figures (default: all); ``jobs``: figures drawn side by side
    in up to this many forked processes where that is safe (analysis/figure_pool.py).
    """
    with start_figures(a, out, y_scale=y_scale, svg=svg, names=names, jobs=jobs) as pending:
        return pending.finish(log=log, progress=progress)


class PendingFigures:
    """Figures being drawn (see :func:`start_figures`); :meth:`finish` waits for them and returns the Figures."""

    def __init__(self, pending: PendingDraws, n: int, cuts: tuple[Slice, ...], cov: Coverage) -> None:
        self._pending, self._n, self._cuts, self._cov = pending, n, cuts, cov

    def finish(self, *, log: Callable[[str], None] | None = None, progress: bool = False) -> Figures:
        """Every figure written (``log``: a line per file; ``progress``: a bar with ETA on stderr)."""
        with stage_bar(self._n, "figures", progress, unit="fig") as bar, _rc():

            def done(made: FigureFile | None) -> None:
                bar.update()
                if made is not None and log:
                    log(f"wrote {made.png}")

            made = self._pending.finish(done)
        return Figures(tuple(f for f in made if f is not None), self._cuts, self._cov)

    def __enter__(self) -> PendingFigures:
        return self

    def __exit__(self, *exc: object) -> None:
        self._pending.close()


def _rc() -> AbstractContextManager[None]:
    """Titles at a fixed height: placing each one above its axes' tick labels measured them all again per save."""
    return rc_context({"axes.titley": 1.0})


def start_figures(
    a: Analysis, out: str | Path, *, y_scale: str = "auto", svg: bool = False, names: Sequence[str] | None = None,
    jobs: int = 1,
) -> PendingFigures:
    """Begin writing the figures (arguments as :func:`write_figures`): in forked workers where that is safe, so the
    caller can work on meanwhile; use the result as a context manager and call its finish()."""
    if y_scale not in ("auto", "log", "linear"):
        raise ValueError(f"y scale {y_scale!r}: expected 'auto', 'log' or 'linear'")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    ang = angles_of(a.samples.wi, a.samples.wo)
    cuts, cov = slices(ang), coverage(ang)
    every = {"slices": lambda: plot_slices(a, ang, cuts, out, y_scale, svg),
             "polar": lambda: plot_polar(a, ang, cuts, out, svg),
             "residuals": lambda: _plot_residuals(a, ang, out, svg),
             "coverage": lambda: _plot_coverage(a, ang, cov, out, svg),
             "uncertainty": lambda: _plot_uncertainty(a, out, svg),
             "truth": lambda: _plot_truth(a, out, svg)}  # fmt: skip
    unknown = set(names or ()) - set(every)
    if unknown:
        raise ValueError(f"figures {sorted(unknown)}: expected names from {', '.join(every)}")
    draws = [draw for name, draw in every.items() if names is None or name in names]
    with _rc():  # forked workers keep the settings they were forked with
        pending = start_draws(draws, jobs)
    return PendingFigures(pending, len(draws), cuts, cov)
