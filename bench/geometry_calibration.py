"""Geometry calibration recovery: random misaligned rigs, what `gonio calibrate geometry` finds, and its dials.

For each random simulated rig (joint zeros up to --max-zero deg, sample tilt up to --max-tilt deg, offsets
up to --max-offset mm per axis) the calibration runs on the simulated board and its estimates are set
against the hidden truth: the error, and the error in units of the reported standard error (z). Printed:
per rig; the fraction of |z| <= 3 per quantity and overall (the goal: every quantity within 3 standard
errors); the largest joint-zero and tilt errors (goal: 0.02 deg); the capture count and the rig time it
took. With --dial, the same over captures and coat roughness (the speed-accuracy dial). The anchor is the
calibration's own reported uncertainty: a ratio of RMS z to 1 near 1 means honest error bars.

With --rehearsal dynamixel|grbl the calibration runs as on a lab's rig instead of in this process: each
random rig is written as a simulated rig file, served by ``gonio sim rig --link ... --write-rig`` (virtual
servos or GRBL on a pty, a tethering program writing whole-sensor DNG frames), and calibrated by ``gonio
calibrate geometry --rig <written rig>`` in a separate process, through the folder camera, with the board
mounted when it asks (the operator of tests/rehearsal/harness.py). The board's coat is then the
rehearsal's (GGX alpha 0.01, what ``scene board`` mounts). --rig FILE calibrates that simulated rig file
(e.g. examples/rig_misaligned.toml) instead of random ones, its [simulation.misalignment] the truth.

    .venv/bin/python -m bench.geometry_calibration --rigs 20
    .venv/bin/python -m bench.geometry_calibration --rigs 6 --dial
    .venv/bin/python -m bench.geometry_calibration --rigs 20 --rehearsal dynamixel
    .venv/bin/python -m bench.geometry_calibration --rigs 1 --rig examples/rig_misaligned.toml --rehearsal grbl
"""

from __future__ import annotations

import argparse
import json
import math
import tempfile
import time
import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from bench._common import load_average, machine_description
from rig.alignment.procedure import calibrate_geometry
from rig.run.config.files import load_rig
from tests.rehearsal.harness import Operator, Rehearsal

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


def rig_doc(mis: dict[str, Any], seed: int, resolution: int, spp: int) -> dict[str, Any]:
    """The simulated rig file (as a TOML document) of one random rig."""
    return {"name": f"bench rig {seed}", "camera": {"resolution": [resolution, resolution], "spp": spp},
            "simulation": {"seed": seed, "misalignment": mis}}  # fmt: skip


def _toml_value(value: Any) -> str:
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string of plain text is a TOML basic string
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    return repr(float(value)) if isinstance(value, float) else str(value)


def toml_text(doc: dict[str, Any], prefix: str = "") -> str:
    """A nested dict of strings, numbers and lists as TOML text (the rig files' subset of TOML)."""
    lines = [f"{k} = {_toml_value(v)}" for k, v in doc.items() if not isinstance(v, dict)]
    for k, v in doc.items():
        if isinstance(v, dict):
            name = f"{prefix}{k}"
            lines += ["", f"[{name}]", toml_text(v, name + ".")]
    return "\n".join(lines).strip("\n") + "\n"


def truth_of(path: Path) -> dict[str, Any]:
    """A simulated rig file's [simulation.misalignment] with every quantity the calibration reports (default 0)."""
    mis = tomllib.loads(path.read_text()).get("simulation", {}).get("misalignment", {})
    return {**dict.fromkeys(SCALARS, 0.0), "sample_offset_mm": [0.0, 0.0, 0.0],
            **{k: v for k, v in mis.items() if k in SCALARS or k == "sample_offset_mm"}}  # fmt: skip


def calibrate_in_process(rig_file: Path, captures: int, alpha: float) -> tuple[dict[str, Any], float]:
    """``calibrate_geometry`` on the simulated rig of ``rig_file`` in this process; the calibration, wall s."""
    rig = load_rig(rig_file)
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as out:
        path = calibrate_geometry(rig, out, captures=captures, alpha=alpha, log=lambda _: None)
        cal = json.loads(path.read_text())
    return cal, time.perf_counter() - start


def calibrate_rehearsed(rig_file: Path, work: Path, link: str, captures: int, alpha: float,
                        speed: float) -> tuple[dict[str, Any], float, float]:  # fmt: skip
    """``gonio calibrate geometry`` against ``gonio sim rig`` of ``rig_file`` on ``link``.

    Returns the calibration, the calibrating command's wall seconds, and the wall seconds with the
    rehearsal's start (Mitsuba's scene load; a lab's rig being switched on) and stop.
    """
    written, out = work / "controller_rig.toml", work / "calibration"
    begin = time.perf_counter()
    args = ("--rig", str(rig_file.resolve()), "--link", link, "--speed", f"{speed:g}", "--write-rig", str(written))
    with Rehearsal(args, work / "frames") as reh:
        start = time.perf_counter()
        done = Operator(reh, work).run("calibrate", "geometry", "--rig", str(written), "--out", str(out),
                                       "--captures", str(captures), "--alpha", f"{alpha:g}", "--quiet")  # fmt: skip
        wall = time.perf_counter() - start
    total = time.perf_counter() - begin
    if done.status != 0:
        raise RuntimeError(f"gonio calibrate geometry ended with status {done.status}:\n{done.output[-3000:]}")
    return json.loads((out / "geometry_calibration.json").read_text()), wall, total


def run_one(mis: dict[str, Any], rig_file: Path, captures: int, alpha: float,
            args: argparse.Namespace) -> dict[str, Any]:  # fmt: skip
    """Calibrate the simulated rig of ``rig_file`` (misalignment ``mis``); errors and z per quantity, wall time."""
    if args.rehearsal:
        cal, wall, total = calibrate_rehearsed(rig_file, rig_file.parent, args.rehearsal, captures, alpha,
                                               args.speed)  # fmt: skip
    else:
        cal, wall = calibrate_in_process(rig_file, captures, alpha)
        total = wall
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
    return {"errors": errors, "z": z, "wall_s": wall, "total_s": total,
            "reduced_chi2": cal["residuals"]["reduced_chi2"], "warnings": cal["warnings"]}  # fmt: skip


def study(
    rigs: int, captures: int, alpha: float, resolution: int, spp: int, args: argparse.Namespace
) -> dict[str, Any]:
    """Calibrate ``rigs`` random rigs; per quantity the fraction within 3 SE, RMS z and the largest error."""
    rng = np.random.default_rng(args.seed)
    results, failed = [], 0
    for k in range(rigs):
        mis = random_misalignment(rng, args.max_zero, args.max_tilt, args.max_offset)
        with tempfile.TemporaryDirectory(prefix="gonio-geometry-bench-") as work:
            # The rig file goes into the work folder: the rehearsal's frames and the calibration go beside it.
            rig_file = Path(work) / "simulated_rig.toml"
            if args.rig:
                rig_file.write_text(Path(args.rig).read_text())
                mis = truth_of(rig_file)
            else:
                rig_file.write_text(toml_text(rig_doc(mis, args.seed * 1000 + k, resolution, spp)))
            try:
                r = run_one(mis, rig_file, captures, alpha, args)
            except RuntimeError as exc:  # a calibration that fails is counted, and the study goes on
                failed += 1
                print(f"  rig {k:2d}: FAILED: {exc}", flush=True)
                continue
        results.append(r)
        worst = max(r["z"], key=lambda n: abs(r["z"][n]))
        print(f"  rig {k:2d}: max |z| {abs(r['z'][worst]):4.2f} ({worst}), zeros err (deg) "
              + ", ".join(f"{r['errors'][n]:+.4f}" for n in SCALARS[:4])
              + f", tilt err {r['errors']['sample_tilt_deg']:+.4f}, chi2/dof {r['reduced_chi2']:.2f}, "
              f"{r['wall_s']:.0f} s" + (f" ({r['total_s']:.0f} s with the rehearsal's start and stop)"
                                        if args.rehearsal else ""),
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
    return {"summary": summary, "wall_s": float(np.mean([r["wall_s"] for r in results])), "failed": failed,
            "total_s": float(np.mean([r["total_s"] for r in results])), "rigs": rigs}  # fmt: skip


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
          f"mean wall time per calibration {summary['wall_s']:.1f} s ({summary['total_s']:.1f} s a rig in all); "
          f"{summary['failed']} of {summary['rigs']} calibrations failed")  # fmt: skip


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
    p.add_argument(
        "--rehearsal",
        choices=("dynamixel", "grbl"),
        help="calibrate through gonio sim rig on this link and the folder camera (separate processes)",
    )
    p.add_argument("--speed", type=float, default=50.0, help="the rehearsal's time factor (default 50)")
    p.add_argument("--rig", help="a simulated rig file to calibrate instead of random rigs (give --rigs 1)")
    args = p.parse_args()
    if args.rehearsal and args.alpha != 0.01:
        p.error("--rehearsal: the board the rehearsal mounts has a coat of alpha 0.01; leave --alpha at 0.01")
    if args.rig and args.dial:
        p.error("--dial varies random rigs; it does not take --rig")
    what = args.rig or f"{args.rigs} random rigs"
    how = f"through the rehearsal on {args.rehearsal} (time x{args.speed:g})" if args.rehearsal else "in process"
    print(f"geometry calibration of {what} {how}: {args.rigs} calibrations, {args.captures} captures, coat alpha "
          f"{args.alpha}" + ("" if args.rig else f", {args.resolution}^2 px, spp {args.spp}"))  # fmt: skip
    print(f"  on {machine_description()}; {load_average()}")
    _print(study(args.rigs, args.captures, args.alpha, args.resolution, args.spp, args))
    print(f"  {load_average()} at the end")
    if args.dial:
        for captures in (12, 18, 30):
            print(f"\ncaptures {captures}:")
            _print(study(args.rigs, captures, args.alpha, args.resolution, args.spp, args))
        for alpha in (0.001, 0.003, 0.03):
            print(f"\ncoat alpha {alpha}:")
            _print(study(args.rigs, args.captures, alpha, args.resolution, args.spp, args))


if __name__ == "__main__":
    main()
