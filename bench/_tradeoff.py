"""Helpers of ``bench.sweep_tradeoff``: the materials, the sweep designs of a given size, one measured fit, the plot.

Every design is isotropic (phi_i = 0, phi_o in [0, 180]) and keeps both zeniths at or below ``MAX_THETA``,
the part of the hemisphere where the simulated rig's readings agree with the point model (beyond it the
ROI's footprint stretches and the light's finite distance show: see simulator/comparison.py). The error
pairs cover the same range, so no design is judged where none of them measured.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from model.fit.design import ErrorPairs, brdf_error
from model.fit.samples import Samples
from model.fit.solve import fit
from model.fit.spec import LAMBERT, FitSpec, ggx_conductor, lambert_ggx
from rig.instrument.kinematics import solve_degrees
from rig.run.adaptive import measure_points
from rig.run.config import RigConfig, material_from, parse, rig_config
from rig.run.config_schema import RigFile
from rig.run.sweeps import half_diff_to_directions, normalise, unique_rows

FloatArray = npt.NDArray[np.float64]
MAX_THETA = 70.0
SNR = 100.0
#: Reference readings at a higher SNR than the points: they calibrate every point between them.
REFERENCE_SNR = 1000.0
#: The adaptive sweep's references: its rounds are short runs, ~18 readings in all against the dense grid's 42
#: (one every 25 points), so it reads them at REFERENCE_SNR * sqrt(42 / 18) to calibrate as well.
ADAPTIVE_REFERENCE_SNR = 1500.0
#: The adaptive sweep at three capture SNRs (labels and goals): rig time is mostly moves, so SNR is cheap.
ADAPTIVE_VARIANTS = (("adaptive", 100.0), ("adaptive SNR 300", 300.0), ("adaptive SNR 500", 500.0))

GOLD = {"model": "CookTorrance", "alpha": 0.2, "distribution": "ggx", "fresnel": "conductor",
        "eta": [0.18, 0.42, 1.37], "k": [3.42, 2.35, 1.77]}  # fmt: skip
PLASTIC = {"model": "CookTorrance", "rho_d": [0.5, 0.12, 0.08], "alpha": 0.08, "distribution": "ggx",
           "fresnel": "dielectric", "eta": 1.5}  # fmt: skip
MATTE = {"model": "Lambert", "rho_d": [0.6, 0.55, 0.45]}


@dataclass(frozen=True)
class Material:
    """A simulated material, the spec fitted to it, and a label."""

    name: str
    table: dict[str, Any]
    spec: FitSpec


MATERIALS = (
    Material("rough metal (GGX gold, alpha 0.2)", GOLD, ggx_conductor()),
    Material("glossy plastic (Lambert + GGX, alpha 0.08)", PLASTIC, lambert_ggx("dielectric")),
    Material("matte diffuse (Lambert)", MATTE, LAMBERT),
)


def rig_for(material: Material, seed: int = 1) -> RigConfig:
    """The simulated rig with this material, a 4x4-pixel ROI and high-SNR references every 25 points.

    The ROI is 4 pixels of a 512-pixel view of the 5 cm sample (0.4 mm, 0.05 deg from 0.5 m). The reading
    averages the BRDF over the ROI's footprint, and the fit's point model does not: at 32 pixels (0.7 deg)
    the glossy plastic's peak read up to 6 % low; at 128 pixels its grazing peaks (theta_d > 45 deg) still
    read 0.2-0.8 % low, which is 2 sigma at SNR 300, and exactly where an adaptive sweep looks.
    """
    doc = {
        "name": "tradeoff rig",
        "simulation": {"material": material.table, "seed": seed},
        "camera": {"resolution": [512, 512], "roi": [254, 254, 258, 258]},
        "reference": {"every": 25, "target_snr": REFERENCE_SNR},
    }
    return rig_config(parse(doc, RigFile, "<tradeoff rig>"), "<tradeoff rig>")


def _reachable(rig: RigConfig, pts: FloatArray) -> FloatArray:
    pts = normalise(pts)
    pts = pts[unique_rows(pts)]
    ok = np.asarray(solve_degrees(rig.geometry, pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 3]).reachable, dtype=bool)
    return pts[ok]


def grid_design(rig: RigConfig, n: int) -> FloatArray:
    """The regular grid in (theta_i, theta_o, phi_o) whose reachable size is closest to n, (N, 4) degrees."""
    best: FloatArray | None = None
    for ki, kp in itertools.product(range(2, 16), range(1, 14)):
        if best is not None and abs(ki * ki * kp - n) > 2 * abs(len(best) - n) + 50:
            continue
        th = np.linspace(0.0, MAX_THETA, ki)
        phi = np.linspace(0.0, 180.0, kp) if kp > 1 else np.array([180.0])
        pts = np.array([(a, 0.0, b, c) for a in th for b in th for c in phi])
        pts = _reachable(rig, pts)
        if best is None or abs(len(pts) - n) < abs(len(best) - n):
            best = pts
    assert best is not None
    return best


def rusinkiewicz_design(rig: RigConfig, n: int) -> FloatArray:
    """A half/difference grid, theta_h spaced quadratically (MERL's), closest to n reachable pairs, degrees."""
    best: FloatArray | None = None
    for kh, kd, kp in itertools.product(range(3, 20), range(2, 12), range(1, 8)):
        if kh * kd * kp < 0.5 * n or kh * kd * kp > 4 * n:
            continue
        th = 90.0 * (np.arange(kh) / kh) ** 2
        td = np.linspace(0.0, MAX_THETA, kd)
        pd = np.linspace(0.0, 180.0, kp + 1)[1:] if kp > 1 else np.array([90.0])
        combos = np.array(list(itertools.product(th, td, pd)))
        rows = half_diff_to_directions(combos[:, 0], combos[:, 1], combos[:, 2], np.zeros(len(combos)))
        rows = rows[(rows[:, 0] <= MAX_THETA) & (rows[:, 2] <= MAX_THETA)]
        # Turned about the normal to phi_i = 0 and folded to phi_o in [0, 180]: the isotropic equivalent.
        dphi = (rows[:, 3] - rows[:, 1]) % 360.0
        rows = np.stack([rows[:, 0], np.zeros(len(rows)), rows[:, 2], np.minimum(dphi, 360.0 - dphi)], axis=-1)
        pts = _reachable(rig, rows)
        if best is None or abs(len(pts) - n) < abs(len(best) - n):
            best = pts
    assert best is not None
    return best


@dataclass(frozen=True)
class Outcome:
    """One design measured and fitted: captures, rig time (s), relative BRDF error (total, shape), chi2/dof."""

    strategy: str
    captures: int
    rig_time_s: float
    error: float
    shape_error: float
    reduced_chi2: float


def measure_and_fit(rig: RigConfig, material: Material, strategy: str, pts: FloatArray, out: Path,
                    pairs: ErrorPairs) -> Outcome:  # fmt: skip
    """Run the design on the simulated rig into ``out``, fit the material's spec, and score the fit."""
    import warnings

    rows, rig_time_s = measure_points(rig, pts, out, SNR)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = fit(material.spec, Samples.from_table_rows(rows, source=str(out), errors="point"), starts=4, warn=False)
    truth = material_from(rig)
    err, shape = brdf_error(res.model, truth, pairs), brdf_error(res.model, truth, pairs, scale_free=True)
    return Outcome(strategy, len(rows), rig_time_s, err, shape, res.reduced_chi2)


def plot(results: dict[str, list[Outcome]], goal: dict[str, float], path: Path) -> Path:
    """Error against captures (top) and rig hours (bottom), one column per material; writes a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(results)
    fig, axes = plt.subplots(2, len(names), figsize=(5.0 * len(names), 7.5), squeeze=False)
    styles: dict[str, tuple[str, str]] = {
        "grid": ("o-", "tab:blue"),
        "rusinkiewicz": ("s-", "tab:green"),
        "adaptive": ("D-", "tab:red"),
        "adaptive SNR 300": ("^-", "tab:purple"),
        "adaptive SNR 500": ("v-", "tab:brown"),
    }
    for col, name in enumerate(names):
        for row, key in enumerate(("captures", "rig_time_s")):
            ax = axes[row][col]
            for strat, (fmt, colour) in styles.items():
                pts = sorted((o for o in results[name] if o.strategy == strat), key=lambda o: o.captures)
                if not pts:
                    continue
                x = [o.captures if key == "captures" else o.rig_time_s / 3600.0 for o in pts]
                ax.plot(x, [o.error for o in pts], fmt, color=colour, ms=4, label=strat)
            ax.axhline(goal[name], color="0.4", ls=":", lw=1, label="dense grid (~1000)")
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_xlabel("captures" if key == "captures" else "rig time (h)")
            ax.set_ylabel("relative BRDF error")
            ax.grid(True, which="both", alpha=0.3)
            if row == 0:
                ax.set_title(name, fontsize=10)
        axes[0][col].legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def sizes(quick: bool) -> tuple[Sequence[int], Sequence[int]]:
    """Grid and Rusinkiewicz design sizes (captures) to measure."""
    if quick:
        return (30, 100, 300), (30, 100)
    return (30, 100, 300, 1000), (30, 100, 300)


def mean_outcomes(runs: Sequence[Sequence[Outcome]]) -> list[Outcome]:
    """Outcomes averaged over repeated runs (noise realisations), matched by design and captures."""
    groups: dict[tuple[str, int], list[Outcome]] = {}
    for run in runs:
        for o in run:
            groups.setdefault((o.strategy, o.captures), []).append(o)
    return [Outcome(k[0], k[1], *(float(np.mean([getattr(o, f) for o in g]))
                                  for f in ("rig_time_s", "error", "shape_error", "reduced_chi2")))
            for k, g in groups.items()]  # fmt: skip
