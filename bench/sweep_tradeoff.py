"""The headline trade: fitted-BRDF error against captures and rig time, for four ways to sweep.

Three known materials on the simulated rig (a rough metal, a glossy plastic, a matte diffuse). For each,
every design is run end to end (servos on the pty, Mitsuba camera, HDR merge, reference calibration), its
table is fitted with the material's own model family, and the fit is scored against the truth: the
relative, cosine-weighted RMS BRDF error over 4000 pairs up to 70 deg (``model.fit.design.brdf_error``).

Every design is measured with several simulator seeds (``--seeds``, default 3): each seed is a fresh noise
realisation of every frame, reference readings included, and a fresh candidate pool for the adaptive
sweep; the tables show the mean over seeds. One seed alone is a coin toss at these error levels.

Designs: regular grids in (theta_i, theta_o, phi_o), from sparse (30) to dense (~1000, the anchor);
Rusinkiewicz half/difference grids with theta_h spaced quadratically (dense at the specular peak); and
the adaptive sweep of ``rig.run.adaptive.sweep`` (20 space-filling captures, then rounds of 10 chosen where the
current fit's expected BRDF error falls most), scored after every round, at capture SNRs of 100, 300 and
500. Goal: the adaptive sweep reaches the dense grid's error with at most 100 captures.

Rig time is the simulated clock: moves at the servos' programmed speeds, settling, exposures, reference
readings. Each adaptive round is its own run, with its own references before and after.

The study runs through ``gonio batch study`` (analysis/batch/study.py): every design x material x seed is one
task on a local Dask cluster (``--workers``; ``--scheduler`` for an existing one; ``--serial`` in this
process), and the numbers do not depend on where a task ran. With ``--out DIR`` a stopped study resumes.

Run: ``.venv/bin/python -m bench.sweep_tradeoff [--quick] [--seeds N] [--first-seed K] [--materials ...]
[--no-write] [--serial | --workers N | --scheduler ADDRESS] [--out DIR]`` (about 4 minutes of CPU per seed and
material set; ``--quick --seeds 1`` about 2). Prints a table per material and, per seed, whether each adaptive
variant ended at or below that seed's dense grid; with every material, writes the ``sweep_tradeoff`` section of
docs/benchmarks.md and docs/figures/sweep_tradeoff.png.
"""

from __future__ import annotations

import argparse
import datetime
import shutil
import sys
import tempfile
import time
from pathlib import Path

from analysis.batch.cluster import ClusterSettings
from analysis.batch.study import run_study, tradeoff_cells
from analysis.batch.study_report import markdown_report, text_report
from analysis.batch.tradeoff import ADAPTIVE_REFERENCE_SNR, KEYS, MAX_THETA, REFERENCE_SNR
from bench._common import BENCHMARKS_MD, machine_description, write_section

ROOT = Path(__file__).resolve().parent.parent
FIGURE = ROOT / "docs" / "figures" / "sweep_tradeoff.png"


def main(argv: list[str] | None = None) -> int:
    """Run the trade for every material; print tables, write the docs section and the figure."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer and smaller designs (a smoke run)")
    ap.add_argument("--no-write", action="store_true", help="print only; leave docs/ alone")
    ap.add_argument("--seeds", type=int, default=3, help="noise realisations averaged (default 3)")
    ap.add_argument("--first-seed", type=int, default=1, help="first simulator seed (default 1): more seeds later")
    ap.add_argument("--materials", nargs="+", choices=list(KEYS), default=list(KEYS),
                    help="materials to run (default all; docs/ is written only for all)")  # fmt: skip
    ap.add_argument("--serial", action="store_true", help="run every task in this process, one after the other")
    ap.add_argument("--workers", type=int, help="workers of the local Dask cluster (default: the cores)")
    ap.add_argument("--scheduler", metavar="ADDRESS", help="run on this Dask scheduler instead")
    ap.add_argument("--out", type=Path, help="keep the study here (resumable); default a temporary directory")
    args = ap.parse_args(argv)
    command = " ".join(["python -m bench.sweep_tradeoff", *(sys.argv[1:] if argv is None else argv)])
    write = not args.no_write and len(set(args.materials)) == len(KEYS)
    cells = tradeoff_cells(args.materials, range(args.first_seed, args.first_seed + args.seeds), quick=args.quick)
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        result = run_study(cells, out, serial=args.serial, cluster=ClusterSettings(args.scheduler, args.workers),
                           log=lambda line: print(line, file=sys.stderr, flush=True))  # fmt: skip
        elapsed = time.perf_counter() - t_start
        print(text_report(result.results, result.verdicts))
        print(result.summary())
        print(f"wall time {elapsed:.0f} s")
        if result.failed:
            print("\n".join(f"failed: {k}: {e}" for k, e in result.failed.items()), file=sys.stderr)
            return 1
        if write:
            FIGURE.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(result.files["figure"], FIGURE)
            print(f"figure: {FIGURE}")
    if write:
        where = "in this process" if args.serial else "on " + (args.scheduler or "a local Dask cluster")
        body = (
            f"Measured {datetime.date.today()} on {machine_description()}"
            f"{' (--quick)' if args.quick else ''}; `{command}` ({len(cells)} tasks {where}), wall time "
            f"{elapsed:.0f} s. Error: relative cosine-weighted RMS BRDF error of the fit against the true "
            f"material over 4000 pairs up to {MAX_THETA:.0f} deg (shape error: after the best scale per channel, "
            f"i.e. without the calibration's share), mean over {args.seeds} simulator seeds. Grid points at SNR "
            f"100 in the dimmest channel, references at SNR {REFERENCE_SNR:g} every 25 points (each an "
            f"independent draw); the adaptive sweep's references at SNR {ADAPTIVE_REFERENCE_SNR:g} (its ~18 "
            "readings calibrate as well as the dense grid's 42); fits weighted by each capture's own reading "
            "error; a 4-pixel ROI of a 512-pixel view (0.05 deg).\n\n"
            + markdown_report(result.results, result.verdicts)
            + "\n![error against captures and rig time](figures/sweep_tradeoff.png)\n"
        )  # fmt: skip
        write_section(BENCHMARKS_MD, "sweep_tradeoff", body)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
