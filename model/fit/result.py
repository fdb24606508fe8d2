"""A fit's result: the fitted model, its parameters with std errors, the goodness of fit and the warnings.

``fit`` (model/fit/solve.py) makes them; the module docstring there says how each number is computed.
"""

from __future__ import annotations

from dataclasses import dataclass
from html import escape

import numpy as np
import numpy.typing as npt

from model.base import Model

Array = npt.NDArray[np.float64]


class FitWarning(UserWarning):
    """A fit succeeded but some of its numbers deserve less trust than they seem to (see the message)."""


@dataclass(frozen=True, eq=False)
class FitResult:
    """A fitted model with its parameters, their std errors (field units) and the goodness of fit.

    ``residuals`` (N, C) are (model - value) / std_error at the ordinary samples used; ``chi2`` their sum
    of squares over ``dof`` = N C - n_params degrees of freedom; ``loss_value`` the optimiser's cost
    (0.5 sum rho(r^2), constraints included). ``n_bounds`` saturated samples entered as lower bounds;
    ``bound_chi2`` is the sum of their squared shortfalls max(0, value - model) / std_error (0 when the
    model clears every bound; computed in "exclude" mode too).
    """

    spec: str
    model: Model
    names: tuple[str, ...]
    values: Array
    std_errors: Array
    covariance: Array
    residuals: Array
    chi2: float
    dof: int
    loss: str
    robust: str | None
    loss_value: float
    n_samples: int
    n_excluded: int
    n_starts: int
    n_starts_agreeing: int
    std_error_assumed: bool
    warnings: tuple[str, ...]
    n_bounds: int = 0
    bound_chi2: float = 0.0

    @property
    def n_params(self) -> int:
        """Number of fitted numbers."""
        return len(self.names)

    @property
    def reduced_chi2(self) -> float:
        """chi2 / dof; about 1 when the residuals are at the level of the std errors."""
        return self.chi2 / self.dof if self.dof > 0 else float("nan")

    @property
    def p_value(self) -> float:
        """Probability of a chi2 at least this large if the model were true and the errors right."""
        # chdtrc is chi2's survival function itself; scipy.stats would import far more than one function needs.
        from scipy import special  # here: a process that only reads fit results need not load scipy

        return float(special.chdtrc(self.dof, self.chi2)) if self.dof > 0 else float("nan")

    @property
    def noise_reached(self) -> bool:
        """Whether the reduced chi2 is within 3 standard deviations of 1 (residuals at the noise)."""
        return bool(self.dof > 0 and self.reduced_chi2 <= 1.0 + 3.0 * np.sqrt(2.0 / self.dof))

    @property
    def aic(self) -> float:
        """Akaike's criterion for Gaussian errors of known size: chi2 + 2 k."""
        return self.chi2 + 2.0 * self.n_params

    @property
    def bic(self) -> float:
        """Schwarz's Bayesian criterion: chi2 + k ln(n), n = number of residuals."""
        return self.chi2 + self.n_params * float(np.log(self.residuals.size))

    def param(self, name: str) -> tuple[float, float]:
        """(value, std error) of one fitted number by label, e.g. "alpha" or "rho_d_r"."""
        i = self.names.index(name)
        return float(self.values[i]), float(self.std_errors[i])

    def summary(self) -> str:
        """A few lines of text: parameters +- std errors, chi2, and the warnings."""
        noise = "assumed" if self.std_error_assumed else "measured"
        lines = [
            f"{self.spec} fit to {self.n_samples} samples ({self.n_excluded} excluded"
            + (f", {self.n_bounds} lower bounds, shortfall chi2 {self.bound_chi2:.3g}" if self.n_bounds else "")
            + f"), loss {self.loss}" + (f" ({self.robust})" if self.robust else "")
            + f", {self.n_starts_agreeing}/{self.n_starts} starts agree",
            *(f"  {n:>12} = {v:.6g} +- {e:.2g}" for n, v, e in zip(self.names, self.values, self.std_errors)),  # noqa: B905
            f"  chi2 = {self.chi2:.4g} for {self.dof} dof (reduced {self.reduced_chi2:.3g}, p = {self.p_value:.3g}) "
            f"against the {noise} std errors: residuals {'at' if self.noise_reached else 'above'} the noise",
        ]  # fmt: skip
        return "\n".join(lines + [f"  warning: {w}" for w in self.warnings])

    def _repr_html_(self) -> str:
        """Jupyter's display: the parameters with std errors, chi2 and p, the warnings, the residual histogram."""
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        from model.notebook import figure_img, html_table

        rows = [[n, f"{v:.6g}", f"{e:.2g}"] for n, v, e in zip(self.names, self.values, self.std_errors, strict=True)]
        fig = Figure(figsize=(4.5, 2.6), layout="tight")
        FigureCanvasAgg(fig)
        ax = fig.add_subplot()
        r = self.residuals.reshape(-1)
        ax.hist(np.clip(r[np.isfinite(r)], -5, 5), bins=31, range=(-5.0, 5.0), color="#0072B2")
        ax.set(xlabel="(model − value) / std error, clipped at ±5", ylabel="count", title="residuals")
        warns = "".join(f"<li>{escape(w)}</li>" for w in self.warnings)
        return (f"<div><b>{escape(self.spec)}</b> ({escape(type(self.model).__name__)}): chi2/dof = "
                f"{self.reduced_chi2:.3g}, p = {self.p_value:.3g}, {self.n_samples} samples"
                + html_table(["parameter", "value", "std error"], rows)
                + (f"<ul>{warns}</ul>" if warns else "") + figure_img(fig) + "</div>")  # fmt: skip
