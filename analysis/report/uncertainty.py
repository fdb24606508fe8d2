"""The report's uncertainty figure: are the error bars honest, and how much of them is angular?

Left: the histogram of z = (measured - predicted) / effective error against the chosen fit and, for a
simulated run, against the true material, with the standard normal drawn over it and the fractions within
1, 2, 3 beside the normal's 68 / 95 / 99.7 %. Right (when the samples carry direction covariances): each
sample's angular share of its effective variance against its specular angle theta_h, where a lobe's flank
makes the angular term dominate.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from matplotlib.figure import Figure

from analysis.report.layout import Margins, panel_figure
from analysis.result import Analysis
from analysis.uncertainty import NORMAL, angular_summary, truth, z_scores
from model.base import BRDF
from model.geometry import to_half_diff


def uncertainty_figure(a: Analysis) -> tuple[Figure, str]:
    """The figure (not yet saved) and its caption."""
    ang = angular_summary(a)
    fig, grid, _ = panel_figure((10.5, 4.0), 1, 2 if ang["included"] else 1,
                                Margins(left=0.7, bottom=0.6, top=0.35, wgap=0.9))  # fmt: skip
    axes = grid[0]
    left = axes[0]
    bins = np.linspace(-5, 5, 41)
    grid = np.linspace(-5, 5, 201)
    lines = []
    true = truth(a)
    compared: list[tuple[str, BRDF, npt.NDArray[np.float64] | None, str]] = [
        ("fit", a.selection.chosen.model, None, "#0072B2")
    ]
    if true is not None:
        compared.append(("truth", true.brdf, true.std_error, "#D55E00"))
    for label, brdf, se, colour in compared:
        zs = z_scores(a, brdf, se)
        clipped = np.clip(zs.z, -4.99, 4.99)
        left.hist(clipped, bins=bins, density=True, histtype="step", color=colour, linewidth=1.6,
                  label=f"against the {label} (n = {len(zs.z)})")  # fmt: skip
        lines.append(f"against the {label}: " + ", ".join(f"{100 * zs.within[k]:.1f} %" for k in (1, 2, 3)))
    left.plot(grid, np.exp(-0.5 * grid**2) / np.sqrt(2 * np.pi), color="black", linewidth=1, label="standard normal")
    left.set(xlabel="z = (measured - predicted) / effective error", ylabel="density", xlim=(-5, 5),
             title="z of every sample and channel (clipped at |z| = 5)")  # fmt: skip
    left.legend(loc="upper right", fontsize=8)
    left.grid(alpha=0.3)
    if ang["included"]:
        right = axes[1]
        theta_h = np.degrees(to_half_diff(a.samples.wi, a.samples.wo)[0])
        share = np.asarray(ang["share_per_sample"])
        right.scatter(theta_h, share, s=12, color="#009E73", rasterized=len(share) > 2000)
        right.set(xlabel="θh (deg)", ylabel="angular share of the variance", ylim=(-0.02, 1.02),
                  title=f"angular share: {100 * ang['share_total']:.1f} % of the total variance")  # fmt: skip
        right.grid(alpha=0.3)
    normal = ", ".join(f"{100 * NORMAL[k]:.1f} %" for k in (1, 2, 3))
    cap = (f"Honesty of the error bars. Fractions within 1, 2, 3 effective errors: {'; '.join(lines)} "
           f"(a standard normal: {normal}).")  # fmt: skip
    if ang["included"]:
        cap += (f" The angular uncertainty of the directions (encoder, motion during the frames, the geometry "
                f"calibration) is {100 * ang['share_total']:.1f} % of the total variance; on a steep lobe's "
                "flank it dominates a reading's error.")  # fmt: skip
    return fig, cap
