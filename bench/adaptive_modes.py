"""Adaptive sweeps in point, auto and image mode at equal budget: samples, rig time and fitted-BRDF error.

For the three materials of bench/sweep_tradeoff (rough gold, glossy plastic, matte; a flat 50 mm sample) the
simulated rig measures, end to end, an adaptive sweep (``rig.run.adaptive``) of ``--budget`` captures (the first
round 40 % of it, space-filling, then rounds of 20 %) three ways:

- point mode at rest (the anchor): every capture one 4 px ROI reading at the centre of a ``RESOLUTION`` px camera;
- ``mode = "auto"``: the first round in image mode where the camera resolves the sample into >= 16 tiles, later
  rounds in point mode at the directions the design chose;
- image mode in every round: each capture every 8 px tile of the footprint, the design weighing a candidate by
  all its tiles.

All at SNR 100 per sample (a point's reading or a tile's), references at sweep_tradeoff's adaptive SNR. Each
sweep fits the material's own model between rounds (with tiles, with their footprint's angular share, as
``gonio analyze`` fits) and its last fit is scored as sweep_tradeoff scores: the relative cosine-weighted RMS
BRDF error against the true material over 4000 pairs up to 70 deg (the shape error, after the best scale per
channel, beside it). Rig time is the simulated clock summed over the rounds; the budget is in captures, so the
modes' rig times are close but not equal, and the table shows both.

    .venv/bin/python -m bench.adaptive_modes [--quick] [--no-docs] [--seed N] [--budget N]

``--quick``: a 128 px camera instead of 256 and a budget of 20.
"""

from __future__ import annotations

import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

from analysis.batch.tradeoff import ADAPTIVE_REFERENCE_SNR, MATERIALS, MAX_THETA, SNR, Material
from bench._common import bench_parser, format_table, load_average, machine_description, markdown_table, record
from model.fit.design import ErrorPairs, brdf_error, error_pairs
from rig.run.adaptive.sweep import AdaptiveSettings, run_adaptive
from rig.run.config.files import RigConfig, material_from, parse, rig_config
from rig.run.config.schema import RigFile

#: The camera (pixels a side; --quick's) and the point ROI's side (pixels) at its centre.
RESOLUTION = 256
QUICK_RESOLUTION = 128
ROI_PX = 4
BUDGET = 40
QUICK_BUDGET = 20
MODES = ("point", "auto", "image")
#: Candidate pool before the reachability filter: enough for the budget, small enough to design quickly.
CANDIDATES = 3000
#: What a reader needs to weigh the figures (written under the table).
CAVEAT = ("Every figure is one noise realisation (one seed). The errors are all near 1e-3, and on the matte sample "
          "(shape error 0) the error is the reference calibration's scale, a few draws of the references per sweep: "
          "the error ratios there compare those draws as much as the modes, and a ratio on either side of 1 may "
          "change side with another seed (`--seed`). Samples per rig-hour are the robust figure: at a budget in "
          "captures the modes spend close rig times, and image mode's captures give a sample per tile. auto's "
          "first round is in image mode on every material here (the camera resolves the sample into far more "
          "than 16 tiles), so its samples are that round's tiles plus one per later capture.")


@dataclass
class Outcome:
    """One adaptive sweep: its rounds' modes, captures, samples, rig time (s), errors, CPU (s)."""

    mode: str
    rounds: str
    captures: int
    samples: int
    rig_time_s: float
    error: float
    shape_error: float
    cpu_s: float


def _rig(material: Material, seed: int, resolution: int) -> RigConfig:
    c = resolution // 2
    doc = {"name": "adaptive modes rig", "simulation": {"material": material.table, "seed": seed},
           "camera": {"resolution": [resolution, resolution],
                      "roi": [c - ROI_PX // 2, c - ROI_PX // 2, c + ROI_PX // 2, c + ROI_PX // 2]},
           "reference": {"every": 25, "target_snr": ADAPTIVE_REFERENCE_SNR}}  # fmt: skip
    return rig_config(parse(doc, RigFile, "<adaptive modes rig>"), "<adaptive modes rig>")


def measure(material: Material, mode: str, seed: int, resolution: int, budget: int, work: Path,
            pairs: ErrorPairs) -> Outcome:  # fmt: skip
    """One adaptive sweep of ``budget`` captures in ``mode`` on the material, scored against its truth."""
    rig = _rig(material, seed, resolution)
    initial, batch = max(2, round(0.4 * budget)), max(1, round(0.2 * budget))
    settings = AdaptiveSettings(budget=budget, initial=initial, batch=batch, candidates=CANDIDATES,
                                max_theta_deg=MAX_THETA, target_snr=SNR, reference_snr=ADAPTIVE_REFERENCE_SNR,
                                seed=seed, mode=mode)  # fmt: skip
    cpu = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = run_adaptive(rig, work / mode, material.spec, settings, pairs=pairs, log=lambda _: None)
    cpu = time.process_time() - cpu
    last = result.rounds[-1]
    truth = material_from(rig)
    names = "/".join(f"{r.mode}" + ("~" if r.motion == "continuous" else "") for r in result.rounds)
    return Outcome(mode, names, last.captures, last.samples, result.rig_time_s,
                   brdf_error(last.fit.model, truth, pairs), brdf_error(last.fit.model, truth, pairs, scale_free=True),
                   cpu)  # fmt: skip


HEAD = ["material", "mode", "rounds", "captures", "samples", "rig time (s)", "samples / rig-h", "error",
        "error / point's", "shape error", "CPU (s)"]  # fmt: skip


def table_rows(label: str, outcomes: list[Outcome]) -> list[list[str]]:
    """The table's rows for one material, each mode against point mode's."""
    anchor = next(o for o in outcomes if o.mode == "point")
    return [[label, o.mode, o.rounds, str(o.captures), str(o.samples), f"{o.rig_time_s:.0f}",
             f"{o.samples / o.rig_time_s * 3600:.3g}", f"{o.error:.4f}", f"{o.error / anchor.error:.2f}",
             f"{o.shape_error:.4f}", f"{o.cpu_s:.0f}"] for o in outcomes]  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    """Measure the three modes on every material; print the table; write the docs section."""
    parser = bench_parser(__doc__)
    parser.add_argument("--quick", action="store_true",
                        help=f"a {QUICK_RESOLUTION} px camera and a budget of {QUICK_BUDGET}")  # fmt: skip
    parser.add_argument("--budget", type=int, default=None, help=f"captures per sweep (default {BUDGET})")
    parser.add_argument("--seed", type=int, default=1, help="simulator and sweep seed (default 1)")
    args = parser.parse_args(argv)
    machine, load = machine_description(), load_average()
    print(f"{machine}\n{load} before the run", flush=True)
    resolution = QUICK_RESOLUTION if args.quick else RESOLUTION
    budget = args.budget or (QUICK_BUDGET if args.quick else BUDGET)
    pairs = error_pairs(4000, max_theta_deg=MAX_THETA)
    rows: list[list[str]] = []
    wall = time.perf_counter()
    for material in MATERIALS:
        with tempfile.TemporaryDirectory(prefix="gonio-adaptive-modes-") as tmp:
            outcomes = [measure(material, mode, args.seed, resolution, budget, Path(tmp), pairs) for mode in MODES]
        rows += table_rows(material.name, outcomes)
        print(format_table(HEAD, table_rows(material.name, outcomes)), flush=True)
    elapsed = time.perf_counter() - wall
    print("\n" + format_table(HEAD, rows))
    print(f"wall time {elapsed:.0f} s; {load_average()} after the run")
    if args.no_docs:
        return 0
    options = " --quick" if args.quick else ""
    options += f" --budget {args.budget}" if args.budget else ""
    options += f" --seed {args.seed}" if args.seed != 1 else ""
    record(
        "adaptive_modes", "Adaptive sweeps in point, auto and image mode", options,
        f"{machine}, shared with other work ({load} before the run; wall time {elapsed:.0f} s).",
        f"Each material measured end to end on the simulated rig (seed {args.seed}, one noise realisation) by an "
        f"adaptive sweep of {budget} captures (first round 40 %, then rounds of 20 %) on a {resolution} px camera: "
        f"point mode (the anchor, a {ROI_PX} px ROI per capture), auto (image first round, point after) and image "
        f"(8 px tiles every round), SNR {SNR:g} per sample, references at SNR {ADAPTIVE_REFERENCE_SNR:g}. Rounds: "
        "each round's mode. Error: the last fit's relative cosine-weighted RMS BRDF error against the true "
        f"material over 4000 pairs up to {MAX_THETA:.0f} deg (shape error: after the best scale per channel). "
        "Rig time: the simulated clock over every round. CPU: this process's seconds for the sweep (rendering, "
        "merges, fits and design).",
        markdown_table(HEAD, rows),
        CAVEAT,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
