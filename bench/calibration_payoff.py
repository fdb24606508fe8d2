"""What geometry calibration buys: fitted-BRDF error on a misaligned rig, uncalibrated, calibrated, and perfect.

For each material (a glossy GGX conductor, alpha 0.05, and the glossy plastic and rough metal of
bench/sweep_tradeoff) the same grid is measured on three simulated rigs: the perfect one; one misaligned by
--misalign deg (every joint zero, the sample's tilt) and --offset mm of sample offset, measured as drawn
(no calibration); and the same rig after `gonio calibrate geometry`, whose result the rig file applies.
Each table is fitted with the material's model (effective errors, angular uncertainty included) and the
fit scored against the true material (relative, cosine-weighted RMS over error pairs, as sweep_tradeoff
does). The anchor is the perfect rig's error: the goal is calibrated / perfect <= 1.5. Beside it, how
honest the calibrated run's error bars are: the fraction of readings within 1, 2 and 3 effective errors of
the truth (a standard normal: 68.3, 95.4, 99.7 %; the binomial scatter of n readings is printed).

    .venv/bin/python -m bench.calibration_payoff
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from analysis.batch.tradeoff import GOLD, MAX_THETA, PLASTIC, Material, grid_design
from model.fit.angular import fit_with_angular
from model.fit.design import brdf_error, error_pairs
from model.fit.samples import Samples
from model.fit.spec import ggx_conductor, lambert_ggx
from rig.alignment.procedure import calibrate_geometry
from rig.run.adaptive.sweep import measure_points
from rig.run.config.files import RigConfig, material_from, parse, rig_config
from rig.run.config.schema import RigFile

GLOSSY = {"model": "CookTorrance", "alpha": 0.05, "distribution": "ggx", "fresnel": "conductor",
          "eta": [0.18, 0.42, 1.37], "k": [3.42, 2.35, 1.77]}  # fmt: skip
MATERIALS = (
    Material("glossy metal (GGX, alpha 0.05)", GLOSSY, ggx_conductor()),
    Material("glossy plastic (Lambert + GGX, alpha 0.08)", PLASTIC, lambert_ggx("dielectric")),
    Material("rough metal (GGX gold, alpha 0.2)", GOLD, ggx_conductor()),
)
SNR = 300.0


def _rig(
    material: Material, misalignment: dict[str, Any] | None, seed: int, calibration: Path | None = None
) -> RigConfig:
    # Every rig's servos settle within their encoder's count, as real ones do ("perfect" is the geometry).
    doc: dict[str, Any] = {
        "name": "payoff rig",
        "simulation": {"material": material.table, "seed": seed,
                       "misalignment": {**(misalignment or {}), "joint_settle_ticks": 1.0}},
        "camera": {"resolution": [512, 512], "roi": [254, 254, 258, 258]},
        "reference": {"every": 25, "target_snr": 1000.0},
    }
    if calibration is not None:
        doc["geometry"] = {"calibration": str(calibration)}
    return rig_config(parse(doc, RigFile, "<payoff rig>"), "<payoff rig>")


def _true_calibration(fitted: Path, path: Path, mis: dict[str, Any]) -> Path:
    """A copy of a calibration file holding the simulated rig's true geometry (errors as fitted)."""
    doc = json.loads(fitted.read_text())
    for name, value in mis.items():
        if isinstance(doc.get(name), dict) and "value" in doc[name]:
            doc[name]["value"] = value
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc))
    return path


def _score(rig: RigConfig, material: Material, rows: list[dict[str, Any]], pairs: Any) -> dict[str, Any]:
    samples = Samples.from_table_rows(rows, errors="point")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res, variance = fit_with_angular(material.spec, samples)
    truth = material_from(rig)
    exact = Samples.from_table_rows(rows, errors="readings")  # the simulated tile's albedo is exact
    pred = np.asarray(truth.eval(samples.wi, samples.wo), dtype=np.float64).reshape(samples.n, -1)
    se = np.sqrt(np.square(exact.std_error) + variance)
    z = ((samples.value - pred) / se)[~samples.lower_bound].reshape(-1)
    return {"error": brdf_error(res.model, truth, pairs), "chi2": res.reduced_chi2,
            "within": [float(np.mean(np.abs(z) <= k)) for k in (1, 2, 3)], "n_z": len(z)}  # fmt: skip


def main() -> None:
    """Measure, fit and score every material on the three rigs; print the table."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--misalign", type=float, default=0.5, help="joint zeros and sample tilt (deg)")
    p.add_argument("--offset", type=float, default=1.0, help="sample offset per axis (mm)")
    p.add_argument("--points", type=int, default=150)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--captures", type=int, default=30)
    p.add_argument("--materials", default="glossy,plastic,metal", help="comma-separated: glossy, plastic, metal")
    p.add_argument("--oracle", action="store_true",
                   help="also measure with the true geometry as the calibration: the floor calibration could reach")
    args = p.parse_args()
    keys = ("glossy", "plastic", "metal")
    wanted = [k.strip() for k in args.materials.split(",") if k.strip()]
    if not wanted or any(k not in keys for k in wanted):
        p.error(f"--materials {args.materials!r}: expected a comma-separated choice of {', '.join(keys)}")
    m = args.misalign
    mis = {"light_zero_deg": m, "camera_zero_deg": -m, "tilt_zero_deg": m, "roll_zero_deg": -m,
           "sample_tilt_deg": m, "sample_tilt_azimuth_deg": 30.0, "sample_offset_mm": [args.offset, -args.offset,
           0.5 * args.offset]}  # fmt: skip
    pairs = error_pairs(4000, max_theta_deg=MAX_THETA)
    print(f"misalignment: zeros +-{m} deg, sample tilt {m} deg, offset {args.offset} mm; {args.points}-point grid "
          f"at SNR {SNR:g}; calibration {args.captures} captures")  # fmt: skip
    print(f"  {'material':<44} {'perfect':>9} {'uncalibrated':>13} {'calibrated':>11} {'cal/perfect':>12} "
          f"{'within 1/2/3 (calibrated)':>28}")  # fmt: skip
    for k, material in enumerate(MATERIALS):
        if keys[k] not in wanted:
            continue
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp)
            start = time.perf_counter()
            perfect_rig = _rig(material, None, args.seed + k)
            pts = grid_design(perfect_rig, args.points)
            scores = {}
            rows, _ = measure_points(perfect_rig, pts, out / "perfect", SNR)
            scores["perfect"] = _score(perfect_rig, material, rows, pairs)
            bent = _rig(material, mis, args.seed + k)
            rows, _ = measure_points(bent, pts, out / "uncalibrated", SNR)
            scores["uncalibrated"] = _score(bent, material, rows, pairs)
            board_rig = rig_config(parse({"camera": {"resolution": [512, 512]}, "simulation": {
                "misalignment": {**mis, "joint_settle_ticks": 1.0}, "seed": args.seed + k}}, RigFile, "<board rig>"),
                "<board rig>")  # fmt: skip
            cal = calibrate_geometry(board_rig, out / "cal", captures=args.captures, log=lambda _: None)
            fixed = _rig(material, mis, args.seed + k, calibration=cal)
            rows, _ = measure_points(fixed, pts, out / "calibrated", SNR)
            scores["calibrated"] = _score(fixed, material, rows, pairs)
            if args.oracle:
                truth = _true_calibration(cal, out / "oracle_cal" / "geometry_calibration.json", mis)
                known = _rig(material, mis, args.seed + k, calibration=truth)
                rows, _ = measure_points(known, pts, out / "oracle", SNR)
                scores["oracle"] = _score(known, material, rows, pairs)
        c, pe = scores["calibrated"], scores["perfect"]
        n = c["n_z"]
        scatter = "/".join(f"{100 * math.sqrt(q * (1 - q) / max(n, 1)):.1f}" for q in (0.683, 0.954, 0.997))
        within = "/".join(f"{100 * w:.1f}" for w in c["within"])
        print(f"  {material.name:<44} {pe['error']:9.2e} {scores['uncalibrated']['error']:13.2e} {c['error']:11.2e} "
              f"{c['error'] / pe['error']:12.2f} {within:>16} % (+-{scatter}, n {n}) "
              f"[{time.perf_counter() - start:.0f} s]", flush=True)  # fmt: skip
        if "oracle" in scores:
            o = scores["oracle"]
            print(f"  {'  ... with the true geometry (oracle)':<44} {'':9} {'':13} {o['error']:11.2e} "
                  f"{o['error'] / pe['error']:12.2f} {'/'.join(f'{100 * w:.1f}' for w in o['within']):>16} %, "
                  f"chi2/dof {o['chi2']:.2f}", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
