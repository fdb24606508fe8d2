"""``gonio analyze``: fit a ladder of models to a run or a MERL file and write a static report.

Progress lines go to stderr; stdout gets the path of index.html and a one-line verdict. Bad input (a
missing source, a directory that is not a run, a run with too few points, an unreadable MERL file, an
unknown model name) raises analysis.result.AnalysisError, a ValueError, which ``gonio`` turns into exit code 2
with the message naming the path.

An existing analysis is not replaced without ``--force``: the command refuses (exit 2, before any fitting)
and says what is there. Refusing rather than warning, because the command runs unattended in scripts where a
warning scrolls by unread, and an earlier analysis may hold choices (models, loss, seed) worth comparing;
``--force`` or another ``--out`` is one word away. The report is written into a temporary directory beside
the target and swapped in whole, so an analysis that fails half-way leaves the previous one as it was (a
directory holding other files, not an analysis, gets the report written into it, and keeps its files).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from gonio.cli_errors import CliError
from gonio.cli_options import add_command, add_quiet_option, positive_count
from gonio.cli_run import EXIT_OK

if TYPE_CHECKING:
    from model.runtime import CollectorPause, Standby

_MODELS_HELP = ("lambert, lambert_ggx (dielectric), lambert_ggx_schlick, ggx_conductor, ggx_conductor_lambert, "
                "blinn_phong, ward (anisotropic)")  # fmt: skip


def _whole(out: Path, force: bool) -> bool:
    """Whether the report may replace ``out`` whole; refuses to replace an analysis without --force.

    A directory that holds other files (not an analysis) gets the report written into it, as it always did:
    replacing it whole would delete what it held.
    """
    if not out.exists():
        return True
    if not out.is_dir():
        raise CliError(f"--out {out}: exists and is not a directory")
    if not (out / "fit.json").is_file():
        return not any(out.iterdir())
    what = _previous(out / "fit.json")
    if not force:
        raise CliError(f"{out}: holds an analysis already ({what}); --force replaces it, or --out names "
                       "another directory")  # fmt: skip
    print(f"gonio: warning: replacing the analysis in {out} ({what}) (--force)", file=sys.stderr)
    return True


def _previous(fit: Path) -> str:
    """What an earlier analysis chose, for the refusal's message."""
    import json

    try:
        doc = json.loads(fit.read_text(encoding="utf-8"))
        return f"chose {doc['chosen']} from {len(doc['candidates'])} models, {doc['n_samples']} samples"
    except (OSError, ValueError, KeyError, TypeError):
        return "its fit.json is unreadable"


def _figure_modules() -> None:
    import analysis.report.html
    import analysis.report.plots  # noqa: F401  (matplotlib and every figure's module)


def _export_modules() -> None:
    # Mitsuba's import and its variant's first load need no fit, nor do the exports' seeded draws, error grid and
    # Mitsuba's first-use costs (prepare_exports: what the export then no longer spends after the fit); an export
    # that cannot load Mitsuba fails the same way when it runs, so nothing is raised here.
    with contextlib.suppress(Exception):
        from analysis.exports.write import prepare_exports  # Mitsuba, drjit
        from model.mitsuba.variant import pick_variant

        pick_variant()
        prepare_exports()


def _analyze(args: argparse.Namespace) -> int:
    """fit models to a run or a MERL file and write an HTML report with figures

    Load a run directory (finished, or stopped: then analysed as far as it got, with a warning) or a MERL .binary file
    (random bins, std errors assumed), fit a ladder of models from Lambert upward, choose the simplest the data support
    (BIC) and write DIR/index.html, DIR/fit.json and DIR/figures (in-plane slices, polar lobes, residual maps, coverage
    of the BRDF domain). Exit codes: 0 done, 2 bad input.

    Example: gonio analyze runs/gold --models lambert,lambert_ggx,ggx_conductor (writes runs/gold/analysis/index.html);
    gonio analyze gold-metallic-paint.binary --samples 20000
    """
    from model.runtime import CollectorPause, Standby

    # The garbage collector is paused while this process and the standbys import: an import is many objects that
    # live as long as the process, and the collector's passes over them (a visible share of importing scipy and
    # matplotlib) free nothing. The standbys keep theirs paused after their imports (runtime.imports_done), this
    # process resumes its own after them (_analyze_with); a caller that had paused it keeps it paused.
    with CollectorPause() as paused:
        import numpy  # noqa: F401  (which every process needs: loaded once, before the forks)

        # The figures' process loads matplotlib and the report's modules, the exports' process Mitsuba, while this
        # one loads scipy and the run's configuration and fits; they draw and export once the fit is handed to them
        # (write_report). The figures' standby is forked first, before scipy, which no figure needs (the fit's
        # modules load it only to solve): it loads matplotlib on the second core while this process loads scipy,
        # which the exports need too (their own fits), so their standby is forked after it. The figures' standby
        # forks a worker of its own, which must not inherit Mitsuba.
        with Standby(_figure_modules) if args.jobs > 1 else contextlib.nullcontext() as standby:
            import scipy.optimize
            import scipy.special  # noqa: F401

            with Standby(_export_modules) if args.jobs > 1 else contextlib.nullcontext() as exporter:
                return _analyze_with(args, standby, exporter, paused)


def _analyze_with(args: argparse.Namespace, standby: Standby | None, exporter: Standby | None = None,
                  paused: CollectorPause | None = None) -> int:  # fmt: skip
    from analysis.analyze import default_out, load_and_fit, stderr_log, write_report
    from analysis.batch.records import staged_dir
    from analysis.ladder import parse_models

    if paused is not None:
        paused.resume()  # not frozen as the standbys' imports are: this process may be a caller's that lives on

    log = None if args.quiet else stderr_log
    models = parse_models(args.models) if args.models else None
    out = Path(args.out) if args.out else default_out(args.source)
    whole = _whole(out, args.force)  # before the fit: a refusal should not cost minutes
    a = load_and_fit(args.source, models=models, loss=args.loss, starts=args.starts, samples=args.samples,
                     seed=args.seed, compare=args.compare, log=log, errors=args.errors,
                     progress=not args.quiet, jobs=args.jobs)  # fmt: skip
    options = {"y_scale": args.y_scale, "merl": args.merl, "mitsuba_plugin": args.mitsuba_plugin, "svg": args.svg,
               "progress": not args.quiet, "jobs": args.jobs, "mitsuba_stock": args.mitsuba_stock,
               "standby": standby, "exporter": exporter}  # fmt: skip
    if not whole:
        page = write_report(a, out, log=log, **options)
    else:
        with staged_dir(out) as tmp:
            # The progress lines name where the files will be, not the temporary directory they are written in.
            shown = None if log is None else (lambda line: stderr_log(line.replace(str(tmp), str(out))))
            page = out / write_report(a, tmp, log=shown, **options).relative_to(tmp)
    print(page)
    print(a.text())
    return EXIT_OK


def add_analyze_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``gonio analyze``."""
    p = add_command(sub, "analyze", _analyze)
    p.add_argument("source", help="run directory, adaptive sweep directory, samples.csv / samples.parquet table, "
                   "or MERL .binary file")
    p.add_argument("--out", help="report directory (default: RUN/analysis, or <name>-analysis beside a MERL file)")
    p.add_argument("--force", action="store_true",
                   help="replace an existing analysis in the report directory (without it gonio analyze refuses)")
    add_fit_options(p)
    add_quiet_option(p, "no progress lines")
    p.add_argument("--jobs", type=positive_count, default=min(os.cpu_count() or 1, 4),
                   help="processes drawing the figures side by side, and with 2 or more two fit the candidates "
                   "(default: the cores, at most 4; 1: everything in this process)")


def add_fit_options(p: argparse.ArgumentParser) -> None:
    """The options of how an analysis fits and reports (gonio analyze, and gonio batch analyze for every input)."""
    p.add_argument("--models", help=f"comma-separated ladder (default: lambert, lambert_ggx, lambert_ggx_schlick, "
                   f"ward); known: {_MODELS_HELP}")  # fmt: skip
    # No `choices` from model.fit: importing it (scipy) would slow every gonio command; analyze checks the name.
    p.add_argument("--loss", default="l2", help="fit loss: l2 (default, chi-square), cosine_l2, log or cbrt")
    p.add_argument("--errors", default="total", choices=("total", "point"),
                   help="sample weights: total (default; each value's whole error, calibration included) or point "
                   "(each capture's own reading error: chi2 then tests the model against the capture noise, and the "
                   "scale carries the calibration's error on top)")
    p.add_argument("--starts", type=positive_count, default=4, help="optimiser starts per candidate (default 4)")
    p.add_argument("--samples", type=positive_count, help="MERL bins drawn at random (MERL source only; default 20000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the MERL subsample and the random starts (default 0)")
    p.add_argument("--compare", metavar="MERL_FILE", help="overlay a reference MERL material on the slices")
    p.add_argument("--y-scale", default="auto", choices=("auto", "log", "linear"),
                   help="slices' y axis (default auto: log when the values span more than 50x)")  # fmt: skip
    p.add_argument("--merl", action="store_true", help="also export the chosen model as a MERL .binary (35 MB)")
    p.add_argument("--mitsuba-plugin", action="store_true",
                   help="also export the exact model for gonio's Mitsuba plugin (export/mitsuba_gonio_plugin.xml; "
                   "renders only where gonio is installed) when the stock-Mitsuba export is not exact (a table or a "
                   "projection)")  # fmt: skip
    p.add_argument("--mitsuba-stock", default="auto", choices=("auto", "tabulated", "projection"),
                   help="what export/mitsuba_bsdf.xml holds for a model with no native Mitsuba plugin: auto "
                   "(default: whichever Mitsuba measures closer), tabulated (the RGL table material.bsdf for the "
                   "measured plugin) or projection (the nearest diffuse + GGX); both are also written under their "
                   "own names")  # fmt: skip
    p.add_argument("--svg", action="store_true", help="also write every figure as SVG beside its PNG (slower; the "
                   "page links each PNG to its SVG)")  # fmt: skip
