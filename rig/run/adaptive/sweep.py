"""An adaptive sweep: measure a few points, fit, then measure where the fit is least certain, and repeat.

Each round is an ordinary run (a ``list`` sweep in ``OUT/round-NN``, with its own reference readings,
journal and table), so everything a run guarantees holds per round: safe stops, resume, calibration.
Between rounds the samples of every round so far are fitted with one :class:`model.fit.spec.FitSpec`
(or the model chosen by :func:`model.fit.select.select`), and :func:`model.fit.design.choose_batch` picks
the next round's points from a pool of reachable candidates: those that most lower the fit's expected
BRDF error over the hemisphere (see model/fit/design.py).

Candidates: cosine-distributed pairs (the diffuse body) plus Rusinkiewicz pairs with theta_h drawn
densely near 0 (the specular lobe, where a narrow peak hides between cosine-random points), all with
phi_i = 0 for isotropic samples and filtered by the rig's kinematics. The first round is a space-filling
pick over the candidates in (theta_h, theta_d, phi_d), since there is no fit to ask yet.

Written to OUT: ``samples.csv`` (every round's table rows, with a ``round`` column; ``samples.parquet`` and
``samples.schema.json`` beside it) and ``adaptive.json`` (:mod:`rig.run.adaptive.state`: the settings, model
and rig a resume needs, and per round: points, rig time, the fit's parameters, the measured and predicted errors).

Resume (:func:`resume_adaptive`, ``gonio adaptive --resume OUT`` or ``gonio resume OUT``). Every step but the
measuring is a function of the settings and the rounds' tables (the pool is seeded, the fits are seeded and
deterministic), so a resume replays the sweep: rounds whose run finished are read back, the round that was
interrupted is resumed as any run is (its journal keeps what it measured), and the rest are measured. Each
replayed round's points are checked against its run's manifest, so a sweep whose settings or rig changed is
refused instead of continued with other points. A resumed sweep ends with the table of an uninterrupted one
(but for the ``utc`` column: when each point was really measured).
"""

from __future__ import annotations

import csv
import dataclasses
import sys
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from model.fit.design import (
    ErrorPairs,
    choose_batch,
    cosine_zeniths,
    covariance,
    error_pairs,
    error_weight,
    fisher,
    sensitivities,
)
from model.fit.samples import FitError, Samples
from model.fit.select import default_ladder, select
from model.fit.solve import FitResult, fit
from model.fit.spec import FitSpec
from model.geometry import degrees_to_vector
from rig.instrument.kinematics import solve_degrees
from rig.run.adaptive.state import AdaptiveStateError, new_state, read_state, rig_of, write_state
from rig.run.config.files import ConfigError, RigConfig, parse, sweep_config
from rig.run.config.schema import SweepFile
from rig.run.config.sweeps import directions_to_half_diff, half_diff_to_directions
from rig.run.storage.store import RunStore, RunStoreError
from rig.run.tables.parquet import write_beside

FloatArray = npt.NDArray[np.float64]
#: Relative noise assumed where a fitted value is below this fraction of the median (keeps sigma > 0).
NOISE_FLOOR = 1e-3


@dataclass(frozen=True)
class AdaptiveSettings:
    """How an adaptive sweep spends its captures.

    budget: captures in all; initial: captures of the first (space-filling) round; batch: captures per
    later round; candidates: pool size before the reachability filter; max_theta_deg: largest zenith
    (deg) of candidates and of the error pairs; target_snr: the capture's SNR goal; reference_snr: the
    reference readings' SNR goal (None: the rig's ``[reference] target_snr``); seed: pool and fits.

    Each round is its own run with a reference reading before and after, so a sweep of 100 takes about 18
    readings where one run of 1000 at ``every = 25`` takes 42. A matte sample's fit is one scale per channel,
    i.e. all calibration: the references need SNR x sqrt(42 / 18) to calibrate as well as that long run.
    """

    budget: int = 100
    initial: int = 20
    batch: int = 10
    candidates: int = 6000
    max_theta_deg: float = 70.0
    target_snr: float = 100.0
    reference_snr: float | None = None
    starts: int = 4
    seed: int = 0

    def __post_init__(self) -> None:
        if not 1 <= self.initial <= self.budget or self.batch < 1 or self.candidates < self.budget:
            raise ValueError(
                f"adaptive settings: need 1 <= initial ({self.initial}) <= budget ({self.budget}), batch "
                f"({self.batch}) >= 1 and candidates ({self.candidates}) >= budget"
            )
        if not 0.0 < self.max_theta_deg <= 90.0:
            raise ValueError(f"adaptive settings: max_theta_deg ({self.max_theta_deg}) must be a zenith in (0, 90]")
        if not self.target_snr > 0 or (self.reference_snr is not None and not self.reference_snr > 0):
            raise ValueError(f"adaptive settings: target_snr ({self.target_snr}) and reference_snr "
                             f"({self.reference_snr}) must be > 0")  # fmt: skip


@dataclass(frozen=True)
class Round:
    """One round: captures so far, this round's rig time (s), the fit after it, and the predicted error."""

    index: int
    captures: int
    rig_time_s: float
    fit: FitResult
    predicted_error: float
    directory: Path


@dataclass
class AdaptiveResult:
    """Every round of an adaptive sweep, and where its merged table is."""

    rounds: list[Round] = field(default_factory=list)
    table: Path | None = None

    @property
    def rig_time_s(self) -> float:
        """Rig time of all rounds (s)."""
        return sum(r.rig_time_s for r in self.rounds)


def candidate_points(geometry: Any, n: int, *, max_theta_deg: float = 80.0, seed: int = 0) -> FloatArray:
    """Up to n reachable isotropic candidates (N, 4) in degrees: half cosine-random, half near-specular."""
    rng = np.random.default_rng(seed)
    m = n // 2
    ti, to = (cosine_zeniths(rng, n - m, max_theta_deg) for _ in range(2))
    body = np.stack([ti, np.zeros(n - m), to, rng.uniform(0.0, 180.0, n - m)], axis=-1)
    # theta_h = 90 u^2 puts half the lobe candidates within 22.5 deg of the mirror direction.
    hd = half_diff_to_directions(90.0 * rng.uniform(0, 1, m) ** 2, rng.uniform(0.0, max_theta_deg, m),
                                 rng.uniform(0.0, 180.0, m), rng.uniform(0.0, 360.0, m))  # fmt: skip
    # Turn each pair about the normal so that phi_i = 0: the same geometry for an isotropic sample.
    lobe = np.stack([hd[:, 0], np.zeros(m), hd[:, 2], (hd[:, 3] - hd[:, 1]) % 360.0], axis=-1)
    pts = np.concatenate([body, lobe])
    pts[:, 3] = np.where(pts[:, 3] > 180.0, 360.0 - pts[:, 3], pts[:, 3])  # mirror: isotropic
    ok = (pts[:, 0] <= max_theta_deg) & (pts[:, 2] <= max_theta_deg)
    pts = pts[ok]
    reach = solve_degrees(geometry, pts[:, 0], pts[:, 1], pts[:, 2], pts[:, 3]).reachable
    return pts[np.asarray(reach, dtype=bool)]


def space_filling(points_deg: FloatArray, k: int) -> npt.NDArray[np.intp]:
    """k indices of points spread over (theta_h, theta_d, phi_d) by farthest-point selection."""
    hd = directions_to_half_diff(points_deg)
    x = np.stack([hd[:, 0] / 90.0, hd[:, 1] / 90.0, np.abs(hd[:, 2]) / 180.0], axis=-1)
    picked = [int(np.argmin(hd[:, 0] + hd[:, 1]))]
    d = np.linalg.norm(x - x[picked[0]], axis=1)
    for _ in range(k - 1):
        j = int(np.argmax(d))
        picked.append(j)
        d = np.minimum(d, np.linalg.norm(x - x[j], axis=1))
    return np.asarray(picked, dtype=np.intp)


def _values(model: Any, wi: npt.NDArray[np.floating], wo: npt.NDArray[np.floating], channels: int) -> FloatArray:
    f = np.asarray(model.eval(wi, wo), dtype=np.float64).reshape(len(wi), -1)
    return np.broadcast_to(f, (len(wi), channels))


def next_points(
    result: FitResult, spec: FitSpec, samples: Samples, pool: FloatArray, k: int, pairs: ErrorPairs
) -> tuple[npt.NDArray[np.intp], float, float]:
    """Indices of the k pool points to measure next, the predicted error now and after them (relative RMS)."""
    c = samples.channels
    rel = float(np.median(samples.std_error / np.maximum(np.abs(samples.value), 1e-300)))

    def sigma(f: FloatArray) -> FloatArray:
        return rel * np.maximum(np.abs(f), NOISE_FLOOR * float(np.median(np.abs(f))) + 1e-300)

    x = result.values
    g_meas = sensitivities(spec, x, samples.wi, samples.wo, c)
    cov = covariance(fisher(g_meas, samples.std_error))
    a = error_weight(sensitivities(spec, x, pairs.wi, pairs.wo, c), _values(result.model, pairs.wi, pairs.wo, c))
    wi, wo = degrees_to_vector(pool[:, 0], pool[:, 1]), degrees_to_vector(pool[:, 2], pool[:, 3])
    g = sensitivities(spec, x, wi, wo, c)
    batch = choose_batch(cov, g, sigma(_values(result.model, wi, wo, c)), a, k)
    return batch.indices, batch.error_before, float(batch.error_after[-1])


def _fit(samples: Samples, spec: FitSpec | None, starts: int, seed: int) -> tuple[FitResult, FitSpec]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # early rounds are expected to be under-determined
        if spec is not None:
            return fit(spec, samples, starts=starts, seed=seed, warn=False), spec
        sel = select(samples, starts=starts, seed=seed)
        return sel.chosen, next(s for s in default_ladder() if s.name == sel.chosen_name)


def measure_points(
    rig: RigConfig, points: FloatArray, out: Path, snr: float, metadata: dict[str, Any] | None = None
) -> tuple[list[dict[str, Any]], float]:
    """Run the points (N, 4) in degrees as a list sweep into ``out``: the table's rows and the rig time (s).

    Where ``out`` already holds this round's run, it is read back (finished) or resumed (stopped or killed);
    its points must be ``points``, or AdaptiveStateError says the sweep changed.
    """
    from rig.run.session import start_run

    if out.exists():
        return _existing_round(out, points)
    table = {"name": f"list sweep {out.name}", "sweep": {"kind": "list", "points": points.tolist()},
             "capture": {"target_snr": snr}, "metadata": metadata or {}}  # fmt: skip
    sweep = sweep_config(parse(table, SweepFile, f"<{out.name}>"), f"<{out.name}>")
    summary = start_run(rig, sweep, out, progress=False)
    return _rows(Path(summary.table)), summary.rig_time_s


def _rows(table: Path) -> list[dict[str, Any]]:
    with open(table, newline="") as fh:
        return list(csv.DictReader(fh))


def _existing_round(out: Path, points: FloatArray) -> tuple[list[dict[str, Any]], float]:
    """A round found on disk by a resume: check its points, finish it if it stopped, return rows and rig time."""
    from rig.run.session import resume_run

    try:
        store = RunStore.read(out)
    except RunStoreError as exc:
        raise AdaptiveStateError(f"{out}: this round's run cannot be read ({exc})") from None
    planned = np.asarray(store.manifest.get("sweep", {}).get("sweep", {}).get("points", []), dtype=float)
    if planned.shape != points.shape or not np.allclose(planned, points, rtol=0.0, atol=1e-9):
        raise AdaptiveStateError(
            f"{out}: its run measured other points than this sweep chooses for the round: the settings, the rig or "
            "gonio changed since it started; resume with the same gonio, or start a new sweep"
        )
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
    say = log or (lambda msg: print(msg, file=sys.stderr))
    pairs = pairs or error_pairs(max_theta_deg=s.max_theta_deg, seed=s.seed + 1)
    pool = _pool(rig, s)
    rig = with_reference_snr(rig, s.reference_snr)
    result = AdaptiveResult()
    rows: list[dict[str, Any]] = []
    todo = space_filling(pool, s.initial)
    predicted = float("nan")
    while True:
        r = len(result.rounds)
        directory = out / f"round-{r:02d}"
        new_rows, rig_s = measure_points(round_rig(rig, r), pool[todo], directory, s.target_snr, doc.get("metadata"))
        pool = np.delete(pool, todo, axis=0)
        rows += [{**row, "round": r} for row in new_rows]
        # Weighted by each capture's own error: the design trades SNR against position, and the common
        # calibration share would hide what a better capture buys.
        samples = Samples.from_table_rows(rows, source=str(out), errors="point")
        try:
            res, used = _fit(samples, spec, s.starts, s.seed)
        except FitError as exc:
            raise FitError(f"{directory}: round {r} cannot be fitted ({len(rows)} samples): {exc}") from None
        rnd = Round(r, len(rows), rig_s, res, predicted, directory)
        result.rounds.append(rnd)
        write_state(out, {**doc, "rounds": _round_docs(result)})
        say(f"round {r}: {len(rows)} captures, {rig_s:.0f} s rig time, {used.name} chi2/dof {res.reduced_chi2:.2f}")
        if on_round is not None:
            on_round(rnd)
        k = min(s.batch, s.budget - len(rows))
        if k <= 0:
            break
        todo, before, predicted = next_points(res, used, samples, pool, k, pairs)
        say(f"  next {k} points: predicted relative BRDF error {before:.2e} -> {predicted:.2e}")
    result.table = _write(out, rows, result, doc)
    return result


def _round_docs(result: AdaptiveResult) -> list[dict[str, Any]]:
    return [{"round": r.index, "captures": r.captures, "rig_time_s": r.rig_time_s, "model": r.fit.spec,
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
