"""Fit a model's parameters to BRDF samples: weighted, bounded, multi-start least squares with uncertainties.

Residuals. For a loss with transform g and geometric weight w, the optimiser minimises
sum rho(r^2) over samples and channels with r = w (g(model) - g(value)) / s, where

- "l2":        g(f) = f,                   w = 1 (with s = std_error: chi-square, the maximum likelihood
                                           under Gaussian noise);
- "cosine_l2": g(f) = f,                   w = cos(theta_i) sqrt(sin(theta_i) sin(theta_o)) (Ngan et al.
                                           2005; the sines are the measure of an angle grid);
- "log":       g(f) = log(1 + f cos(theta_i))  (Low et al. 2012);
- "cbrt":      g(f) = f^(1/3), which compresses the specular peak less than log.

``weighted=True`` (default) sets s to the sample's std_error carried through g, (g(y + se) - g(y - se)) / 2,
so every loss is a chi-square in its own coordinates; ``weighted=False`` sets s = 1, as the papers did.
``robust`` ("soft_l1", "huber", "cauchy") down-weights residuals beyond ``f_scale`` (in std errors when
weighted) via scipy.optimize.least_squares.

Uncertainties come from the Jacobian at the optimum with the sandwich formula A^-1 B A^-1, A = J^T J,
B = J^T diag(nu^2) J, nu the std of each residual implied by the std errors; for the weighted losses
nu = 1 and this is (J^T J)^-1. Where residuals exceed the noise (reduced chi2 significantly above 1) the
covariance is scaled by the reduced chi2 and a warning says so. Robust losses are ignored in the
covariance (it is the non-robust estimate at the robust optimum). chi2 is always computed from the
plain residuals (model - value) / std_error, whatever the loss, so fits can be compared.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import optimize, stats

from model._params import ParameterError
from model.base import Model, Pair
from model.fit_samples import FitError, Samples
from model.fit_spec import LAMBERT, FitSpec, Param, blinn_phong, ggx_conductor, lambert_ggx, ward_anisotropic

Array = npt.NDArray[np.float64]
LOSSES = ("l2", "cosine_l2", "log", "cbrt")
ROBUST = (None, "soft_l1", "huber", "cauchy")
#: Singular values of the column-normalised Jacobian below this fraction of the largest mark directions
#: in parameter space the data do not constrain.
RANK_TOL = 1e-7
#: Samples on which several starts are screened before the best is polished on all of them.
SCREEN_SAMPLES = 2000

__all__ = [
    "LAMBERT", "FitError", "FitResult", "FitSpec", "FitWarning", "Param", "Samples", "blinn_phong", "fit",
    "ggx_conductor", "lambert_ggx", "ward_anisotropic",
]  # fmt: skip


class FitWarning(UserWarning):
    """A fit succeeded but some of its numbers deserve less trust than they seem to (see the message)."""


@dataclass(frozen=True, eq=False)
class FitResult:
    """A fitted model with its parameters, their std errors (field units) and the goodness of fit.

    ``residuals`` (N, C) are (model - value) / std_error at the samples used; ``chi2`` their sum of
    squares over ``dof`` = N C - n_params degrees of freedom; ``loss_value`` the optimiser's cost
    (0.5 sum rho(r^2)).
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
        return float(stats.chi2.sf(self.chi2, self.dof)) if self.dof > 0 else float("nan")

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
            f"{self.spec} fit to {self.n_samples} samples ({self.n_excluded} excluded), loss {self.loss}"
            + (f" ({self.robust})" if self.robust else "") + f", {self.n_starts_agreeing}/{self.n_starts} starts agree",
            *(f"  {n:>12} = {v:.6g} +- {e:.2g}" for n, v, e in zip(self.names, self.values, self.std_errors)),  # noqa: B905
            f"  chi2 = {self.chi2:.4g} for {self.dof} dof (reduced {self.reduced_chi2:.3g}, p = {self.p_value:.3g}) "
            f"against the {noise} std errors: residuals {'at' if self.noise_reached else 'above'} the noise",
        ]  # fmt: skip
        return "\n".join(lines + [f"  warning: {w}" for w in self.warnings])


def _predict(spec: FitSpec, x_native: Array, pair: Pair, channels: int, *, validate: bool = False) -> Array:
    """Model values (N, C) in 1/sr at the pairs (all above the horizon), reusing the pair's geometry.

    The numpy path with the cached Pair, not CookTorrance's compiled kernel: inside the optimiser's loop
    the kernel measured no faster here and far noisier (its threads' wake-up), see bench/fit.py.
    """
    m = spec.build(spec.values(x_native, channels), validate=validate)
    with np.errstate(all="ignore"):
        f = m._eval(pair)
    return np.broadcast_to(f, (f.shape[0], channels))


def _transform(loss: str, cos_i: Array) -> tuple[Callable[[Array], Array], bool]:
    if loss == "log":
        return (lambda f: np.log1p(np.maximum(f * cos_i, -1.0 + 1e-12))), True
    if loss == "cbrt":
        return np.cbrt, True
    return (lambda f: f), False


def _coplanar(s: Samples) -> bool:
    """Whether every wi and wo lies in one plane through the origin (e.g. one plane of incidence)."""
    sv = np.linalg.svd(np.concatenate([s.wi, s.wo]), compute_uv=False)
    return bool(sv.size < 3 or sv[2] <= 1e-9 * sv[0])


Groups = list[list[tuple[int, int | None]]]


def _jacobian(f: Callable[[Array], Array], x: Array, groups: Groups, channels: int, f0: Array | None = None) -> Array:
    """Finite-difference Jacobian in the optimiser's coordinates, one evaluation per group of columns.

    Per-channel parameters of one field touch disjoint residuals (their own channel), so a group perturbs
    them together and each column keeps only its channel's rows: a GGX conductor on RGB costs 3
    evaluations per Jacobian instead of 7. Forward differences when f0 = f(x) is given (inside the
    optimiser), central ones otherwise (for the covariance).
    """
    base = f0 if f0 is not None else f(x)
    out = np.zeros((base.size, x.size))
    for grp in groups:
        h = np.zeros_like(x)
        cols = [j for j, _ in grp]
        h[cols] = (1.5e-8 if f0 is not None else 1e-6) * np.maximum(1.0, np.abs(x[cols]))
        diff = f(x + h) - base if f0 is not None else (f(x + h) - f(x - h)) / 2.0
        for j, ch in grp:
            if ch is None:
                out[:, j] = diff / h[j]
            else:
                out[ch::channels, j] = diff[ch::channels] / h[j]
    return out


class _Problem:
    """The objective of one fit over a set of sample rows, in the optimiser's coordinates u."""

    def __init__(self, spec: FitSpec, s: Samples, loss: str, weighted: bool, is_log: Array) -> None:
        self.spec, self.c, self.is_log = spec, s.channels, is_log
        self.pair = Pair(s.wi, s.wo)
        cos_i, cos_o = s.wi[:, 2:3], s.wo[:, 2:3]
        self.g, curved = _transform(loss, cos_i)
        s_noise = (self.g(s.value + s.std_error) - self.g(s.value - s.std_error)) / 2.0 if curved else s.std_error
        scale = s_noise if weighted else np.ones_like(s.value)
        w = np.ones_like(cos_i)
        if loss == "cosine_l2":
            w = cos_i * np.sqrt(np.sqrt(1.0 - cos_i**2) * np.sqrt(1.0 - cos_o**2))
        self.w_over, self.gy = w / scale, self.g(s.value)
        #: std of each objective residual implied by the std errors (1 for the weighted losses)
        self.nu = (w * s_noise / scale).ravel()
        self.groups: Groups = []
        i = 0
        for q, k in zip(spec.params, spec.sizes(self.c), strict=True):
            self.groups.append([(i + ch, ch if q.per_channel else None) for ch in range(k)])
            i += k
        self._last: tuple[Array, Array] | None = None

    def native(self, u: Array) -> Array:
        """Optimiser coordinates to native parameter values."""
        return np.where(self.is_log, np.exp(np.where(self.is_log, u, 0.0)), u)

    def residuals(self, u: Array) -> Array:
        """The objective's residual vector (N C,)."""
        r = (self.w_over * (self.g(_predict(self.spec, self.native(u), self.pair, self.c)) - self.gy)).ravel()
        self._last = (u.copy(), r)
        return r

    def jac(self, u: Array) -> Array:
        """Forward-difference Jacobian, reusing the residuals least_squares just computed at u."""
        f0 = self._last[1] if self._last is not None and np.array_equal(self._last[0], u) else self.residuals(u)
        return _jacobian(self.residuals, u, self.groups, self.c, f0)

    def solve(
        self, u0: Array, bounds: tuple[Array, Array], robust: str | None, f_scale: float
    ) -> optimize.OptimizeResult:
        """One bounded trust-region run from u0."""
        return optimize.least_squares(
            self.residuals, u0, jac=self.jac, bounds=bounds, loss=robust or "linear", f_scale=f_scale, x_scale="jac"
        )


def fit(
    spec: FitSpec,
    samples: Samples,
    loss: str = "l2",
    robust: str | None = None,
    *,
    starts: int = 4,
    seed: int = 0,
    weighted: bool = True,
    f_scale: float = 3.0,
    warn: bool = True,
) -> FitResult:
    """Fit spec's model to the samples (values in 1/sr); see the module docstring for losses and errors.

    ``starts``: the spec's initial guess plus starts - 1 random points inside the bounds (seeded); the
    lowest cost wins. Warnings are collected in the result and, with ``warn``, also issued as FitWarning.
    """
    if loss not in LOSSES or robust not in ROBUST or starts < 1:
        raise FitError(
            f"fit: loss {loss!r} (one of {LOSSES}), robust {robust!r} (one of {ROBUST}), starts {starts} >= 1"
        )
    notes = list(samples.notes)
    up = (samples.wi[:, 2] > 0) & (samples.wo[:, 2] > 0)
    n_lower = int((samples.lower_bound & up).sum())
    if n_lower:
        notes.append(f"{n_lower} saturated (lower-bound) samples excluded from the fit")
    if (~up).any():
        notes.append(f"{int((~up).sum())} samples at or below the horizon excluded")
    s = samples.subset(up & ~samples.lower_bound)
    n, c = s.n, s.channels
    labels = spec.labels(c)
    p = len(labels)
    fields = [q.name for q in spec.params]
    if n < len(fields) or n * c <= p:
        raise FitError(
            f"{spec.name}: {n} usable samples x {c} channels ({samples.n - n} excluded) cannot determine "
            f"{p} parameters ({len(fields)} per channel: {', '.join(fields)}); need more than {p} "
            f"residuals and at least {len(fields)} samples"
        )
    if _coplanar(s):
        if spec.anisotropic:
            raise FitError(
                f"{spec.name}: all {n} samples lie in one plane, so the anisotropic parameters "
                f"{', '.join(spec.anisotropic)} are unconstrained; measure off that plane or fit an isotropic model"
            )
        notes.append(
            f"all {n} samples lie in one plane: out-of-plane behaviour is unconstrained by the data and "
            "rests on the model's isotropy"
        )

    lo = np.concatenate([np.full(k, q.to_internal(q.lo)) for q, k in zip(spec.params, spec.sizes(c), strict=True)])
    hi = np.concatenate([np.full(k, q.to_internal(q.hi)) for q, k in zip(spec.params, spec.sizes(c), strict=True)])
    is_log = np.concatenate([np.full(k, q.log) for q, k in zip(spec.params, spec.sizes(c), strict=True)])
    full = _Problem(spec, s, loss, weighted, is_log)
    rng = np.random.default_rng(seed)
    x0 = spec.initial(s)
    inner = lo + 1e-6 * (hi - lo), hi - 1e-6 * (hi - lo)
    tries = [np.where(is_log, np.log(np.where(is_log, x0, 1.0)), x0)] + [rng.uniform(*inner) for _ in range(starts - 1)]
    # Several starts on many samples: screen them on a seeded subsample (the same minima, 5x cheaper at
    # 10,000 samples), then polish the winner on all samples.
    screen = full
    if starts > 1 and n > SCREEN_SAMPLES:
        screen = _Problem(spec, s.subset(rng.choice(n, SCREEN_SAMPLES, replace=False)), loss, weighted, is_log)
    results = [screen.solve(u, (lo, hi), robust, f_scale) for u in tries]
    best = min(results, key=lambda r: r.cost)
    agreeing = sum(r.cost <= best.cost * (1 + 1e-6) + 1e-12 for r in results)
    if screen is not full:
        best = full.solve(best.x, (lo, hi), robust, f_scale)
    if not best.success:
        notes.append(f"the optimiser stopped without converging: {best.message}")
    ux: Array = best.x
    x = full.native(ux)

    vals = spec.values(x, c)
    try:
        model = spec.build(vals)
    except ParameterError as exc:
        notes.append(f"the best fit breaks a rule of the model ({exc}); the returned model is unvalidated")
        model = spec.build(vals, validate=False)
    resid = (_predict(spec, x, full.pair, c) - s.value) / s.std_error
    chi2 = float(np.sum(resid**2))
    dof = n * c - p

    # Covariance in native units: chain rule d/dnative = d/du / (dnative/du), column-normalised for the SVD.
    jac = _jacobian(full.residuals, ux, full.groups, c) / np.where(is_log, x, 1.0)
    norms = np.linalg.norm(jac, axis=0)
    norms = np.where(norms > 0, norms, 1.0)
    _, sv, vt = np.linalg.svd(jac / norms, full_matrices=False)
    keep = sv > RANK_TOL * sv[0]
    ainv = (vt[keep].T / sv[keep] ** 2) @ vt[keep]
    jn = jac / norms
    cov = ainv @ ((jn * full.nu[:, None] ** 2).T @ jn) @ ainv / np.outer(norms, norms)
    red = chi2 / dof
    if red > 1.0 + 3.0 * np.sqrt(2.0 / dof):
        cov *= red
        notes.append(
            f"residuals exceed the noise (reduced chi2 {red:.3g}): std errors scaled by sqrt({red:.3g}); "
            "the model misses structure in the data or the std errors are underestimated"
        )
    err = np.sqrt(np.maximum(np.diag(cov), 0.0))
    if not keep.all():
        null = np.abs(vt[~keep]).max(axis=0) > 0.1
        err = np.where(null, np.inf, err)
        notes.append(f"the data do not constrain {', '.join(np.array(labels)[null])} (Jacobian rank deficient)")
    span = hi - lo
    at_bound = (ux - lo < 1e-6 * span) | (hi - ux < 1e-6 * span)
    if at_bound.any():
        names = ", ".join(f"{labels[i]} = {x[i]:.4g}" for i in np.flatnonzero(at_bound))
        notes.append(f"at a bound: {names}; their std errors assume the bound is not there")

    if n_lower:
        lb = samples.subset(samples.lower_bound & up)
        shortfall = _predict(spec, x, Pair(lb.wi, lb.wo), c) < lb.value
        if shortfall.any():
            notes.append(
                f"the fit lies below {int(shortfall.any(axis=1).sum())} of {n_lower} saturated lower bounds: "
                "the saturated peak is higher than the model predicts and the data cannot say by how much"
            )
    if warn:
        for note in notes:
            warnings.warn(f"{spec.name}: {note}", FitWarning, stacklevel=2)
    return FitResult(
        spec.name, model, tuple(labels), x, err, cov, resid, chi2, dof, loss, robust, float(best.cost), n,
        samples.n - n, starts, int(agreeing), s.std_error_assumed, tuple(notes),
    )  # fmt: skip
