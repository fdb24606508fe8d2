"""``gonio analyze``: from a run directory or a MERL file to a fitted model and a report a person reads at a glance.

The source is loaded into :class:`model.fit.samples.Samples` (analysis/sources.py), the ladder of candidate
models is fitted and one chosen (analysis/ladder.py), and the :class:`analysis.result.Analysis` this
produces is all the writers need: the figures (analysis/report/plots.py), the page
(analysis/report/html.py), ``fit.json`` and the exports (analysis/exports/write.py), all written by
:func:`write_report` here.
"""

from __future__ import annotations

import json
import math
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from acquisition.files.atomic import write_atomic
from analysis.ladder import fit_ladder
from analysis.parameters import covariance_json, parameter_status
from analysis.report import notebook  # noqa: F401  (an Analysis displays itself in Jupyter once this is loaded)
from analysis.report.truth import compare_truth
from analysis.result import Analysis, AnalysisError, Log, Reference
from analysis.sources import (
    DEFAULT_MERL_SAMPLES,
    load_adaptive,
    load_merl,
    load_run,
    load_table,
    read_merl_source,
    source_kind,
    unknown_file,
)
from analysis.uncertainty import uncertainty_json
from model.base import Model
from model.fit.samples import FitError
from model.fit.select import default_ladder
from model.fit.solve import LOSSES
from model.fit.spec import FitSpec
from model.plain import json_walk
from model.serialize import to_json_dict
from rig.run.storage.store import MANIFEST

if TYPE_CHECKING:
    from analysis.report.files import Figures
    from model.runtime import Standby


def load_and_fit(
    source: str | Path,
    *,
    models: Sequence[FitSpec] | None = None,
    loss: str = "l2",
    starts: int = 4,
    samples: int | None = None,
    seed: int = 0,
    compare: str | Path | None = None,
    log: Log | None = None,
    errors: str = "total",
    progress: bool = False,
    jobs: int = 1,
) -> Analysis:
    """Load a run, an adaptive sweep, a samples table or a MERL file (``samples`` random bins), fit and choose
    (``jobs`` > 1: candidates fitted in two processes where that is safe, see :func:`analysis.ladder.fit_ladder`)."""
    say = log or (lambda _: None)
    path = Path(source)
    kind = source_kind(path)
    if errors not in ("total", "point"):
        raise AnalysisError(f"--errors {errors!r}: expected 'total' or 'point'")
    if errors == "point" and kind == "merl":
        raise AnalysisError(f"--errors point: {path} is a MERL file, which has no readings (its errors are assumed)")
    if loss not in LOSSES:
        raise AnalysisError(f"--loss {loss!r}: expected one of {', '.join(LOSSES)}")
    if starts < 1:
        raise AnalysisError(f"--starts {starts}: expected at least 1")
    if kind == "missing":
        raise AnalysisError(f"{path}: no such file or directory (SOURCE: a run directory, an adaptive sweep's "
                            "directory, a samples.csv / samples.parquet table or a MERL .binary file)")  # fmt: skip
    if kind != "merl" and samples is not None:
        raise AnalysisError(f"--samples {samples}: only a MERL source is subsampled; {path} is not a MERL file")
    n = DEFAULT_MERL_SAMPLES if samples is None else samples
    if n < 1:
        raise AnalysisError(f"--samples {n}: expected a positive number of MERL bins")
    if kind == "unknown file":
        raise AnalysisError(unknown_file(path))
    if kind == "unknown":
        raise AnalysisError(f"{path}: not a run directory (no {MANIFEST}; expected a directory written by gonio run) "
                            "nor an adaptive sweep's (no adaptive.json, written by gonio adaptive)")  # fmt: skip
    ladder = tuple(default_ladder() if models is None else models)
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        loaders = {"run": load_run, "adaptive": load_adaptive, "table": load_table}
        summary, data, refs = loaders[kind](path, say, errors) if kind in loaders else load_merl(path, n, seed, say)
        if compare is not None:
            refs.append(Reference(f"MERL reference {Path(compare).name}", read_merl_source(Path(compare), "--compare")))
    loaded = [f"{w.category.__name__}: {w.message}" for w in got]
    try:
        angular: dict[str, Any] = {}
        selection, times, caught = fit_ladder(data, ladder, loss=loss, starts=starts, seed=seed, log=say,
                                              angular=angular, progress=progress, jobs=jobs)  # fmt: skip
    except FitError as exc:
        raise AnalysisError(f"{path}: cannot fit: {exc}") from exc
    variance = angular.get(selection.chosen_name) if data.direction_cov.size else None
    return Analysis(summary, data, ladder, selection, times, tuple(dict.fromkeys(loaded + caught)), tuple(refs),
                    loss, starts, errors, variance)  # fmt: skip


def model_json(model: Model) -> dict[str, Any]:
    """{"model": class name, "params": {field: value}} of a fitted model (model.serialize's JSON form)."""
    return to_json_dict(model)


def _null_for_nan(value: Any) -> Any:
    """``_plain``'s rule where its walk stops: containers walked on, other numbers as floats, inf and NaN as None."""
    if isinstance(value, dict):
        return _plain(dict(value))
    if isinstance(value, list | tuple | np.ndarray):
        return _plain(list(value))
    if isinstance(value, bool | str | int) or value is None:
        return value
    f = float(value)
    return f if math.isfinite(f) else None


#: JSON-ready: tuples and arrays as lists, numpy scalars as floats, inf and NaN as None (JSON has neither), keys str.
_plain = json_walk(_null_for_nan, str)


def fit_json(a: Analysis) -> dict[str, Any]:
    """The content of fit.json: source, every candidate's fit, the chosen model and its parameters (no timings)."""
    sel = a.selection
    best = min(c.criterion(sel.criterion) for c in sel.candidates)
    cands = []
    for c in sel.candidates:
        # time_s stays a field but is null: wall-clock time differs from run to run, and fit.json must be a
        # function of the inputs alone (a batch writes the same bytes as gonio analyze). The progress lines print
        # the times; a batch keeps them in its task records and catalogue (analysis/batch/).
        doc: dict[str, Any] = {"name": c.name, "k": c.n_params, "fitted": c.result is not None, "error": c.error,
                               "time_s": None}  # fmt: skip
        if c.result is not None:
            r = c.result
            doc |= {
                "params": dict(zip(r.names, r.values, strict=True)),
                "std_errors": dict(zip(r.names, r.std_errors, strict=True)),
                "chi2": r.chi2, "dof": r.dof, "reduced_chi2": r.reduced_chi2, "p_value": r.p_value, "aic": r.aic,
                "bic": r.bic, f"delta_{sel.criterion}": c.criterion(sel.criterion) - best,
                "noise_reached": r.noise_reached, "warnings": list(r.warnings), "model": model_json(r.model),
                **covariance_json(r),
                "parameters": {p.name: p.as_dict() for p in parameter_status(r, a.spec(c.name), a.samples.channels)},
            }  # fmt: skip
        cands.append(doc)
    return _plain({
        "source": a.source.as_dict(), "loss": a.loss, "errors": a.errors, "starts": a.starts,
        "criterion": sel.criterion, "n_samples": a.samples.n, "chosen": sel.chosen_name, "reason": sel.reason,
        "candidates": cands,
        "model": model_json(sel.chosen.model), **covariance_json(sel.chosen), "warnings": list(a.warnings),
        "uncertainty": uncertainty_json(a), "truth": None if (true := compare_truth(a)) is None else true.as_dict(),
    })  # fmt: skip


def default_out(source: str | Path) -> Path:
    """RUN/analysis for a run directory, <stem>-analysis beside a MERL file."""
    p = Path(source)
    return p / "analysis" if p.is_dir() else p.with_name(f"{p.stem}-analysis")


def write_report(
    a: Analysis, out: str | Path, *, y_scale: str = "auto", merl: bool = False, log: Log | None = None,
    mitsuba_plugin: bool = False, svg: bool = False, progress: bool = False, jobs: int = 1, mitsuba_stock: str = "auto",
    standby: Standby | None = None, exporter: Standby | None = None,
) -> Path:
    """Write figures/ (PNG; SVG too if ``svg``), fit.json, export/ (the chosen model for Mitsuba, glTF, optionally
    MERL) and index.html; ``progress``: a bar with ETA over the figures; ``jobs``: processes drawing figures.

    ``mitsuba_plugin`` adds export/mitsuba_gonio_plugin.xml, the exact model for processes that have gonio;
    ``mitsuba_stock`` (auto, tabulated, projection) picks what export/mitsuba_bsdf.* hold for a model
    without a native Mitsuba plugin (auto: the projection within 5 % RMS, else whichever Mitsuba measures closer).
    With ``jobs`` > 1 the figures and the exports are made side by side (model/runtime.py, where it is
    safe): the figures in ``standby`` (a process forked before the fit that loads matplotlib meanwhile, as
    ``gonio analyze`` starts one) while the exports are made here, or else the exports in a forked child while the
    figures are drawn here and in ``jobs`` - 1 workers. With a forked ``exporter`` as well (a standby that loaded
    Mitsuba during the fit) the exports are made there, and this process only waits and writes the page. The files
    are the same bytes either way.
    """
    from model.runtime import ForkedCall

    say = log or (lambda _: None)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise AnalysisError(f"--out {out}: exists and is not a directory")
    text = json.dumps(fit_json(a), indent=2, allow_nan=False) + "\n"
    write_atomic(out / "fit.json", lambda tmp: tmp.write_text(text, encoding="utf-8"))
    say(f"wrote {out / 'fit.json'}")

    # The export closes over the chosen model alone: handed to the export standby it is pickled, and the analysis
    # would be its samples, every candidate and a MERL source's table (tens of MB to pickle and to load again).
    chosen = a.selection.chosen.model

    def export() -> tuple[dict[str, Path], dict[str, str]]:
        # Imported only here: it loads Mitsuba, whose threads would keep figures from being drawn in forked workers.
        from analysis.exports.write import export_material, export_notes

        paths = export_material(chosen, out / "export", merl=merl, gonio_plugin=mitsuba_plugin,
                                stock=mitsuba_stock)  # fmt: skip
        return paths, export_notes(paths)

    def figures_of() -> Figures:
        from analysis.report.plots import write_figures

        return write_figures(a, out / "figures", y_scale=y_scale, svg=svg, progress=progress, jobs=jobs)

    say(f"writing figures to {out / 'figures'}")
    say(f"exporting the chosen model to {out / 'export'}" + (" (with a 35 MB MERL table)" if merl else ""))
    if standby is not None and standby.forked and jobs > 1:
        standby.run(figures_of)
        if exporter is not None and exporter.forked:
            exporter.run(export)
            exports, notes = exporter.result()
        else:
            exports, notes = export()
        figures = standby.result()
    else:
        # Forked before matplotlib loads here, so both load side by side.
        with ForkedCall(export, fork=jobs > 1) as exporting:
            figures = figures_of()
            exports, notes = exporting.result()  # here and now, after the figures, when it was not forked
    for f in figures.files:
        say(f"wrote {f.png}")
    from analysis.report.html import write_html

    return write_html(a, figures, out / "index.html", exports, notes=notes)


def analyze(
    source: str | Path,
    out: str | Path | None = None,
    *,
    models: Sequence[FitSpec] | None = None,
    loss: str = "l2",
    starts: int = 4,
    samples: int | None = None,
    seed: int = 0,
    compare: str | Path | None = None,
    y_scale: str = "auto",
    merl: bool = False,
    log: Log | None = None,
    errors: str = "total",
    mitsuba_plugin: bool = False,
    svg: bool = False,
    progress: bool = False,
    mitsuba_stock: str = "auto",
) -> Path:
    """Analyse a run, adaptive sweep, table or MERL file into ``out`` (default: see default_out); returns index.html."""
    a = load_and_fit(source, models=models, loss=loss, starts=starts, samples=samples, seed=seed, compare=compare,
                     log=log, errors=errors, progress=progress)  # fmt: skip
    return write_report(a, default_out(source) if out is None else out, y_scale=y_scale, merl=merl, log=log,
                        mitsuba_plugin=mitsuba_plugin, svg=svg, progress=progress,
                        mitsuba_stock=mitsuba_stock)  # fmt: skip


def stderr_log(line: str) -> None:
    """Progress lines go to stderr, so stdout carries only the result."""
    from tqdm.auto import tqdm

    tqdm.write(line, file=sys.stderr)  # above any progress bar, which tqdm then redraws
