"""The README's main job until the simulated rig exists: in-plane BRDF slices of a few materials.

Writes a PNG figure and a CSV table of the slices, and prints each material's physical checks, so a
newcomer sees in one command what the model module computes and how trustworthy it is.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import model as m
from model.base import BRDF
from model.checks import check_energy, check_reciprocity, check_sanity


@dataclass(frozen=True)
class Material:
    """A named model for the demonstration."""

    name: str
    brdf: BRDF


#: Aluminium's complex index eta + i k at roughly 650/550/450 nm (Rakic 1995), as RGB channels.
ALUMINIUM_ETA = (1.657, 0.880, 0.521)
ALUMINIUM_K = (9.224, 6.270, 4.837)

DEMO_MATERIALS: tuple[Material, ...] = (
    Material("matte (Oren-Nayar, sigma 0.3 rad)", m.OrenNayar((0.6, 0.5, 0.4), 0.3)),
    Material("rough aluminium (GGX, alpha 0.3)", m.CookTorrance(alpha=0.3, eta=ALUMINIUM_ETA, k=ALUMINIUM_K)),
    Material(
        "glossy plastic (GGX, eta 1.5, alpha 0.08)",
        m.CookTorrance(alpha=0.08, fresnel="dielectric", eta=1.5, rho_d=(0.5, 0.1, 0.1)),
    ),
    Material("brushed (Ward balanced, 0.05 x 0.3)", m.Ward(0.1, 0.3, 0.05, 0.3, variant="balanced")),
)

THETA_I_DEG = (0.0, 30.0, 60.0)


def in_plane_slice(brdf: BRDF, theta_i_deg: float, theta_o_deg: np.ndarray) -> np.ndarray:
    """f_r in 1/sr along the plane of incidence; signed theta_o > 0 is forward of the light (the mirror side),
    as in the sweep files and the analysis report (analysis.report.plots.in_plane_directions)."""
    from analysis.report.plots import in_plane_directions

    wi, wo = in_plane_directions(theta_i_deg, theta_o_deg)
    f = np.asarray(brdf.eval(wi, wo), dtype=float)
    return f if f.ndim == 2 else np.repeat(f[:, None], 3, axis=1)


def write_slices(out_dir: Path, materials: tuple[Material, ...] = DEMO_MATERIALS) -> tuple[Path, Path]:
    """Write the slice figure (PNG) and table (CSV) into out_dir and return their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    theta_o = np.linspace(-89.0, 89.0, 357)
    fig, axes = plt.subplots(2, 2, figsize=(11, 8), constrained_layout=True)
    rows: list[list[object]] = []
    for ax, mat in zip(axes.flat, materials, strict=True):
        for t_i, style in zip(THETA_I_DEG, ("-", "--", ":"), strict=True):
            f = in_plane_slice(mat.brdf, t_i, theta_o)
            for c, colour in enumerate(("tab:red", "tab:green", "tab:blue")):
                ax.semilogy(theta_o, np.maximum(f[:, c], 1e-4), style, color=colour, lw=1.2)
            ax.plot([], [], style, color="black", label=f"theta_i {t_i:.0f} deg")
            rows += [[mat.name, t_i, to, *fo] for to, fo in zip(theta_o, f, strict=True)]
        ax.axvline(0.0, color="0.8", lw=0.8)
        ax.set_title(mat.name, fontsize=10)
        ax.set_xlabel("signed θo in the plane of incidence (deg; > 0 forward of the light, the mirror side)")
        ax.set_ylabel("f_r (1/sr), R/G/B")
        ax.set_ylim(1e-3, None)
        ax.legend(fontsize=8)
    fig.suptitle("In-plane BRDF slices (light at phi = 0; line style = incidence angle)")
    png = out_dir / "brdf_slices.png"
    fig.savefig(png, dpi=110)
    plt.close(fig)
    table = out_dir / "brdf_slices.csv"
    with open(table, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["material", "theta_i_deg", "theta_o_deg", "f_r_red_per_sr", "f_r_green_per_sr", "f_r_blue_per_sr"])
        w.writerows(rows)
    return png, table


def check_table(materials: tuple[Material, ...] = DEMO_MATERIALS) -> list[str]:
    """One line per material with its reciprocity, energy and sanity checks."""
    lines = [f"{'material':44s} {'reciprocity':>12s} {'max albedo':>11s} {'at theta_i':>10s} {'finite>=0':>9s}"]
    for mat in materials:
        rec = check_reciprocity(mat.brdf, n=2000)
        en = check_energy(mat.brdf, n=20_000, method="mc")
        san = check_sanity(mat.brdf, n=500)
        lines.append(
            f"{mat.name:44s} {rec.max_rel_error:12.1e} {en.max_albedo:11.4f} "
            f"{np.degrees(en.theta_at_max):8.1f} deg {'yes' if san.passed else 'NO':>9s}"
        )
    return lines
