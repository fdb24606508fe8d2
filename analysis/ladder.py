"""The ladder of candidate models: the names ``--models`` accepts, and fitting every candidate.

Candidates are fitted one by one (each timed, its warnings captured for the report), in this process or, with
``jobs`` > 1, in two (this one and a forked helper, each taking the next candidate not yet taken), and chosen
among exactly as :func:`model.fit.select.select` chooses; ``select`` itself has no per-candidate hook, so the
loop lives here and the tests check it agrees with ``select``.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Iterator, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from analysis.progress import stage_bar
from analysis.result import AnalysisError, Log
from model.fit.angular import fit_with_angular
from model.fit.samples import FitError, Samples
from model.fit.select import Candidate, Selection, choose
from model.fit.solve import FitWarning
from model.fit.spec import LAMBERT, FitSpec, blinn_phong, ggx_conductor, lambert_ggx, ward_anisotropic

Array = npt.NDArray[np.float64]

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



#: What fitting one candidate gives: the candidate, its seconds, the warnings it raised, its angular variance.
Outcome = tuple[Candidate, float, list[str], "Array | None"]


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
    angular: dict[str, Array] | None = None,
    progress: bool = False,
    jobs: int = 1,
) -> tuple[Selection, dict[str, float], list[str]]:
    """Fit every candidate (timed, warnings captured) and choose as select() does: (selection, seconds, warnings).

    Samples with a direction covariance are fitted with effective errors (photometric plus angular,
    :func:`model.fit.angular.fit_with_angular`); ``angular``, if given, receives each candidate's angular
    variance per sample (N, C) in (1/sr)^2. ``progress``: a bar with ETA over the candidates (stderr).
    ``jobs`` > 1: a forked process fits candidates beside this one where that is safe (model/runtime.py);
    each candidate's fit is the same either way (its own seeded starts), and so is what is logged, in ladder order.
    """
    from model.runtime import ForkedCall, fork_safe

    def fit_one(i: int) -> Outcome:
        return _fit_candidate(ladder[i], samples, loss, starts, seed)

    outcomes: dict[int, Outcome] = {}
    bar = stage_bar(len(ladder), "fitting", progress, unit="model")
    shown = 0

    def show() -> None:  # the candidates known so far, in ladder order
        nonlocal shown
        while shown in outcomes:
            cand, seconds = outcomes[shown][0], outcomes[shown][1]
            if log:
                r = cand.result
                how = f"chi2/dof = {r.reduced_chi2:.4g}" if r is not None else f"not fitted: {cand.error}"
                log(f"fitting {cand.name} ({cand.n_params} parameters): {how} ({seconds:.2f} s)")
            shown += 1
            if shown < len(ladder):
                bar.set_postfix_str(ladder[shown].name, refresh=False)
            bar.update()

    if len(ladder) > 0:
        bar.set_postfix_str(ladder[0].name, refresh=False)
    if jobs > 1 and len(ladder) > 1 and fork_safe():
        # Both processes take the next candidate not yet taken, so neither waits while the other has two to fit.
        import multiprocessing

        taken = multiprocessing.get_context("fork").Value("i", 0)
        # A helper that dies hands back nothing: the loop below fits what it took.
        with ForkedCall(lambda: {i: fit_one(i) for i in _next_of(taken, len(ladder))}, fork=True,
                        fallback=dict) as other:
            for i in _next_of(taken, len(ladder)):
                outcomes[i] = fit_one(i)
                show()
            outcomes.update(other.result())
    for i in range(len(ladder)):
        if i not in outcomes:
            outcomes[i] = fit_one(i)
        show()
    bar.close()
    cands, times, caught = [], {}, []
    for i in range(len(ladder)):
        cand, seconds, warned, variance = outcomes[i]
        cands.append(cand)
        times[cand.name] = seconds
        caught += warned
        if angular is not None and variance is not None:
            angular[cand.name] = variance
    return choose(cands, criterion, delta), times, list(dict.fromkeys(caught))


def _next_of(taken: Any, n: int) -> Iterator[int]:
    """Indices below n, each handed to one process only (``taken``: a shared counter both processes draw from)."""
    while True:
        with taken.get_lock():
            i = taken.value
            taken.value = i + 1
        if i >= n:
            return
        yield i


def _fit_candidate(spec: FitSpec, samples: Samples, loss: str, starts: int, seed: int) -> Outcome:
    """One candidate fitted, timed, with the warnings it raised (as the report lists them)."""
    k = len(spec.labels(samples.channels))
    start = time.perf_counter()
    variance = None
    with warnings.catch_warnings(record=True) as got:
        warnings.simplefilter("always")
        try:
            result, variance = fit_with_angular(spec, samples, loss, starts=starts, seed=seed)
            cand = Candidate(spec.name, k, result)
        except FitError as exc:
            cand = Candidate(spec.name, k, None, str(exc))
    seconds = time.perf_counter() - start
    # A fit with angular errors is several fits in turn, each warning with its own numbers; only the last
    # fit's notes describe the result (model.fit.solve prefixes them with the spec's name, as here).
    caught = [f"{w.category.__name__}: {w.message}" for w in got if not issubclass(w.category, FitWarning)]
    if cand.result is not None:
        caught += [f"{spec.name}: {note}" for note in cand.result.warnings]
    else:
        caught += [str(w.message) for w in got if issubclass(w.category, FitWarning)]
    return cand, seconds, caught, variance
