"""``gonio demo``: an in-plane sweep of rough gold on the simulated rig, its table, and a plot against the truth.

The rig and sweep are the ones in examples/rig_simulated.toml and examples/sweep_in_plane.toml, built here
so the demo runs from an installed package too. The plot shows the measured BRDF per channel with
2-sigma error bars against the simulated material's model, so a person sees at a glance that the whole
chain (servos, kinematics, camera, HDR merge, reference calibration) recovers the BRDF.
"""

from __future__ import annotations

import csv
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from gonio.cli_errors import CliError
from model.geometry import degrees_to_vector
from rig.run.config.files import RigConfig, material_from, parse, rig_config, sweep_config
from rig.run.config.schema import RigFile, SweepFile

GOLD = {"model": "CookTorrance", "alpha": 0.2, "distribution": "ggx", "fresnel": "conductor",
        "eta": [0.18, 0.42, 1.37], "k": [3.42, 2.35, 1.77]}  # fmt: skip


def demo_rig() -> RigConfig:
    """The simulated four-axis rig with a rough gold sample and a reference tile read every 20 points."""
    # A 4x4 px ROI at the sample's centre: its directions span ~0.06 deg, so the BRDF's curvature across
    # the footprint (the default ROI, the central half of the sample, spans ~3 deg) does not bias readings
    # past their errors.
    camera = {"resolution": [512, 512], "roi": [254, 254, 258, 258]}
    table = {"name": "simulated rig (demo)", "camera": camera, "simulation": {"material": GOLD, "seed": 1},
             "reference": {"every": 20}}  # fmt: skip
    return rig_config(parse(table, RigFile, "<demo rig>"), "<demo rig>")


def _signed_theta_o(row: dict[str, str]) -> float:
    dphi = (float(row["phi_o_deg"]) - float(row["phi_i_deg"])) % 360.0
    side = 1.0 if 90.0 < dphi < 270.0 else -1.0
    return side * float(row["theta_o_deg"])


def plot_demo(rows: list[dict[str, str]], rig: RigConfig, path: Path) -> Path:
    """Measured BRDF (1/sr, 2-sigma bars) against the material's model per incidence angle; writes a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    material = material_from(rig)
    incidences = sorted({round(float(r["target_theta_i_deg"]), 6) for r in rows})
    fig, axes = plt.subplots(1, len(incidences), figsize=(5.2 * len(incidences), 4.2), squeeze=False)
    colours = ("tab:red", "tab:green", "tab:blue")
    for ax, ti in zip(axes[0], incidences, strict=True):
        sel = sorted((r for r in rows if round(float(r["target_theta_i_deg"]), 6) == ti), key=_signed_theta_o)
        to = np.linspace(-85.0, 85.0, 341)
        wi = degrees_to_vector(ti, 0.0)
        wo = degrees_to_vector(np.abs(to), np.where(to >= 0, 180.0, 0.0))
        truth = np.asarray(material.eval(np.broadcast_to(wi, wo.shape), wo))
        x = np.array([_signed_theta_o(r) for r in sel])
        for c, (ch, colour) in enumerate(zip("rgb", colours, strict=True)):
            ax.plot(to, truth[:, c], color=colour, lw=1, alpha=0.7, label=f"model ({ch})" if c == 0 else None)
            y = np.array([float(r[f"brdf_{ch}"]) for r in sel])
            e = np.array([float(r[f"brdf_se_{ch}"]) for r in sel])
            ax.errorbar(x, y, yerr=2 * e, fmt="o", ms=3, color=colour, capsize=2,
                        label="measured (2 sigma)" if c == 0 else None)  # fmt: skip
        ax.set_yscale("log")
        ax.set_title(f"theta_i = {ti:g} deg")
        ax.set_xlabel("theta_o (deg; > 0 forward of the light)")
        ax.set_ylabel("BRDF (1/sr)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("gonio demo: rough gold on the simulated rig, measured against its model")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def agreement(rows: list[dict[str, str]], rig: RigConfig) -> tuple[float, float]:
    """Median |measured / model - 1| and the fraction of values within 3 standard errors of the model."""
    material = material_from(rig)
    wi = degrees_to_vector(np.array([float(r["theta_i_deg"]) for r in rows]),
                           np.array([float(r["phi_i_deg"]) for r in rows]))  # fmt: skip
    wo = degrees_to_vector(np.array([float(r["theta_o_deg"]) for r in rows]),
                           np.array([float(r["phi_o_deg"]) for r in rows]))  # fmt: skip
    truth = np.asarray(material.eval(wi, wo))
    got = np.array([[float(r[f"brdf_{c}"]) for c in "rgb"] for r in rows])
    se = np.array([[float(r[f"brdf_se_{c}"]) for c in "rgb"] for r in rows])
    return float(np.median(np.abs(got / truth - 1))), float(np.mean(np.abs(got - truth) <= 3 * se))


def run_demo(out: Path, *, points: int = 13, progress: bool = True) -> int:
    """Run the demo sweep into ``out/run``, write ``out/demo.png`` and print the table's head; exit code."""
    from rig.run.session import start_run

    if points < 2:
        raise CliError(f"--points {points}: expected at least 2 view angles")
    rig = demo_rig()
    sweep_table: dict[str, Any] = {
        "name": "demo in-plane slices",
        "sweep": {"kind": "in_plane", "theta_i_deg": [30.0, 60.0],
                  "theta_o_deg": [float(v) for v in np.round(np.linspace(-75.0, 75.0, points), 3)]},
        "capture": {"target_snr": 200.0},
    }  # fmt: skip
    sweep = sweep_config(parse(sweep_table, SweepFile, "<demo sweep>"), "<demo sweep>")
    run_dir = out / "run"
    if run_dir.exists():
        if not (run_dir / "manifest.json").exists():
            raise CliError(f"{run_dir} exists and is not a gonio run: refusing to replace it")
        shutil.rmtree(run_dir)
    summary = start_run(rig, sweep, run_dir, progress=progress)
    with open(summary.table, newline="") as fh:
        rows = list(csv.DictReader(fh))
    png = plot_demo(rows, rig, out / "demo.png")
    median, within = agreement(rows, rig)
    print(f"{len(rows)} BRDF samples in {summary.table}; plot: {png}")
    print(f"against the true material: median |measured/model - 1| = {median:.2%}, "
          f"{within:.0%} of values within 3 standard errors")  # fmt: skip
    print(f"{'theta_i':>8} {'theta_o':>8} {'phi_o':>7} {'brdf_r':>10} {'brdf_g':>10} {'brdf_b':>10} {'se_g':>9}")
    for r in rows[:: max(1, len(rows) // 8)]:
        print(f"{float(r['theta_i_deg']):8.2f} {float(r['theta_o_deg']):8.2f} {float(r['phi_o_deg']):7.1f} "
              f"{float(r['brdf_r']):10.4g} {float(r['brdf_g']):10.4g} {float(r['brdf_b']):10.4g} "
              f"{float(r['brdf_se_g']):9.2g}")  # fmt: skip
    return 0
