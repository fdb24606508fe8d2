"""``gonio batch analyze`` and ``gonio batch study``: many analyses or a simulation study as tasks on a Dask cluster.

A local cluster by default (one worker per core, nothing to set up); ``--scheduler ADDRESS`` uses a running
one. Progress goes to stderr (a bar with tasks done and the ETA, and the dashboard's address when one runs);
stdout gets the catalogue's or the study's paths and a one-line summary. Exit codes: 0 every input done, 2 bad
input (including any input that failed: the catalogue names each with its error), 130 interrupted (what
finished is kept; the same command again does the rest).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING

from gonio.cli_analyze import add_fit_options
from gonio.cli_errors import CliError
from gonio.cli_options import add_command, add_quiet_option, positive_count
from gonio.cli_run import EXIT_BAD_INPUT, EXIT_OK

if TYPE_CHECKING:  # imported for real inside the commands: Dask and scipy would slow every gonio command
    from analysis.batch.cluster import ClusterSettings

_CLUSTER_HELP = (
    "Dask scheduler to run on, e.g. tcp://10.0.0.5:8786 (started with `dask scheduler`, workers with "
    "`dask worker tcp://10.0.0.5:8786` on each machine, or by dask-jobqueue on SLURM); every path must then be "
    "the same on every worker (a shared file system). Default: a local cluster of one worker per core"
)


def _log(quiet: bool) -> Callable[[str], None]:
    return (lambda _: None) if quiet else (lambda line: print(line, file=sys.stderr, flush=True))


def _cluster(args: argparse.Namespace) -> ClusterSettings:
    from analysis.batch.cluster import ClusterSettings

    return ClusterSettings(scheduler=args.scheduler, workers=args.workers, dashboard=not args.no_dashboard)


def _batch_analyze(args: argparse.Namespace) -> int:
    """fit, report and export every input as gonio analyze would, and catalogue them

    Analyse each run directory or MERL .binary file as one task: OUT/<name> holds exactly what `gonio analyze INPUT
    --out OUT/<name>` writes (the same bytes for the same inputs and seed), OUT/catalogue.parquet one row per input
    (chosen model, parameters and errors, goodness of fit, the run's metadata, the paths of its outputs; failed inputs
    with their error). --samples applies to MERL inputs. Exit codes: 0 all done, 2 bad input or any input failed, 130
    interrupted.

    Example: gonio batch analyze runs/* library/*.binary --out batch/2024-06 --models lambert,lambert_ggx,ggx_conductor;
    again after a stop, it does only what is left
    """
    from analysis.batch.analyze_batch import batch_analyze
    from analysis.batch.inputs import AnalyzeSettings

    settings = AnalyzeSettings(models=args.models, loss=args.loss, starts=args.starts, samples=args.samples,
                               seed=args.seed, compare=args.compare, y_scale=args.y_scale, merl=args.merl,
                               errors=args.errors, svg=args.svg)  # fmt: skip
    result = batch_analyze(args.sources, args.out, settings, cluster=_cluster(args), progress=not args.quiet,
                           log=_log(args.quiet))  # fmt: skip
    print(result.catalogue)
    print(result.summary())
    for key, error in result.failed.items():
        print(f"failed: {key}: {error}", file=sys.stderr)
    return EXIT_BAD_INPUT if result.failed else EXIT_OK


def _batch_study(args: argparse.Namespace) -> int:
    """run a simulation study (designs x materials x seeds) as tasks, and tabulate and plot it

    Without --rig/--sweep: the study of bench/sweep_tradeoff (grids, Rusinkiewicz grids and the adaptive sweep at three
    SNRs on a rough metal, a glossy plastic and a matte sample). With them: every sweep file on every rig file
    (simulated rigs), each with --seeds simulator seeds, fitted with the --models ladder and scored against the rig's
    true material. Each (design, material, seed) is one task; OUT gets study.md and study.txt (a table per material:
    captures, rig time, BRDF error and its ratio to the densest design, shape error, chi2/dof), study.png and
    outcomes.parquet. Exit codes: 0 done, 2 bad input or a failed cell, 130 interrupted (the same command again runs
    what is left).

    Examples: gonio batch study --out studies/tradeoff --seeds 5; gonio batch study --rig rigs/velvet.toml --sweep
    sweeps/grid.toml sweeps/sparse.toml --seeds 3 --out studies/velvet
    """
    from analysis.batch.study import file_cells, run_study, tradeoff_cells
    from analysis.batch.study_report import text_report
    from analysis.batch.tradeoff import KEYS

    seeds = range(args.first_seed, args.first_seed + args.seeds)
    if args.rig or args.sweep:
        if args.materials or args.quick:
            raise CliError("--materials and --quick choose the sweep_tradeoff study; with --rig and --sweep the "
                             "study is those files")  # fmt: skip
        cells = file_cells(args.rig or [], args.sweep or [], seeds, models=args.models, max_theta_deg=args.max_theta)
    else:
        if args.models:
            raise CliError("--models sets the ladder of a study of --rig and --sweep files; the sweep_tradeoff "
                             "study fits each material with its own model family")  # fmt: skip
        cells = tradeoff_cells(args.materials or KEYS, seeds, quick=args.quick)
    result = run_study(cells, args.out, cluster=_cluster(args), serial=args.serial, keep_runs=args.keep_runs,
                       progress=not args.quiet, log=_log(args.quiet))  # fmt: skip
    if not args.quiet:
        print(text_report(result.results, result.verdicts), file=sys.stderr)
    for kind in ("markdown", "figure", "outcomes"):
        if kind in result.files:
            print(result.files[kind])
    print(result.summary())
    for key, error in result.failed.items():
        print(f"failed: {key}: {error}", file=sys.stderr)
    return EXIT_BAD_INPUT if result.failed else EXIT_OK


def _add_cluster_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scheduler", metavar="ADDRESS", help=_CLUSTER_HELP)
    p.add_argument("--workers", type=positive_count, help="workers of the local cluster (default: the cores)")
    p.add_argument("--no-dashboard", action="store_true", help="run the local cluster without Dask's dashboard")
    add_quiet_option(p, "no progress bar or lines")


def add_batch_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``gonio batch analyze`` and ``gonio batch study``."""
    batch = sub.add_parser(
        "batch", help="analyse many runs or MERL files, or run a simulation study, on a Dask cluster",
        description="Work that is many independent tasks, run in parallel on a local Dask cluster or an existing one. "
        "Each task is idempotent and writes atomically: a worker lost mid-task only costs that task again, and a batch "
        "started again skips what is done.",
    )  # fmt: skip
    jobs = batch.add_subparsers(dest="batch_command", required=True, metavar="JOB")
    p = add_command(jobs, "analyze", _batch_analyze)
    p.add_argument("sources", nargs="+", metavar="RUN_OR_MERL", help="run directories and MERL .binary files")
    p.add_argument("--out", required=True, help="batch directory (one directory per input, catalogue.parquet)")
    add_fit_options(p)
    _add_cluster_options(p)

    st = add_command(jobs, "study", _batch_study)
    st.add_argument("--out", required=True, help="study directory (tables, figure, outcomes.parquet, task records)")
    st.add_argument("--rig", nargs="+", metavar="RIG", help="simulated rig files, one material each")
    st.add_argument("--sweep", nargs="+", metavar="SWEEP", help="sweep files, one design each")
    st.add_argument("--seeds", type=positive_count, default=3, help="simulator seeds per cell (default 3)")
    st.add_argument("--first-seed", type=int, default=1, help="first simulator seed (default 1): more seeds later")
    st.add_argument("--materials", nargs="+", choices=("metal", "plastic", "matte"),
                    help="sweep_tradeoff materials (default all three)")  # fmt: skip
    st.add_argument("--quick", action="store_true", help="sweep_tradeoff with fewer and smaller designs")
    st.add_argument("--models", help="ladder fitted in a study of files (default: gonio analyze's)")
    st.add_argument("--max-theta", type=float, default=70.0,
                    help="largest zenith (deg) of the pairs the BRDF error is scored on (default 70)")  # fmt: skip
    st.add_argument("--keep-runs", action="store_true", help="keep every cell's runs in OUT/runs")
    st.add_argument("--serial", action="store_true", help="run the cells in this process, one after the other")
    _add_cluster_options(st)
