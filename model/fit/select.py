"""Model selection: fit a ladder of candidates, from Lambert upward, and keep only what the data require.

Every candidate is fitted with :func:`model.fit.fit`; each gets chi2 against the samples' std errors and an
information criterion (AIC = chi2 + 2k or BIC = chi2 + k ln n for Gaussian errors of known size, n the
number of residuals). The choice is the candidate with the fewest parameters whose criterion is within
``delta`` of the lowest: a richer model must earn its extra parameters by lowering chi2 by more than
their penalty. Whether the chosen model's residuals reach the noise (reduced chi2 about 1) is reported
beside it: if none does, the ladder lacks the right model (or the std errors are too small) and the reason
says so. Candidates the data cannot support (too few samples, anisotropy from one plane) are listed with
the error instead of a fit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from model.fit.samples import FitError, Samples
from model.fit.solve import FitResult, fit
from model.fit.spec import LAMBERT, FitSpec, lambert_ggx, ward_anisotropic

CRITERIA = ("aic", "bic")


def default_ladder() -> list[FitSpec]:
    """Lambert; Lambert + GGX (dielectric, 5 on RGB); + coloured Schlick specular (7); anisotropic Ward (6)."""
    return [LAMBERT, lambert_ggx("dielectric"), lambert_ggx("schlick").per_channel("f0"), ward_anisotropic()]


@dataclass(frozen=True, eq=False)
class Candidate:
    """One rung of the ladder: its fit, or why it could not be fitted."""

    name: str
    n_params: int
    result: FitResult | None
    error: str | None = None

    def criterion(self, which: str) -> float:
        """AIC or BIC of the fit (inf if it was not fitted)."""
        if self.result is None:
            return float("inf")
        return self.result.aic if which == "aic" else self.result.bic


@dataclass(frozen=True, eq=False)
class Selection:
    """The candidates in ladder order, the chosen one, the criterion used and a one-paragraph reason."""

    candidates: tuple[Candidate, ...]
    chosen: FitResult
    criterion: str
    delta: float
    reason: str

    @property
    def chosen_name(self) -> str:
        """Name of the chosen candidate's spec."""
        return self.chosen.spec

    def table(self) -> str:
        """A plain-text table: name, k, chi2, dof, reduced chi2, AIC, BIC, Delta criterion, at noise."""
        best = min(c.criterion(self.criterion) for c in self.candidates)
        lines = [f"{'candidate':<28} {'k':>3} {'chi2':>11} {'dof':>7} {'chi2/dof':>9} {'AIC':>11} {'BIC':>11}"
                 f" {'d' + self.criterion.upper():>9}  noise"]  # fmt: skip
        for c in self.candidates:
            mark = "*" if c.result is self.chosen else " "
            if c.result is None:
                lines.append(f"{mark}{c.name:<27} {c.n_params:>3}  not fitted: {c.error}")
                continue
            r = c.result
            lines.append(
                f"{mark}{c.name:<27} {c.n_params:>3} {r.chi2:>11.5g} {r.dof:>7} {r.reduced_chi2:>9.4g} {r.aic:>11.5g}"
                f" {r.bic:>11.5g} {c.criterion(self.criterion) - best:>9.3g}  {'yes' if r.noise_reached else 'no'}"
            )
        return "\n".join(lines)


def _reason(cands: Sequence[Candidate], chosen: Candidate, crit: str, delta: float) -> str:
    """One paragraph: why the chosen candidate, why not the simpler ones, why not the richer ones."""
    r = chosen.result
    assert r is not None
    ic = {c.name: c.criterion(crit) for c in cands}
    best = min(ic.values())
    name = crit.upper()
    tol = 1.0 + 3.0 * np.sqrt(2.0 / r.dof)
    parts = [
        f"Chose {chosen.name} ({chosen.n_params} parameters): chi2/dof = {r.reduced_chi2:.3g} "
        f"(noise alone gives 1, up to {tol:.3g}), {name} {ic[chosen.name] - best:+.3g} from the lowest."
    ]
    for c in cands:
        if c is chosen:
            continue
        if c.result is None:
            parts.append(f"{c.name} could not be fitted ({c.error}).")
            continue
        d_ic = ic[c.name] - ic[chosen.name]
        d_chi2 = r.chi2 - c.result.chi2
        if c.n_params < chosen.n_params:
            parts.append(
                f"The simpler {c.name} was not enough: its chi2/dof is {c.result.reduced_chi2:.3g}"
                f"{' (above the noise)' if not c.result.noise_reached else ''} and its {name} is higher by {d_ic:.3g}."
            )
        else:
            extra = c.n_params - chosen.n_params
            plural = "s" if extra != 1 else ""
            if d_chi2 <= 0:
                parts.append(
                    f"{c.name} was not needed: with {extra} more parameter{plural} it fits worse "
                    f"(chi2 higher by {-d_chi2:.3g}, {name} higher by {d_ic:.3g})."
                )
            else:
                why = f"within {delta:g} of the lowest, so the fewer parameters win" if d_ic <= 0 else "higher"
                parts.append(
                    f"{c.name} was not needed: {extra} more parameter{plural} lowered chi2 by only {d_chi2:.3g}, "
                    f"{name} {why} ({d_ic:+.3g})."
                )
    if not r.noise_reached:
        parts.append(
            "No fitted candidate brings the residuals down to the noise: the ladder lacks a model of some "
            "structure in the data, or the std errors are underestimated; treat the parameters' std errors "
            "as inflated estimates."
        )
    elif r.std_error_assumed:
        parts.append("The std errors are assumed, not measured, so chi2 judges against that assumption.")
    return " ".join(parts)


def select(
    samples: Samples,
    ladder: Sequence[FitSpec] | None = None,
    *,
    criterion: str = "bic",
    delta: float = 2.0,
    loss: str = "l2",
    robust: str | None = None,
    starts: int = 4,
    seed: int = 0,
) -> Selection:
    """Fit each candidate of the ladder (default :func:`default_ladder`) and choose; see the module docstring."""
    if criterion not in CRITERIA:
        raise FitError(f"select: criterion {criterion!r}; expected one of {CRITERIA}")
    specs = list(default_ladder() if ladder is None else ladder)
    cands = []
    for spec in specs:
        k = len(spec.labels(samples.channels))
        try:
            res = fit(spec, samples, loss, robust, starts=starts, seed=seed, warn=False)
        except FitError as exc:
            cands.append(Candidate(spec.name, k, None, str(exc)))
            continue
        cands.append(Candidate(spec.name, k, res))
    return choose(cands, criterion, delta)


def choose(cands: Sequence[Candidate], criterion: str = "bic", delta: float = 2.0) -> Selection:
    """The selection among fitted candidates: fewest parameters within delta of the best criterion, and why."""
    fitted = [c for c in cands if c.result is not None]
    if not fitted:
        raise FitError("select: no candidate could be fitted:\n" + "\n".join(f"  {c.name}: {c.error}" for c in cands))
    best = min(c.criterion(criterion) for c in fitted)
    # Fewest parameters first; ties keep ladder order.
    ok = [c for c in fitted if c.criterion(criterion) <= best + delta]
    chosen = min(ok, key=lambda c: (c.n_params, list(cands).index(c)))
    assert chosen.result is not None
    return Selection(tuple(cands), chosen.result, criterion, delta, _reason(cands, chosen, criterion, delta))
