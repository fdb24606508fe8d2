"""Geometry calibration recovery: random misaligned rigs, what `gonio calibrate geometry` finds, and its dials.

For each random simulated rig (joint zeros up to --max-zero deg, sample tilt up to --max-tilt deg, offsets
up to --max-offset mm per axis) the calibration runs on the simulated board and its estimates are set
against the hidden truth: the error, and the error in units of the reported standard error (z). Printed:
per rig; the fraction of |z| <= 3 per quantity and overall (the goal: every quantity within 3 standard
errors); the largest joint-zero and tilt errors (goal: 0.02 deg); the capture count and the rig time it
took. With --dial, the same over captures and coat roughness (the speed-accuracy dial). The anchor is the
calibration's own reported uncertainty: a ratio of RMS z to 1 near 1 means honest error bars.

    .venv/bin/python -m bench.geometry_calibration --rigs 20
    .venv/bin/python -m bench.geometry_calibration --rigs 6 --dial
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
from typing import Any

import numpy as np

from rig.alignment.procedure import calibrate_geometry
from rig.run.config import parse, rig_config
from rig.run.config_schema import RigFile

SCALARS = ("light_zero_deg", "camera_zero_deg", "tilt_zero_deg", "roll_zero_deg", "sample_tilt_deg",
           "sample_tilt_azimuth_deg")  # fmt: skip


def random_misalignment(
    rng: np.random.Generator, max_zero: float, max_tilt: float, max_offset: float
) -> dict[str, Any]:
    """A random rig: zeros uniform in +-max_zero, tilt uniform in [0.2, max_tilt], offsets in +-max_offset."""
    return {
        "light_zero_deg": float(rng.uniform(-max_zero, max_zero)),
        "camera_zero_deg": float(rng.uniform(-max_zero, max_zero)),
        "tilt_zero_deg": float(rng.uniform(-max_zero, max_zero)),
        "roll_zero_deg": float(rng.uniform(-max_zero, max_zero)),
        "sample_tilt_deg": float(rng.uniform(0.2, max_tilt)),
        "sample_tilt_azimuth_deg": float(rng.uniform(-180, 180)),
        "sample_offset_mm": [float(v) for v in rng.uniform(-max_offset, max_offset, 3)],
    }


def _wrap(deg: float) -> float:
    return (deg + 180.0) % 360.0 - 180.0


def run_one(mis: dict[str, Any], seed: int, captures: int, alpha: float, resolution: int, spp: int) -> dict[str, Any]:
    """Calibrate one simulated rig; errors and z per quantity, captures, wall and rig time."""
    doc = {"camera": {"resolution": [resolution, resolution], "spp": spp},
           "simulation": {"misalignment": mis, "seed": seed}}  # fmt: skip
    rig = rig_config(parse(doc, RigFile, "bench-rig.toml"), "bench-rig.toml")
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as out:
        path = calibrate_geometry(rig, out, captures=captures, alpha=alpha, log=lambda _: None)
        cal = json.loads(path.read_text())
    wall = time.perf_counter() - start
    errors, z = {}, {}
    for name in SCALARS:
        err = cal[name]["value"] - mis[name]
        err = _wrap(err) if name == "sample_tilt_azimuth_deg" else err
        errors[name], z[name] = err, err / max(cal[name]["std_error"], 1e-300)
    for i, axis in enumerate("xyz"):
        err = cal["sample_offset_mm"]["value"][i] - mis["sample_offset_mm"][i]
        errors[f"offset_{axis}_mm"], z[f"offset_{axis}_mm"] = (
            err,
            err / max(cal["sample_offset_mm"]["std_error"][i], 1e-300),
        )
    return {"errors": errors, "z": z, "wall_s": wall, "reduced_chi2": cal["residuals"]["reduced_chi2"],
            "warnings": cal["warnings"]}  # fmt: skip


def study(
    rigs: int, captures: int, alpha: float, resolution: int, spp: int, args: argparse.Namespace
) -> dict[str, Any]:
    """Calibrate ``rigs`` random rigs; per quantity the fraction within 3 SE, RMS z and the largest error."""
    rng = np.random.default_rng(args.seed)
    results = []
    for k in range(rigs):
        mis = random_misalignment(rng, args.max_zero, args.max_tilt, args.max_offset)
        r = run_one(mis, args.seed * 1000 + k, captures, alpha, resolution, spp)
        results.append(r)
        worst = max(r["z"], key=lambda n: abs(r["z"][n]))
        print(f"  rig {k:2d}: max |z| {abs(r['z'][worst]):4.2f} ({worst}), zeros err (deg) "
              + ", ".join(f"{r['errors'][n]:+.4f}" for n in SCALARS[:4])
              + f", tilt err {r['errors']['sample_tilt_deg']:+.4f}, chi2/dof {r['reduced_chi2']:.2f}, "
              f"{r['wall_s']:.0f} s",
              flush=True)  # fmt: skip
    names = list(results[0]["z"])
    summary = {}
    for n in names:
        zs = np.array([r["z"][n] for r in results])
        es = np.array([r["errors"][n] for r in results])
        summary[n] = {
            "within_3se": float(np.mean(np.abs(zs) <= 3)), "rms_z": float(np.sqrt(np.mean(zs**2))),
            "max_abs_error": float(np.max(np.abs(es))), "rms_error": float(np.sqrt(np.mean(es**2))),
        }  # fmt: skip
    return {"summary": summary, "wall_s": float(np.mean([r["wall_s"] for r in results]))}


def _print(summary: dict[str, Any]) -> None:
    print(f"  {'quantity':<26} {'within 3 SE':>11} {'RMS z':>7} {'RMS error':>10} {'max |error|':>12}")
    for n, s in summary["summary"].items():
        print(
            f"  {n:<26} {100 * s['within_3se']:10.0f}% {s['rms_z']:7.2f} {s['rms_error']:10.5f} "
            f"{s['max_abs_error']:12.5f}"
        )
    zeros = max(summary["summary"][n]["max_abs_error"] for n in SCALARS[:4])
    print(f"  largest joint-zero error {zeros:.4f} deg, largest tilt error "
          f"{summary['summary']['sample_tilt_deg']['max_abs_error']:.4f} deg (goal 0.02); "
          f"RMS z over all / 1 (anchor: honest errors) = "
          f"{math.sqrt(np.mean([s['rms_z'] ** 2 for s in summary['summary'].values()])):.2f}; "
          f"mean wall time per calibration {summary['wall_s']:.1f} s")  # fmt: skip


def main() -> None:
    """Run the study (and the dial with --dial) and print the tables."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rigs", type=int, default=20)
    p.add_argument("--captures", type=int, default=24)
    p.add_argument("--alpha", type=float, default=0.01, help="the board coat's GGX roughness")
    p.add_argument("--resolution", type=int, default=480)
    p.add_argument("--spp", type=int, default=4)
    p.add_argument("--max-zero", type=float, default=1.0)
    p.add_argument("--max-tilt", type=float, default=1.0)
    p.add_argument("--max-offset", type=float, default=2.0)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--dial", action="store_true", help="also vary captures and coat roughness")
    args = p.parse_args()
    print(f"geometry calibration on {args.rigs} random rigs: {args.captures} captures, coat alpha {args.alpha}, "
          f"{args.resolution}^2 px, spp {args.spp}")  # fmt: skip
    _print(study(args.rigs, args.captures, args.alpha, args.resolution, args.spp, args))
    if args.dial:
        for captures in (12, 18, 30):
            print(f"\ncaptures {captures}:")
            _print(study(args.rigs, captures, args.alpha, args.resolution, args.spp, args))
        for alpha in (0.001, 0.003, 0.03):
            print(f"\ncoat alpha {alpha}:")
            _print(study(args.rigs, args.captures, alpha, args.resolution, args.spp, args))


if __name__ == "__main__":
    main()
