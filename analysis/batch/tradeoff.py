"""The study of bench/sweep_tradeoff (``gonio batch study`` without files): its materials and sweep designs.

Three known materials on the simulated rig (a rough metal, a glossy plastic, a matte diffuse), each fitted
with its own model family; designs are regular grids in (theta_i, theta_o, phi_o), Rusinkiewicz
half/difference grids and the adaptive sweep of ``rig.run.adaptive.sweep`` at three capture SNRs
(analysis/batch/study.py runs each as a task, analysis/batch/study_report.py tabulates and draws them).

Every design is isotropic (phi_i = 0, phi_o in [0, 180]) and keeps both zeniths at or below ``MAX_THETA``,
the part of the hemisphere where the simulated rig's readings agree with the point model (beyond it the
ROI's footprint stretches and the light's finite distance show: see simulator/comparison.py). The error
pairs cover the same range, so no design is judged where none of them measured.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from model.fit.spec import LAMBERT, FitSpec, ggx_conductor, lambert_ggx
from rig.instrument.kinematics import solve_degrees
from rig.run.config.files import RigConfig, parse, rig_config
from rig.run.config.schema import RigFile
from rig.run.config.sweeps import half_diff_to_directions, normalise, unique_rows

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
#: Command-line names of MATERIALS, in order.
KEYS = ("metal", "plastic", "matte")
#: Captures of an adaptive sweep.
BUDGET = 100


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


def sizes(quick: bool) -> tuple[Sequence[int], Sequence[int]]:
    """Grid and Rusinkiewicz design sizes (captures) to measure."""
    if quick:
        return (30, 100, 300), (30, 100)
    return (30, 100, 300, 1000), (30, 100, 300)


