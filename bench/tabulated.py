"""The RGL table against the projection, the two stock-Mitsuba forms of a model without a native plugin.

For each model and tabulation grid: the error Mitsuba shows (relative RMS, cosine weighted and worst, on
model.mitsuba.projection's grid; for the table, Mitsuba reading the file), the file's size, and the time to
tabulate. Anchor, measured in the same run: the projection (native_projection: a fit of diffuse + GGX), the
other way to a stock form, for its error and its time. There is no speed goal; the accuracy goal is the
issue's: the table is the default wherever it is closer than the projection.

Run: ``.venv/bin/python -m bench.tabulated [--no-docs]``; prints a table and rewrites its docs/benchmarks.md
section.
"""

from __future__ import annotations

import time

from bench._common import bench_parser, format_table, load_average, machine_description, markdown_table, record
from model import CookTorrance, OrenNayar, Phong, Ward
from model.base import BRDF
from model.mitsuba.projection import native_projection
from model.mitsuba.tabulated import TabulationGrid, tabulate, tabulated_error
from model.mitsuba.variant import pick_variant

MODELS: dict[str, BRDF] = {
    "Phong n 30 (rho_d .3/.2/.1, rho_s .4/.5/.6)": Phong(rho_d=(0.3, 0.2, 0.1), rho_s=(0.4, 0.5, 0.6), n=30.0),
    "Phong n 300 (rho_d .1, rho_s .5)": Phong(rho_d=0.1, rho_s=0.5, n=300.0),
    "Oren-Nayar sigma 0.4": OrenNayar(rho_d=(0.6, 0.5, 0.4), sigma=0.4),
    "Lambert + GGX alpha 0.2, Schlick F0 0.04": CookTorrance(alpha=0.2, fresnel="schlick", f0=0.04,
                                                             rho_d=(0.5, 0.4, 0.2)),
    "Ward anisotropic alpha 0.1 x 0.3": Ward(rho_d=0.2, rho_s=0.3, alpha_x=0.1, alpha_y=0.3),
}  # fmt: skip
GRIDS: dict[str, TabulationGrid] = {
    "low (16, 12, 4, 32)": TabulationGrid(samples=16, theta_i=12, phi_i=4, ndf=32),
    "default (32, 24, 5, 64)": TabulationGrid(),
    "high (48, 32, 7, 96)": TabulationGrid(samples=48, theta_i=32, phi_i=7, ndf=96),
}


def _pct(x: float) -> str:
    return f"{100 * x:.2f}"


def main() -> None:
    """Measure every model on every grid against its projection, print and record."""
    parser = bench_parser(__doc__)
    args = parser.parse_args()
    machine, variant = machine_description(), pick_variant("rgb")
    tabulate(Phong(), GRIDS["low (16, 12, 4, 32)"])  # Mitsuba's kernels compiled before any timing
    head = ["model", "grid (samples, theta_i, phi_i, ndf)", "table RMS %", "cos-weighted %", "worst %", "MB",
            "tabulate s", "projection RMS %", "projection s", "RMS ratio table / projection"]  # fmt: skip
    rows = []
    for name, model in MODELS.items():
        t0 = time.perf_counter()
        projection = native_projection(model, variant=variant)
        t_projection = time.perf_counter() - t0
        for grid_name, grid in GRIDS.items():
            t0 = time.perf_counter()
            table = tabulate(model, grid, variant=variant)
            t_table = time.perf_counter() - t0
            e, p = tabulated_error(model, table, variant), projection.error
            rows.append([name, grid_name, _pct(e["rms_rel"]), _pct(e["rms_rel_cosine_weighted"]),
                         _pct(e["worst_rel"]), f"{table.size_bytes / 1e6:.2f}", f"{t_table:.2f}",
                         _pct(p["rms_rel"]), f"{t_projection:.2f}", f"{e['rms_rel'] / p['rms_rel']:.3f}"])  # fmt: skip
            print(format_table(head, rows[-1:]), flush=True)
    load = load_average()
    print(f"\n{machine}; Mitsuba {variant}; {load}")
    print(format_table(head, rows))
    if args.no_docs:
        return
    record(
        "tabulated", "Stock-Mitsuba table against projection", "",
        f"{machine}; Mitsuba {variant}; shared with other work ({load}): the times include the neighbours' load.",
        "Errors are Mitsuba's (the `measured` plugin reading the file; the projection's BSDF) against gonio's model "
        "on the 16473-pair grid of `model/mitsuba/projection.py` (both zenith angles 0-80 deg). Anchor, in the same "
        "run: the projection onto diffuse + GGX, for its error and the time of its fit. Goal: the table is the "
        "stock default wherever its RMS ratio to the projection is below 1.",
        markdown_table(head, rows),
    )  # fmt: skip


if __name__ == "__main__":
    main()
