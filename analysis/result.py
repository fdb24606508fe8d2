"""What one analysis produced: the source it read, the samples, the fitted ladder and its choice.

:class:`Analysis` is the one result type the report's figures (analysis/report/plots.py), its page
(analysis/report/html.py) and ``fit.json`` (analysis/analyze.py) read; it lives below all of them, so
none of them imports another to get its data.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from analysis.parameters import parameter_status, undetermined_text
from model.base import BRDF
from model.errors import InputError
from model.fit.samples import Samples
from model.fit.select import Candidate, Selection
from model.fit.solve import FitResult
from model.fit.spec import FitSpec

Log = Callable[[str], None]

#: Below this p-value residuals are not called "at the noise", whatever the 3-sigma test of chi2/dof says.
P_AT_NOISE = 0.05
#: Above this p-value chi2 is suspiciously small: the std errors are probably overestimated.
P_TOO_GOOD = 0.999
#: How an Analysis renders in Jupyter; analysis.report.notebook registers its renderer here (the page's pieces sit
#: above this module, so they cannot be imported from it).
HTML_REPR: list[Callable[[Any], str]] = []


def noise_words(r: FitResult) -> str:
    """How the residuals compare with the noise, in words that agree with the p-value printed beside them.

    The selection's test (chi2/dof within 3 sigma of 1, ``FitResult.noise_reached``) accepts fits with p down to
    about 0.003; calling those "at the noise" beside p = 0.0147 reads as a contradiction, so they are "slightly
    above the noise" here (the choice itself is unchanged).
    """
    p = r.p_value
    if p != p:  # NaN: no degrees of freedom
        return "untested (no degrees of freedom)"
    if p > P_TOO_GOOD:
        return f"below the noise (p = {p:.3g}: the std errors look overestimated)"
    if p >= P_AT_NOISE:
        return f"at the noise (p = {p:.3g})"
    if r.noise_reached:
        return f"slightly above the noise (p = {p:.3g})"
    return f"above the noise (p = {p:.2g})"


class AnalysisError(InputError, ValueError):
    """The source cannot be analysed (missing, not a run, unreadable, too little data); names the path."""


@dataclass(frozen=True)
class SourceSummary:
    """What was analysed: a run (status, points measured/planned/unreachable, sweep, material) or a MERL file."""

    kind: str  # "run", "adaptive" (an adaptive sweep's rounds), "table" (a samples table alone) or "merl"
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
    #: The run's ``[metadata]`` (sample, operator, notes, free keys) as (key, value) pairs, values JSON.
    metadata: tuple[tuple[str, Any], ...] = ()

    @property
    def warning(self) -> str | None:
        """The banner for an unfinished run ("run stopped: <reason>; N of M points"), else None."""
        if self.kind not in ("run", "adaptive") or self.state == "finished":
            return None
        of = f"{self.measured} of {self.planned} points"
        if self.kind == "adaptive":
            return f"adaptive sweep not finished: {self.stop_reason}; {of}"
        if self.state == "stopped":
            return f"run stopped: {self.stop_reason or 'no reason recorded'}; {of}"
        return f"run not finished (no status.json: still running or killed); {of}"

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (for fit.json)."""
        return {**dataclasses.asdict(self), "path": str(self.path), "notes": list(self.notes),
                "metadata": dict(self.metadata)}  # fmt: skip


@dataclass(frozen=True)
class Reference:
    """A BRDF drawn beside the fits on the slices: the simulated material, the MERL source, a --compare file."""

    label: str
    brdf: BRDF
    #: The errors a comparison with this reference should use, (N, C) in 1/sr (None: the samples' own).
    std_error: npt.NDArray[np.float64] | None = None


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
    #: The chosen model's angular variance per sample (N, C) in (1/sr)^2 (model.fit.angular); None when the
    #: samples carry no direction covariance.
    angular_variance: npt.NDArray[np.float64] | None = None

    def effective_std_error(self) -> npt.NDArray[np.float64]:
        """Each sample's error with its angular share (N, C) in 1/sr: what the chosen fit weighted by."""
        if self.angular_variance is None:
            return np.asarray(self.samples.std_error, dtype=np.float64)
        return np.sqrt(np.square(self.samples.std_error) + self.angular_variance)

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
        return (f"chosen: {r.spec} ({type(r.model).__name__}, {r.n_params} parameters), chi2/dof = "
                f"{r.reduced_chi2:.3g}, residuals {noise_words(r)} on {r.n_samples} samples")  # fmt: skip

    def _repr_html_(self) -> str:
        """Jupyter's display: the verdict, parameters, selection and key figures (plain text if none registered)."""
        if HTML_REPR:
            return HTML_REPR[0](self)
        from html import escape

        return f"<pre>{escape(self.text())}</pre>"

    def text(self) -> str:
        """What ``gonio analyze`` prints: the verdict, then each parameter of the chosen model and what pins it."""
        r = self.selection.chosen
        status = parameter_status(r, self.spec(r.spec), self.samples.channels)
        width = max(len(p.name) for p in status)
        lines = [self.verdict()]
        for p in status:
            note = p.note()
            lines.append(f"  {p.name:>{width}} = {p.value_text()}" + (f"  [{note}]" if note else ""))
        problem = undetermined_text(status)
        if problem:
            lines.append(problem)
        return "\n".join(lines)
