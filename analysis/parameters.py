"""What the data pin down: each fitted parameter's bound state, its correlations, and plain words for both.

A parameter the optimiser left at a bound is reported as the bound ("0 (at its lower bound)"), not as the
float the optimiser stopped at (6.26e-24): the data want it at or beyond the bound, and its std error assumes
the bound is not there. A parameter is *not pinned down* when its std error is infinite (the Jacobian is rank
deficient), or more than half its value, or its 2-sigma interval spans more than its whole allowed range; the
reason names the parameters it is correlated with (|rho| >= ``CORRELATED``), strongest first, since a
strongly correlated pair trades one against the other along a valley of equal chi2 (a GGX conductor's eta
and k: raising both keeps the Fresnel reflectance nearly the same).

The covariance is the fit's (model.fit.solve: native units, scaled by chi2/dof when the residuals exceed the
noise); its correlation matrix is cov_ij / sqrt(cov_ii cov_jj), NaN where a variance is zero or infinite.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from model.fit.solve import FitResult
from model.fit.spec import FitSpec

Array = npt.NDArray[np.float64]

#: |correlation| from which two parameters are named as trading against each other.
CORRELATED = 0.9
#: A std error above this fraction of |value| leaves the parameter undetermined.
RELATIVE_LIMIT = 0.5
#: How close (fraction of the range, in the optimiser's coordinate) counts as at a bound, as in model.fit.solve.
AT_BOUND = 1e-6


@dataclass(frozen=True)
class ParamStatus:
    """One fitted number: value and std error (native units), its bounds, and what the data say about it."""

    name: str
    value: float
    std_error: float
    lo: float
    hi: float
    #: "lower", "upper" or None.
    bound: str | None
    #: Whether the data determine it (see the module docstring).
    determined: bool
    #: The other parameters with |correlation| >= CORRELATED, strongest first: (name, rho).
    correlated: tuple[tuple[str, float], ...]

    def value_text(self) -> str:
        """The value as the report prints it: the bound itself when at one, else the value with its std error."""
        if self.bound is not None:
            edge = self.lo if self.bound == "lower" else self.hi
            return f"{edge:.4g} (at its {self.bound} bound)"
        return f"{_num(self.value, '.4g')} ± {_num(self.std_error, '.2g')}"

    def note(self) -> str:
        """Why this parameter is, or is not, pinned down by the data (one phrase; "" when all is well)."""
        parts: list[str] = []
        if self.bound == "lower":
            parts.append(f"the data push it to its lower bound {self.lo:g} or below; the range allows no less")
        elif self.bound == "upper":
            parts.append(f"the data push it to its upper bound {self.hi:g} or above; the range allows no more")
        if not self.determined:
            if not math.isfinite(self.std_error):
                parts.append("not pinned down by the data: the fit does not change with it at all")
            elif self.bound is None:
                ratio = self.std_error / abs(self.value) if self.value else math.inf
                parts.append(f"not pinned down by the data: its std error is {_ratio(ratio)} its value")
            else:
                parts.append("not pinned down by the data")
        if self.correlated and (not self.determined or self.bound is not None):
            with_ = ", ".join(f"{n} (ρ = {r:+.2f})" for n, r in self.correlated)
            parts.append(f"it trades against {with_}: the data fix a combination, not each alone")
        return "; ".join(parts)

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready form (for fit.json's ``parameters``)."""
        return {"value": self.value, "std_error": self.std_error, "lo": self.lo, "hi": self.hi, "bound": self.bound,
                "determined": self.determined, "correlated": {n: r for n, r in self.correlated},
                "note": self.note()}  # fmt: skip


def _num(v: float, fmt: str) -> str:
    return format(v, fmt) if math.isfinite(v) else ("unconstrained" if math.isinf(v) else "n/a")


def _ratio(r: float) -> str:
    return f"{r:.2g} times" if r < 10 else f"{r:.0f} times"


def correlation(cov: npt.ArrayLike) -> Array:
    """The correlation matrix of a covariance (NaN where a variance is zero or not finite); diagonal 1."""
    c = np.asarray(cov, dtype=np.float64)
    sd = np.sqrt(np.diag(c))
    ok = np.isfinite(sd) & (sd > 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = c / np.outer(sd, sd)
    rho = np.where(np.outer(ok, ok), np.clip(rho, -1.0, 1.0), np.nan)
    np.fill_diagonal(rho, np.where(ok, 1.0, np.nan))
    return rho


def _ranges(spec: FitSpec, channels: int) -> tuple[Array, Array, Array]:
    """Per label: lower and upper bound (native units) and whether the optimiser works in log space."""
    sizes = spec.sizes(channels)
    lo = np.concatenate([np.full(k, q.lo) for q, k in zip(spec.params, sizes, strict=True)])
    hi = np.concatenate([np.full(k, q.hi) for q, k in zip(spec.params, sizes, strict=True)])
    log = np.concatenate([np.full(k, q.log) for q, k in zip(spec.params, sizes, strict=True)])
    return lo, hi, log


def parameter_status(result: FitResult, spec: FitSpec, channels: int) -> tuple[ParamStatus, ...]:
    """Every fitted number of ``result`` (fitted with ``spec`` to ``channels`` channels) with its status."""
    lo, hi, log = _ranges(spec, channels)
    x = np.asarray(result.values, dtype=np.float64)
    se = np.asarray(result.std_errors, dtype=np.float64)
    # In the optimiser's coordinate, as the solver judges "at a bound" (log parameters in log space).
    ux, ulo, uhi = (np.where(log, np.log(np.where(log, np.maximum(v, 1e-300), 1.0)), v) for v in (x, lo, hi))
    span = uhi - ulo
    rho = correlation(result.covariance)
    out = []
    for i, name in enumerate(result.names):
        bound = "lower" if ux[i] - ulo[i] < AT_BOUND * span[i] else "upper" if uhi[i] - ux[i] < AT_BOUND * span[i] \
            else None  # fmt: skip
        if not math.isfinite(se[i]):
            determined = False
        elif bound is not None:
            # At a bound the value is the bound; undetermined only if its error spans the whole range.
            determined = 2 * se[i] < hi[i] - lo[i]
        else:
            determined = se[i] <= RELATIVE_LIMIT * abs(x[i]) and 4 * se[i] < hi[i] - lo[i]
        others = [(result.names[j], float(rho[i, j])) for j in range(len(result.names))
                  if j != i and np.isfinite(rho[i, j]) and abs(rho[i, j]) >= CORRELATED]  # fmt: skip
        others.sort(key=lambda t: -abs(t[1]))
        out.append(ParamStatus(name, float(x[i]), float(se[i]), float(lo[i]), float(hi[i]), bound, bool(determined),
                               tuple(others)))  # fmt: skip
    return tuple(out)


def undetermined_text(status: tuple[ParamStatus, ...]) -> str | None:
    """One sentence naming the parameters the data do not pin down and those at a bound; None when neither."""
    loose = [p.name for p in status if not p.determined]
    edge = [f"{p.name} = {p.value_text()}" for p in status if p.bound is not None]
    parts = ([f"not pinned down by the data: {', '.join(loose)}"] if loose else []) + \
        ([f"at a bound: {', '.join(edge)}"] if edge else [])  # fmt: skip
    return "; ".join(parts) if parts else None


def covariance_json(result: FitResult) -> dict[str, Any]:
    """fit.json's ``covariance`` (native units) and ``correlation`` of one fit, rows and columns in
    ``parameter_names`` order (the order of ``params``)."""
    return {
        "parameter_names": list(result.names),
        "covariance": np.asarray(result.covariance, dtype=np.float64).tolist(),
        "correlation": correlation(result.covariance).tolist(),
    }
