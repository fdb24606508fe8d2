"""``gonio analyze``: from a run directory or a MERL file to a fitted model and a report a person reads at a glance.

The source is loaded into :class:`model.fit_samples.Samples`: a finished run from its ``samples.csv``; a run
that stopped (or is still running) from its journal through the same ``rig.table.build_rows`` the runner
uses at the end, so an unfinished run is analysed exactly as far as it got, with a warning saying so; a
MERL ``.binary`` file by drawing random bins (``Samples.from_merl``, errors assumed), which is how MERL
materials are imported for fitting and comparison. A ladder of candidate models is then fitted one by
one (each timed, its warnings captured for the report) and chosen among exactly as
:func:`model.fit_select.select` chooses; ``select`` itself has no per-candidate hook, so the loop lives
here and the tests check it agrees with ``select``. The :class:`Analysis` this produces is all the
writers (rig/report_plots.py, rig/report_html.py and ``fit.json`` here) need.
"""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.atomic import atomic_path
from model.base import BRDF, Model
from model.fit import LOSSES, FitWarning, fit
from model.fit_samples import FitError, Samples
from model.fit_select import Candidate, Selection, choose, default_ladder
from model.fit_spec import LAMBERT, FitSpec, blinn_phong, ggx_conductor, lambert_ggx, ward_anisotropic
from model.merl import MerlFormatError, MerlTable, read_merl
from model.serialize import to_json_dict
from rig.config import material_from
from rig.session import configs_of, reference_settings
from rig.store import JOURNAL, MANIFEST, RunStore, RunStoreError
from rig.table import build_rows

Log = Callable[[str], None]

#: Names accepted by ``--models``, in the order ``--help`` lists them (each spec's own name works too).
MODELS: dict[str, Callable[[], FitSpec]] = {
    "lambert": lambda: LAMBERT,
    "lambert_ggx": lambda: lambert_ggx("dielectric"),
    "lambert_ggx_schlick": lambda: lambert_ggx("schlick").per_channel("f0"),
    "ggx_conductor": ggx_conductor,
    "ggx_conductor_lambert": lambda: ggx_conductor(rho_d=True),
    "blinn_phong": blinn_phong,
    "ward": ward_anisotropic,
}
DEFAULT_MERL_SAMPLES = 20_000


class AnalysisError(ValueError):
    """The source cannot be analysed (missing, not a run, unreadable, too little data); names the path."""


@dataclass(frozen=True)
class SourceSummary:
    """What was analysed: a run (status, points measured/planned/unreachable, sweep, material) or a MERL file."""

    kind: str  # "run" or "merl"
    path: Path
    state: str  # finished, stopped or running for a run; "file" for MERL
    stop_reason: str | None = None
    measured: int = 0
    planned: int | None = None
    unreachable: int | None = None
    lower_bound: int = 0
    sweep_kind: str | None = None
    rig_name: str | None = None
    sweep_name: str | None = None
    material: str | None = None
    notes: tuple[str, ...] = ()

    @property
    def warning(self) -> str | None:
        """The banner for an unfinished run ("run stopped: <reason>; N of M points"), else None."""
        if self.kind != "run" or self.state == "finished":
            return None
        of = f"{self.measured} of {self.planned} points"
        if self.state == "stopped":
            return f"run stopped: {self.stop_reason or 'no reason recorded'}; {of}"
        return f"run not finished (no status.json: still running or killed); {of}"

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (for fit.json)."""
        return {**dataclasses.asdict(self), "path": str(self.path), "notes": list(self.notes)}


@dataclass(frozen=True)
class Reference:
    """A BRDF drawn beside the fits on the slices: the simulated material, the MERL source, a --compare file."""

    label: str
    brdf: BRDF


@dataclass(frozen=True, eq=False)
class Analysis:
    """The loaded samples, the fitted ladder and its choice, and what the report says about them."""

    source: SourceSummary
    samples: Samples
    ladder: tuple[FitSpec, ...]
    selection: Selection
    fit_times_s: dict[str, float]
    warnings: tuple[str, ...]
    references: tuple[Reference, ...]
    loss: str
    starts: int
    #: "total" (every error in the table) or "point" (each capture's own reading error): see Samples.from_table_rows.
    errors: str = "total"

    @property
    def chosen(self) -> Candidate:
        """The chosen candidate."""
        return next(c for c in self.selection.candidates if c.result is self.selection.chosen)

    def spec(self, name: str) -> FitSpec:
        """The ladder's spec of that name."""
        return next(s for s in self.ladder if s.name == name)

    def verdict(self) -> str:
        """One line: the chosen model, its chi2/dof and whether the residuals reach the noise."""
        r = self.selection.chosen
        noise = "at the noise" if r.noise_reached else "above the noise"
        return (f"chosen: {r.spec} ({type(r.model).__name__}, {r.n_params} parameters), chi2/dof = "
                f"{r.reduced_chi2:.3g} ({noise}) on {r.n_samples} samples")  # fmt: skip


def parse_models(text: str) -> list[FitSpec]:
    """A ladder from a comma-separated list of MODELS names (or spec names such as lambert+ggx_dielectric)."""
    by_spec = {make().name: make for make in MODELS.values()}
    specs = []
    for name in (n.strip() for n in text.split(",")):
        make = MODELS.get(name) or by_spec.get(name)
        if make is None:
            raise AnalysisError(f"--models {text!r}: unknown model {name!r}; expected names from {', '.join(MODELS)}")
        specs.append(make())
    if len({s.name for s in specs}) != len(specs):
        raise AnalysisError(f"--models {text!r}: a model is listed twice")
    return specs


def _describe_material(table: Any) -> str:
    params = ", ".join(f"{k}={list(v) if isinstance(v, tuple) else v}" for k, v in table.parameters().items())
    return f"{table.model}({params})"


def _load_run(path: Path, log: Log, errors: str = "total") -> tuple[SourceSummary, Samples, list[Reference]]:
    try:
        store = RunStore.read(path)
        status = store.status()
        rig, sweep = configs_of(store)
        records = store.records()
    except (RunStoreError, ValueError, KeyError) as exc:
        raise AnalysisError(f"{path}: not a readable run directory: {exc}") from exc
    table = path / "samples.csv"
    if table.is_file():
        rows: list[dict[str, Any]] = list(store.read_table())
    elif status["state"] == "finished":
        raise AnalysisError(f"{path}: the run is marked finished but has no samples.csv ({table})")
    else:  # a stopped or running run has only its journal: build the table the runner would have written
        ref = reference_settings(rig)
        cosine = bool(store.manifest.get("options", {}).get("include_cosine", False))
        rows = build_rows(records, rig.geometry.joint_names, albedo=ref.albedo if ref else None,
                          albedo_std_error=ref.albedo_std_error if ref else 0.0, include_cosine=cosine)  # fmt: skip
    if not rows:
        raise AnalysisError(f"{path}: no measured points to analyse (journal {path / JOURNAL} holds none)")
    try:
        samples = Samples.from_table_rows(rows, source=str(path), errors=errors)
    except FitError as exc:
        raise AnalysisError(f"{path}: cannot read the samples: {exc}") from exc
    refs, material = [], None
    if rig.file.link.kind == "simulated":
        material = _describe_material(rig.file.simulation.material)
        try:
            refs.append(Reference("simulated material (truth)", material_from(rig)))
        except ValueError as exc:
            warnings.warn(f"{path}: the simulated material cannot be built: {exc}", stacklevel=2)
    summary = SourceSummary(
        "run", path, status["state"], status.get("reason"), len(rows), store.manifest.get("points"),
        len(store.manifest.get("unreachable", [])), int(samples.lower_bound.sum()), sweep.file.sweep.kind,
        rig.file.name, sweep.file.name, material, samples.notes,
    )  # fmt: skip
    log(f"loaded run {path}: {len(rows)} points ({status['state']}), {samples.n} usable samples")
    return summary, samples, refs


def _read_merl(path: Path, what: str) -> MerlTable:
    expect = f"{what}: expected a MERL .binary file" + (" or a run directory" if what == "SOURCE" else "")
    if not path.is_file():
        raise AnalysisError(f"{path}: not found ({expect})")
    try:
        return read_merl(path)
    except (MerlFormatError, OSError) as exc:
        msg = str(exc) if str(path) in str(exc) else f"{path}: {exc}"
        raise AnalysisError(f"{msg} ({expect})") from exc


def _load_merl(path: Path, n: int, seed: int, log: Log) -> tuple[SourceSummary, Samples, list[Reference]]:
    table = _read_merl(path, "SOURCE")
    try:
        samples = Samples.from_merl(table, n, seed)
    except FitError as exc:
        raise AnalysisError(f"{path}: {exc}") from exc
    log(f"loaded MERL table {path}: {samples.n} random bins (seed {seed})")
    return (
        SourceSummary("merl", path, "file", measured=samples.n, notes=samples.notes),
        samples,
        [Reference(f"MERL table {path.name} (source)", table)],
    )


def fit_ladder(
    samples: Samples,
    ladder: Sequence[FitSpec],
    *,
    loss: str = "l2",
    starts: int = 4,
    seed: int = 0,
    criterion: str = "bic",
    delta: float = 2.0,
    log: Log | None = None,
) -> tuple[Selection, dict[str, float], list[str]]:
    """Fit every candidate (timed, warnings captured) and choose as select() does: (selection, seconds, warnings)."""
    cands, times, caught = [], {}, []
    for spec in ladder:
        k = len(spec.labels(samples.channels))
        start = time.perf_counter()
        with warnings.catch_warnings(record=True) as got:
            warnings.simplefilter("always")
            try:
                cand = Candidate(spec.name, k, fit(spec, samples, loss, None, starts=starts, seed=seed))
            except FitError as exc:
                cand = Candidate(spec.name, k, None, str(exc))
        times[spec.name] = time.perf_counter() - start
        caught += [str(w.message) if issubclass(w.category, FitWarning) else f"{w.category.__name__}: {w.message}"
                   for w in got]  # fmt: skip
        cands.append(cand)
        if log:
            r = cand.result
            how = f"chi2/dof = {r.reduced_chi2:.4g}" if r is not None else f"not fitted: {cand.error}"
            log(f"fitting {spec.name} ({k} parameters): {how} ({times[spec.name]:.2f} s)")
    return choose(cands, criterion, delta), times, list(dict.fromkeys(caught))


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
) -> Analysis:
    """Load a run directory or a MERL file (``samples`` random bins), fit the ladder and choose a model."""
    say = log or (lambda _: None)
    path = Path(source)
    if errors not in ("total", "point"):
        raise AnalysisError(f"--errors {errors!r}: expected 'total' or 'point'")
    if errors == "point" and path.is_file():
        raise AnalysisError(f"--errors point: {path} is a MERL file, which has no readings (its errors are assumed)")
    if loss not in LOSSES:
        raise AnalysisError(f"--loss {loss!r}: expected one of {', '.join(LOSSES)}")
    if starts < 1:
        raise AnalysisError(f"--starts {starts}: expected at least 1")
    if not path.exists():
        raise AnalysisError(f"{path}: no such file or directory (SOURCE: a run directory or a MERL .binary file)")
    if path.is_dir() and samples is not None:
        raise AnalysisError(f"--samples {samples}: only a MERL source is subsampled; {path} is a run directory")
    n = DEFAULT_MERL_SAMPLES if samples is None else samples
    if n < 1:
        raise AnalysisError(f"--samples {n}: expected a positive number of MERL bins")
    if path.is_dir() and not (path / MANIFEST).is_file():
        raise AnalysisError(f"{path}: not a run directory (no {MANIFEST}; expected a directory written by gonio run)")
    ladder = tuple(default_ladder() if models is None else models)
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        summary, data, refs = _load_run(path, say, errors) if path.is_dir() else _load_merl(path, n, seed, say)
        if compare is not None:
            refs.append(Reference(f"MERL reference {Path(compare).name}", _read_merl(Path(compare), "--compare")))
    loaded = [f"{w.category.__name__}: {w.message}" for w in got]
    try:
        selection, times, caught = fit_ladder(data, ladder, loss=loss, starts=starts, seed=seed, log=say)
    except FitError as exc:
        raise AnalysisError(f"{path}: cannot fit: {exc}") from exc
    return Analysis(summary, data, ladder, selection, times, tuple(dict.fromkeys(loaded + caught)), tuple(refs),
                    loss, starts, errors)  # fmt: skip


def model_json(model: Model) -> dict[str, Any]:
    """{"model": class name, "params": {field: value}} of a fitted model (model.serialize's JSON form)."""
    return to_json_dict(model)


def _plain(value: Any) -> Any:
    """JSON-ready: tuples and arrays as lists, numpy scalars as floats, inf and NaN as None (JSON has neither)."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [_plain(v) for v in value]
    if isinstance(value, bool | str | int) or value is None:
        return value
    f = float(value)
    return f if math.isfinite(f) else None


def fit_json(a: Analysis) -> dict[str, Any]:
    """The content of fit.json: source, every candidate's fit, the chosen model and its parameters."""
    sel = a.selection
    best = min(c.criterion(sel.criterion) for c in sel.candidates)
    cands = []
    for c in sel.candidates:
        doc: dict[str, Any] = {"name": c.name, "k": c.n_params, "fitted": c.result is not None, "error": c.error,
                               "time_s": a.fit_times_s.get(c.name)}  # fmt: skip
        if c.result is not None:
            r = c.result
            doc |= {
                "params": dict(zip(r.names, r.values, strict=True)),
                "std_errors": dict(zip(r.names, r.std_errors, strict=True)),
                "chi2": r.chi2, "dof": r.dof, "reduced_chi2": r.reduced_chi2, "p_value": r.p_value, "aic": r.aic,
                "bic": r.bic, f"delta_{sel.criterion}": c.criterion(sel.criterion) - best,
                "noise_reached": r.noise_reached, "warnings": list(r.warnings), "model": model_json(r.model),
            }  # fmt: skip
        cands.append(doc)
    return _plain({
        "source": a.source.as_dict(), "loss": a.loss, "errors": a.errors, "starts": a.starts,
        "criterion": sel.criterion, "n_samples": a.samples.n, "chosen": sel.chosen_name, "reason": sel.reason,
        "candidates": cands,
        "model": model_json(sel.chosen.model), "warnings": list(a.warnings),
    })  # fmt: skip


def write_atomic(path: Path, write: Callable[[Path], object]) -> Path:
    """Write a report file through a temporary file and a rename, readable by all (a report is for sharing)."""
    with atomic_path(path) as tmp:
        write(tmp)
        tmp.chmod(0o644)  # mkstemp makes 0600
    return path


def default_out(source: str | Path) -> Path:
    """RUN/analysis for a run directory, <stem>-analysis beside a MERL file."""
    p = Path(source)
    return p / "analysis" if p.is_dir() else p.with_name(f"{p.stem}-analysis")


def write_report(
    a: Analysis, out: str | Path, *, y_scale: str = "auto", merl: bool = False, log: Log | None = None
) -> Path:
    """Write figures/, fit.json, export/ (the chosen model for Mitsuba, glTF, optionally MERL) and index.html."""
    from rig.report_html import write_html
    from rig.report_plots import write_figures
    from simulator.export import export_material

    say = log or (lambda _: None)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise AnalysisError(f"--out {out}: exists and is not a directory")
    say(f"writing figures to {out / 'figures'}")
    figures = write_figures(a, out / "figures", y_scale=y_scale, log=say)
    text = json.dumps(fit_json(a), indent=2, allow_nan=False) + "\n"
    write_atomic(out / "fit.json", lambda tmp: tmp.write_text(text, encoding="utf-8"))
    say(f"wrote {out / 'fit.json'}")
    say(f"exporting the chosen model to {out / 'export'}" + (" (with a 35 MB MERL table)" if merl else ""))
    exports = export_material(a.selection.chosen.model, out / "export", merl=merl)
    return write_html(a, figures, out / "index.html", exports)


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
) -> Path:
    """Analyse a run directory or MERL file into ``out`` (default: see default_out); returns index.html's path."""
    a = load_and_fit(source, models=models, loss=loss, starts=starts, samples=samples, seed=seed, compare=compare,
                     log=log, errors=errors)  # fmt: skip
    return write_report(a, default_out(source) if out is None else out, y_scale=y_scale, merl=merl, log=log)


def stderr_log(line: str) -> None:
    """Progress lines go to stderr, so stdout carries only the result."""
    print(line, file=sys.stderr, flush=True)
