"""An adaptive sweep: measure a few points, fit, then measure where the fit is least certain, and repeat.

Each round is an ordinary run (a ``list`` sweep in ``OUT/round-NN``, with its own reference readings,
journal and table), so everything a run guarantees holds per round: safe stops, resume, calibration.
Between rounds the samples of every round so far are fitted with one :class:`model.fit.spec.FitSpec`
(or the model chosen by :func:`model.fit.select.select`), and :func:`model.fit.design.choose_batch` picks
the next round's points from a pool of reachable candidates (``rig.run.adaptive.design``): those that most
lower the fit's expected BRDF error over the hemisphere (see model/fit/design.py).

Capture modes (:class:`rig.run.adaptive.settings.AdaptiveSettings` ``mode``, ``tile_px``, ``motion``,
``scan_speed_deg_s``, the sweep file's ``[capture]`` keys): each round is measured in point or image mode, at
rest or scanning, fixed or chosen per round by ``mode = "auto"`` (``rig.run.adaptive.modes``). The budget,
``initial`` and ``batch`` count captures (poses); in image mode one capture gives a sample per tile, so a
round's table has more rows than captures. Every row is a sample with its own errors: where any row is a tile
the fit weights them with their angular share (``model.fit.angular.fit_with_angular``, the footprint's spread
included, as gonio analyze fits them), and the design counts a candidate capture's information over all the
samples it would give (``model.fit.design.pooled``).

Written to OUT: ``samples.csv`` (every round's table rows, with a ``round`` column; ``samples.parquet`` and
``samples.schema.json`` beside it) and ``adaptive.json`` (:mod:`rig.run.adaptive.state`: the settings, model
and rig a resume needs, and per round: captures, samples, the mode and motion it was measured in and why, rig
time, the fit's parameters, the measured and predicted errors).

Resume (:func:`resume_adaptive`, ``gonio adaptive --resume OUT`` or ``gonio resume OUT``). Every step but the
measuring is a function of the settings and the rounds' tables (the pool is seeded, the fits are seeded and
deterministic), so a resume replays the sweep: rounds whose run finished are read back, the round that was
interrupted is resumed as any run is (its journal keeps what it measured), and the rest are measured. Each
replayed round's points and capture mode are checked against its run's manifest, so a sweep whose settings or
rig changed is refused instead of continued with other points. A resumed sweep ends with the table of an
uninterrupted one (but for the ``utc`` column: when each point was really measured). A state written before
the capture mode dials existed resumes as point mode at rest, which is how it was measured.
"""

from __future__ import annotations

import csv
import dataclasses
import math
import sys
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from model.fit.angular import fit_with_angular, with_angular
from model.fit.design import ErrorPairs, error_pairs
from model.fit.samples import FitError, Samples
from model.fit.select import Candidate, choose, default_ladder, select
from model.fit.solve import FitResult, fit
from model.fit.spec import FitSpec
from rig.run.adaptive.design import NOISE_FLOOR, candidate_points, next_points, space_filling
from rig.run.adaptive.modes import footprints, image_subset, next_mode, round_capture, round_choice
from rig.run.adaptive.settings import AdaptiveSettings
from rig.run.adaptive.state import AdaptiveStateError, new_state, read_state, rig_of, write_state
from rig.run.config.files import ConfigError, RigConfig, SweepConfig, parse, sweep_config
from rig.run.config.schema import SweepFile
from rig.run.storage.store import RunStore, RunStoreError
from rig.run.tables.parquet import write_beside

# The pool, the first round and the settings live beside this module; their names stay importable from here.
__all__ = ["NOISE_FLOOR", "AdaptiveResult", "AdaptiveSettings", "Round", "candidate_points", "measure_points",
           "next_points", "replace_table", "resume_adaptive", "round_rig", "run_adaptive", "space_filling",
           "with_reference_snr"]  # fmt: skip

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class Round:
    """One round: captures (poses) so far, this round's rig time (s), the fit after it, the predicted error; the
    samples (table rows) so far, and the mode and motion this round was measured in, with why."""

    index: int
    captures: int
    rig_time_s: float
    fit: FitResult
    predicted_error: float
    directory: Path
    samples: int = 0
    mode: str = "point"
    motion: str = "stop"
    reason: str = ""


@dataclass
class AdaptiveResult:
    """Every round of an adaptive sweep, and where its merged table is."""

    rounds: list[Round] = field(default_factory=list)
    table: Path | None = None

    @property
    def rig_time_s(self) -> float:
        """Rig time of all rounds (s)."""
        return sum(r.rig_time_s for r in self.rounds)


def _fit(
    samples: Samples, spec: FitSpec | None, starts: int, seed: int, angular: bool
) -> tuple[FitResult, FitSpec, Samples]:
    """The fit (spec None: the model selection's), its spec, and the samples with the errors it weighted them by.

    ``angular``: effective errors, the directions' covariance (a tile's footprint) included, as gonio analyze fits.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # early rounds are expected to be under-determined
        if not angular:
            if spec is not None:
                return fit(spec, samples, starts=starts, seed=seed, warn=False), spec, samples
            sel = select(samples, starts=starts, seed=seed)
            return sel.chosen, next(s for s in default_ladder() if s.name == sel.chosen_name), samples
        specs = [spec] if spec is not None else list(default_ladder())
        cands, variances = [], {}
        for sp in specs:
            n_params = len(sp.labels(samples.channels))
            try:
                res, variances[sp.name] = fit_with_angular(sp, samples, starts=starts, seed=seed)
            except FitError as exc:
                if spec is not None:
                    raise
                cands.append(Candidate(sp.name, n_params, None, str(exc)))
                continue
            cands.append(Candidate(sp.name, n_params, res))
        chosen = choose(cands)
        used = next(sp for sp in specs if sp.name == chosen.chosen_name)
        return chosen.chosen, used, with_angular(samples, samples.std_error, variances[used.name])


def _round_sweep(
    points: FloatArray, name: str, capture: dict[str, Any], metadata: dict[str, Any] | None
) -> SweepConfig:
    """The list sweep of one round's points (N, 4) in degrees with its ``[capture]`` table."""
    table = {"name": f"list sweep {name}", "sweep": {"kind": "list", "points": points.tolist()},
             "capture": capture, "metadata": metadata or {}}  # fmt: skip
    return sweep_config(parse(table, SweepFile, f"<{name}>"), f"<{name}>")


def measure_points(
    rig: RigConfig, points: FloatArray, out: Path, snr: float, metadata: dict[str, Any] | None = None,
    *, capture: dict[str, Any] | None = None,
) -> tuple[list[dict[str, Any]], float]:  # fmt: skip
    """Run the points (N, 4) in degrees as a list sweep into ``out``: the table's rows and the rig time (s).

    ``capture``: the sweep's ``[capture]`` table (None: point mode at rest with SNR goal ``snr``). Where ``out``
    already holds this round's run, it is read back (finished) or resumed (stopped or killed); its points and
    capture mode must be these, or AdaptiveStateError says the sweep changed.
    """
    from rig.run.session import start_run

    capture = capture or {"target_snr": snr}
    if out.exists():
        return _existing_round(out, points, capture)
    summary = start_run(rig, _round_sweep(points, out.name, capture, metadata), out, progress=False)
    return _rows(Path(summary.table)), summary.rig_time_s


def _rows(table: Path) -> list[dict[str, Any]]:
    with open(table, newline="") as fh:
        return list(csv.DictReader(fh))


def _captures(out: Path) -> int:
    """The captures (poses measured: point records) of the round's run in ``out``."""
    return sum(r.get("kind") == "point" for r in RunStore.read(out).records())


def _existing_round(
    out: Path, points: FloatArray, capture: dict[str, Any]
) -> tuple[list[dict[str, Any]], float]:
    """A round found on disk by a resume: check its points, finish it if it stopped, return rows and rig time."""
    from rig.run.session import resume_run

    try:
        store = RunStore.read(out)
    except RunStoreError as exc:
        raise AdaptiveStateError(f"{out}: this round's run cannot be read ({exc})") from None
    sweep = store.manifest.get("sweep", {})
    planned = np.asarray(sweep.get("sweep", {}).get("points", []), dtype=float)
    if planned.shape != points.shape or not np.allclose(planned, points, rtol=0.0, atol=1e-9):
        raise AdaptiveStateError(
            f"{out}: its run measured other points than this sweep chooses for the round: the settings, the rig or "
            "gonio changed since it started; resume with the same gonio, or start a new sweep"
        )
    was = {k: sweep.get("capture", {}).get(k, d) for k, d in (("mode", "point"), ("motion", "stop"))}
    now = {k: capture.get(k, d) for k, d in (("mode", "point"), ("motion", "stop"))}
    if was != now:
        raise AdaptiveStateError(f"{out}: its run was measured with mode {was['mode']}, motion {was['motion']}; this "
                                 f"sweep chooses mode {now['mode']}, motion {now['motion']} for the round: the "
                                 "settings or gonio changed since it started; start a new sweep")  # fmt: skip
    if store.status().get("state") != "finished":
        resume_run(out, progress=False)
        store = RunStore.read(out)
    # Rig time of the whole round, resumed or not: the run time of its journal's last record.
    times = [float(r["run_time_s"]) for r in store.records() if "run_time_s" in r]
    return _rows(out / "samples.csv"), max(times, default=0.0)


def round_rig(rig: RigConfig, index: int) -> RigConfig:
    """The rig of round ``index``: the simulation's noise seed mixed with the round (a real rig ignores it).

    Each round is its own run, and the simulator draws noise per (seed, state, reference slot): with one seed,
    every round's first reference reading would repeat round 0's draw, and a real camera never does that.
    """
    if index == 0:
        return rig
    # Modulo 2**32: a rig file's seed range (Mitsuba's sampler takes a uint32).
    return replace_table(rig, "simulation", seed=(rig.file.simulation.seed * 1_000_003 + index) % 2**32)


def with_reference_snr(rig: RigConfig, snr: float | None) -> RigConfig:
    """The rig with its reference readings' SNR goal replaced (None: unchanged)."""
    return rig if snr is None else replace_table(rig, "reference", target_snr=float(snr))


def replace_table(rig: RigConfig, table: str, **keys: Any) -> RigConfig:
    """The rig with keys of one table of its file replaced."""
    new = getattr(rig.file, table).model_copy(update=keys)
    return dataclasses.replace(rig, file=rig.file.model_copy(update={table: new}))


def run_adaptive(
    rig: RigConfig,
    out: str | Path,
    spec: FitSpec | None,
    settings: AdaptiveSettings | None = None,
    *,
    pairs: ErrorPairs | None = None,
    on_round: Callable[[Round], None] | None = None,
    log: Callable[[str], None] | None = None,
    metadata: dict[str, Any] | None = None,
) -> AdaptiveResult:
    """Measure rounds into OUT/round-NN until the budget is spent; spec None chooses the model each round.

    ``metadata``: the sweep's ``[metadata]`` (sample, operator, notes, ...), laid over the rig file's.
    """
    from rig.run.session import check_rig

    s = settings or AdaptiveSettings()
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise ConfigError(f"{out}: exists and is not empty; an adaptive sweep needs a fresh directory "
                         "(an interrupted one continues with gonio adaptive --resume)")  # fmt: skip
    # Every input is read before the directory exists (a failed start must leave nothing a retry trips on).
    check_rig(with_reference_snr(rig, s.reference_snr))
    _pool(rig, s)
    out.mkdir(parents=True, exist_ok=True)
    meta = {**rig.file.metadata.as_dict(), **(metadata or {})}
    doc = new_state(rig, spec.name if spec is not None else "auto", s, meta)
    write_state(out, doc)
    return _rounds(rig, out, spec, s, doc, pairs=pairs, on_round=on_round, log=log)


def resume_adaptive(
    out: str | Path,
    spec_of: Callable[[str], FitSpec | None],
    *,
    pairs: ErrorPairs | None = None,
    on_round: Callable[[Round], None] | None = None,
    log: Callable[[str], None] | None = None,
) -> AdaptiveResult:
    """Continue an interrupted adaptive sweep in ``out`` (see the module docstring); ``spec_of`` turns the model
    name its state records (``"auto"``: None) back into a FitSpec."""
    out = Path(out)
    doc = read_state(out)
    if doc["state"] == "finished":
        raise AdaptiveStateError(f"{out}: the adaptive sweep is finished ({out / 'samples.csv'}); nothing to resume")
    try:
        s = AdaptiveSettings(**doc["settings"])
    except (TypeError, ValueError) as exc:
        raise AdaptiveStateError(f"{out / 'adaptive.json'}: settings: {exc}") from None
    spec = None if doc["model"] == "auto" else spec_of(str(doc["model"]))
    return _rounds(rig_of(doc, out), out, spec, s, doc, pairs=pairs, on_round=on_round, log=log)


def _pool(rig: RigConfig, s: AdaptiveSettings) -> FloatArray:
    """The sweep's reachable candidates; ConfigError if fewer than the budget."""
    pool = candidate_points(rig.geometry, s.candidates, max_theta_deg=s.max_theta_deg, seed=s.seed)
    if len(pool) < s.budget:
        raise ConfigError(f"{rig.path}: only {len(pool)} of {s.candidates} candidates are reachable; need {s.budget}")
    return pool


def _rounds(
    rig: RigConfig,
    out: Path,
    spec: FitSpec | None,
    s: AdaptiveSettings,
    doc: dict[str, Any],
    *,
    pairs: ErrorPairs | None,
    on_round: Callable[[Round], None] | None,
    log: Callable[[str], None] | None,
) -> AdaptiveResult:
    from rig.run.session import make_plan

    say = log or (lambda msg: print(msg, file=sys.stderr))
    pairs = pairs or error_pairs(max_theta_deg=s.max_theta_deg, seed=s.seed + 1)
    pool = _pool(rig, s)
    rig = with_reference_snr(rig, s.reference_snr)
    result = AdaptiveResult()
    rows: list[dict[str, Any]] = []
    captures = 0
    todo = space_filling(pool, s.initial)
    predicted = float("nan")
    while True:
        r = len(result.rounds)
        directory, here, points = out / f"round-{r:02d}", round_rig(rig, r), pool[todo]
        planned = make_plan(here, _round_sweep(points, directory.name, {"target_snr": s.target_snr}, None))
        choice = round_choice(here, s, r, planned)
        new_rows, rig_s = measure_points(here, points, directory, s.target_snr, doc.get("metadata"),
                                         capture=round_capture(s, choice))  # fmt: skip
        pool = np.delete(pool, todo, axis=0)
        rows += [{**row, "round": r} for row in new_rows]
        captures += _captures(directory)
        # Weighted by each sample's own error: the design trades SNR against position, and the common
        # calibration share would hide what a better capture buys.
        samples = Samples.from_table_rows(rows, source=str(out), errors="point")
        tiles = any(_is_tile(row) for row in rows)
        try:
            res, used, weighted = _fit(samples, spec, s.starts, s.seed, angular=tiles)
        except FitError as exc:
            raise FitError(f"{directory}: round {r} cannot be fitted ({len(rows)} samples): {exc}") from None
        rnd = Round(r, captures, rig_s, res, predicted, directory, len(rows), choice.mode, choice.motion,
                    choice.reason)  # fmt: skip
        result.rounds.append(rnd)
        write_state(out, {**doc, "rounds": _round_docs(result)})
        say(f"round {r}: {captures} captures ({len(todo)} in {choice.mode} mode, {choice.motion}: {len(new_rows)} "
            f"samples), {rig_s:.0f} s rig time, {used.name} chi2/dof {res.reduced_chi2:.2f}")  # fmt: skip
        if on_round is not None:
            on_round(rnd)
        k = min(s.batch, s.budget - captures)
        if k <= 0:
            break
        mode = next_mode(s)
        # Point mode alone keeps its own noise estimate (every sample a point); with tiles, the next mode's own.
        rel = _relative_noise(rows, mode == "image", s.target_snr) if tiles else None
        if mode == "image":
            sub = image_subset(len(pool), s.seed, r + 1)
            cells = footprints(rig, s, pool[sub])
            picked, before, predicted = next_points(res, used, weighted, pool[sub], k, pairs, rel=rel, cells=cells)
            todo = sub[picked]
        else:
            todo, before, predicted = next_points(res, used, weighted, pool, k, pairs, rel=rel)
        say(f"  next {k} captures ({mode} mode): predicted relative BRDF error {before:.2e} -> {predicted:.2e}")
    result.table = _write(out, rows, result, doc)
    return result


def _is_tile(row: dict[str, Any]) -> bool:
    """Whether a table row is an image-mode tile (its ``tile`` column set)."""
    return row.get("tile") not in (None, "")


def _relative_noise(rows: Sequence[dict[str, Any]], tiles: bool, snr: float) -> float:
    """The median relative error of one reading among the rows that are (or are not) tiles; 1 / snr for none."""
    rel = []
    for row in rows:
        if _is_tile(row) != tiles:
            continue
        for c in ("r", "g", "b"):
            try:
                v, e = float(row[f"reading_{c}"]), float(row[f"reading_se_{c}"])
            except (KeyError, TypeError, ValueError):
                continue
            if v != 0 and math.isfinite(v) and math.isfinite(e):
                rel.append(abs(e / v))
    return float(np.median(rel)) if rel else 1.0 / snr


def _round_docs(result: AdaptiveResult) -> list[dict[str, Any]]:
    return [{"round": r.index, "captures": r.captures, "samples": r.samples, "mode": r.mode, "motion": r.motion,
             "mode_reason": r.reason, "rig_time_s": r.rig_time_s, "model": r.fit.spec,
             "params": dict(zip(r.fit.names, r.fit.values.tolist(), strict=True)),
             "reduced_chi2": r.fit.reduced_chi2, "predicted_error": r.predicted_error,
             "directory": str(r.directory)} for r in result.rounds]  # fmt: skip


def _write(out: Path, rows: Sequence[dict[str, Any]], result: AdaptiveResult, doc: dict[str, Any]) -> Path:
    table = out / "samples.csv"
    names = list(dict.fromkeys(k for row in rows for k in row))
    with open(table, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=names)
        w.writeheader()
        w.writerows(rows)
    write_beside(table, rows, doc.get("metadata"))
    write_state(out, {**doc, "state": "finished", "rounds": _round_docs(result)})
    return table
