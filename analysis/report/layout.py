"""The report figures' layout: panels placed by fixed margins in inches, on matplotlib's Agg canvas.

Constrained layout measured every tick label of every panel to place them, twice per save: a large share of
``gonio analyze``'s time. The report's figures are regular grids with labels of known size, so fixed margins
(room for a y label and its tick labels on the left, an x label below, a title above, a legend row or a
colour bar where asked) place them as well at no cost. No pyplot state: each figure is its own object.
Also here: what every figure writer shares (saving PNG and optional SVG, channel colours); the written file is
analysis/report/files.py's FigureFile.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt
from matplotlib import rc_context
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from acquisition.files.atomic import write_atomic
from model.base import BRDF

Array = npt.NDArray[np.float64]
#: Okabe-Ito colours: channels r, g, b, then candidates.
CHANNEL_COLOURS = ("#D55E00", "#009E73", "#0072B2")
CANDIDATE_COLOURS = ("#E69F00", "#56B4E9", "#CC79A7", "#F0E442", "#999999", "#882255")
#: zlib compression level of the PNG figures (see save_figure).
PNG_LEVEL = 3
#: Salt of the SVG element ids (any fixed string: ids must not change between runs).
SVG_SALT = "gonio"


@dataclass(frozen=True)
class Margins:
    """Space around and between panels, in inches."""

    left: float = 0.8
    right: float = 0.2
    bottom: float = 0.6
    top: float = 0.4
    wgap: float = 0.7
    hgap: float = 0.6
    #: Extra room below the panels for a figure legend (0: none).
    legend: float = 0.0
    #: Width of a colour bar at the right (0: none), and its gap from the panels.
    colorbar: float = 0.0
    colorbar_gap: float = 0.15


def panel_figure(
    size: tuple[float, float], rows: int, cols: int, margins: Margins = Margins(), *, sharex: bool = False,
) -> tuple[Figure, np.ndarray, Axes | None]:
    """A figure of ``size`` (inches) with rows x cols panels (an object array, 2-D) and an optional colour-bar axes."""
    fig = Figure(figsize=size)
    FigureCanvasAgg(fig)
    w, h = size
    m = margins
    right = m.right + (m.colorbar + m.colorbar_gap + 0.75 if m.colorbar else 0.0)  # 0.75 in: the bar's labels
    bottom = m.bottom + m.legend
    aw = (w - m.left - right - m.wgap * (cols - 1)) / cols
    ah = (h - m.top - bottom - m.hgap * (rows - 1)) / rows
    if aw <= 0 or ah <= 0:
        raise ValueError(f"figure {w} x {h} in too small for {rows} x {cols} panels with these margins")
    axes = np.empty((rows, cols), dtype=object)
    first: Axes | None = None
    for i in range(rows):
        for j in range(cols):
            x0 = m.left + j * (aw + m.wgap)
            y0 = h - m.top - (i + 1) * ah - i * m.hgap
            rect = (x0 / w, y0 / h, aw / w, ah / h)
            ax = fig.add_axes(rect, sharex=first if sharex else None)
            first = first or ax
            if sharex and i < rows - 1:
                ax.tick_params(labelbottom=False)
            axes[i, j] = ax
    cax = None
    if m.colorbar:
        x0 = w - right + m.colorbar_gap
        cax = fig.add_axes((x0 / w, bottom / h, m.colorbar / w, (h - m.top - bottom) / h))
    return fig, axes, cax


def legend_below(fig: Figure, handles: list, labels: list[str], ncol: int) -> None:
    """A figure legend centred in the bottom strip Margins.legend reserved."""
    fig.legend(handles, labels, loc="lower center", bbox_to_anchor=(0.5, 0.0), ncol=max(ncol, 1), fontsize=8,
               frameon=False)  # fmt: skip


def eval_channels(brdf: BRDF, wi: Array, wo: Array, channels: int) -> Array:
    """f_r (N, channels) in 1/sr of ``brdf`` at wi (3,) or (N, 3) and wo (N, 3), grey models repeated per channel."""
    f = np.asarray(brdf.eval(np.broadcast_to(wi, wo.shape), wo), dtype=np.float64)
    f = f[:, None] if f.ndim == 1 else f
    if f.shape[1] == channels:
        return f
    return np.broadcast_to(f.mean(axis=1, keepdims=True) if channels == 1 else f[:, :1], (f.shape[0], channels))


def save_figure(fig: Figure, out: Path, name: str, svg: bool) -> tuple[Path, Path | None]:
    """Write NAME.png (and NAME.svg when asked: it costs as much again and is rarely opened)."""
    png, svg_path = out / f"{name}.png", out / f"{name}.svg"
    # zlib level 3, not PIL's 6: the same pixels in slightly larger files, for less of the encoding's time (which
    # PNG encoding is a visible share of drawing the figures).
    write_atomic(png, lambda tmp: fig.savefig(tmp, format="png", dpi=100, pil_kwargs={"compress_level": PNG_LEVEL}))
    if not svg:
        svg_path.unlink(missing_ok=True)  # a stale copy from an earlier --svg run would not match the PNG
        return png, None
    # The same figure gives the same bytes: no date in the metadata, element ids hashed with a fixed salt
    # (matplotlib salts them with a random UUID otherwise), so a batch writes exactly what gonio analyze does.
    with rc_context({"svg.hashsalt": SVG_SALT}):
        write_atomic(svg_path, lambda tmp: fig.savefig(tmp, format="svg", metadata={"Date": None}))
    return png, svg_path
