"""Plot of a renderer comparison: where the rendered readings agree with the model's prediction, and why not.

Two panels over the sweep's points: measured/predicted - 1 and measured/extended - 1, in percent, each
point coloured by its explanation with its standard error as an error bar, over a band of +-2 expected
standard deviations (the sensor model's for the first panel; sensor and render noise for the second).
The deviations span decades (0.01 % noise next to a sample edge's 50 %), so the y axis is linear within a
few noise widths of 0 and logarithmic beyond. Unreachable points are shaded grey and labelled.

Drawn on matplotlib's Agg canvas directly (no pyplot): no global backend or figure state is touched.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter

from acquisition.files.atomic import atomic_path
from simulator.comparison import ComparisonResult, ComparisonRow, Explanation

#: One colour per explanation (colour-blind-safe Okabe-Ito palette).
COLOURS: dict[Explanation, str] = {
    Explanation.AGREES: "#009E73",
    Explanation.EXTENT: "#0072B2",
    Explanation.SAMPLE_EDGE: "#E69F00",
    Explanation.BEAM_EDGE: "#CC79A7",
    Explanation.GRAZING: "#D55E00",
    Explanation.RENDER_NOISE: "#56B4E9",
    Explanation.SENSOR_NOISE: "#F0E442",
    Explanation.UNEXPLAINED: "#000000",
    Explanation.UNREACHABLE: "#999999",
}


def _label(row: ComparisonRow) -> str:
    return f"{row.theta_i:g}/{row.theta_o:g}\n{row.phi_i:g}/{row.phi_o:g}"


def _panel(ax: Axes, result: ComparisonResult, which: str) -> None:
    """One panel: deviation in % of measured from ``which`` ("predicted" or "extended") with its noise band."""
    rows = [r for r in result.rows if r.reachable]
    x = np.array([r.index for r in rows], dtype=float)
    ratio = np.array([r.ratio if which == "predicted" else r.ratio_extended for r in rows])
    if which == "predicted":
        band = np.array([r.expected_rel_noise for r in rows])
    else:
        band = np.hypot([r.expected_rel_noise for r in rows], [r.render_rel_noise for r in rows])
    err = np.array([r.measured_rel_se for r in rows]) * ratio
    dev = 100.0 * (ratio - 1.0)
    finite = band[np.isfinite(band)]
    scale = 100.0 * float(np.median(finite)) if finite.size else 0.01
    ax.set_yscale("symlog", linthresh=max(4.0 * scale, 1e-4), linscale=1.5)
    # One bar per point: a band drawn across unreachable gaps would claim noise figures nobody computed.
    ax.bar(x, 400.0 * band, bottom=-200.0 * band, width=0.8, color="0.85", label="±2 expected sigma")
    ax.axhline(0.0, color="0.4", lw=0.8)
    for expl in Explanation:
        sel = np.array([r.explanation is expl for r in rows], dtype=bool)
        if sel.any():
            ax.errorbar(x[sel], dev[sel], yerr=100.0 * err[sel], fmt="o", ms=5, capsize=2,
                        color=COLOURS[expl], label=expl.value)  # fmt: skip
    for r in result.rows:
        if not r.reachable:
            ax.axvspan(r.index - 0.4, r.index + 0.4, color=COLOURS[Explanation.UNREACHABLE], alpha=0.25)
            ax.text(r.index, 0.0, "unreachable", rotation=90, ha="center", va="center", fontsize=7)
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.set_ylabel(f"measured / {which} - 1 (%)")
    ax.grid(True, which="major", alpha=0.3)


def plot_comparison(result: ComparisonResult, path: str | Path, *, dpi: int = 110) -> Path:
    """Write the comparison's two-panel plot (deviations in %, by point) as a PNG, atomically; return the path."""
    if not math.isfinite(dpi) or dpi <= 0:
        raise ValueError(f"dpi = {dpi!r}: expected a positive number of dots per inch")
    n = max(len(result.rows), 1)
    fig = Figure(figsize=(max(8.0, 0.55 * n + 5.0), 7.5), layout="constrained")
    FigureCanvasAgg(fig)
    top, bottom = fig.subplots(2, 1, sharex=True)
    _panel(top, result, "predicted")
    _panel(bottom, result, "extended")
    top.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    title = result.material if len(result.material) <= 90 else result.material[:87] + "..."
    top.set_title(f"{title}\n{result.variant}, {result.spp} spp, |z| <= {result.z_bound:g}", fontsize=9)
    bottom.set_xticks([r.index for r in result.rows], [_label(r) for r in result.rows], fontsize=7)
    bottom.set_xlabel("point: theta_i/theta_o over phi_i/phi_o (deg)")
    bottom.set_xlim(-0.6, n - 0.4)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi)
    return Path(path)
