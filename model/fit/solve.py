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

Saturated samples (``lower_bound``: the truth is at least the value) are one-sided constraints by default
(``lower_bounds="constrain"``): each adds the residual min(0, r), r as above, so a model below a bound is
pulled up and one above it is free (see model/fit/problem.py for the hinge). ``lower_bounds="exclude"``
leaves them out. Either way chi2 and dof = N C - k count the N ordinary samples only: a satisfied bound
carries no information about the noise and an active one holds the model at a value that is not a
measurement of it, so neither is a degree of freedom. For the same reason the covariance comes from the
ordinary samples' rows: a bound moves the estimate but adds no precision, so the std errors say what the
data alone determine (conservative where a bound is active). The bounds' squared shortfalls are reported
apart as ``bound_chi2``, and a warning names bounds the final model still lies below by more than 2 std
errors. A bound without a positive std error borrows the median relative std error of the ordinary
samples in its channel, times its value.

Large sample sets (a full MERL table: 1.1 million RGB samples) are solved in stages, with the geometry
cached and compiled model kernels used where they exist (model/fit/problem.py, bench/fit.py).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
import numpy.typing as npt

from model._params import ParameterError
from model.base import Model
from model.fit.problem import Problem, Rows, jacobian, solve_staged
from model.fit.result import FitResult, FitWarning
from model.fit.samples import FitError, Samples
from model.fit.spec import LAMBERT, FitSpec, Param, blinn_phong, ggx_conductor, lambert_ggx, ward_anisotropic

Array = npt.NDArray[np.float64]
LOSSES = ("l2", "cosine_l2", "log", "cbrt")
ROBUST = (None, "soft_l1", "huber", "cauchy")
LOWER_BOUNDS = ("constrain", "exclude")
#: Singular values of the column-normalised Jacobian below this fraction of the largest mark directions
#: in parameter space the data do not constrain.
RANK_TOL = 1e-7
#: A lower bound the fitted model lies below by more than this many std errors is warned about.
BOUND_TOLERANCE = 2.0

__all__ = [
    "LAMBERT", "FitError", "FitResult", "FitSpec", "FitWarning", "Param", "Samples", "blinn_phong", "fit",
    "ggx_conductor", "lambert_ggx", "ward_anisotropic",
]  # fmt: skip


def _coplanar(s: Samples) -> bool:
    """Whether every wi and wo lies in one plane through the origin (e.g. one plane of incidence)."""
    if 2 * s.n < 3:
        return True
    # The smallest singular value of the stacked directions, measured along the Gram matrix's weakest
    # axis (a 3 x 3 eigenproblem instead of an SVD of 2 N rows): the data leave that axis by at most this.
    lam, vec = np.linalg.eigh(s.wi.T @ s.wi + s.wo.T @ s.wo)
    off = np.sqrt(np.sum((s.wi @ vec[:, 0]) ** 2) + np.sum((s.wo @ vec[:, 0]) ** 2))
    return bool(off <= 1e-9 * np.sqrt(lam[-1]))


def _bounds(ordinary: Samples, saturated: Samples, notes: list[str]) -> Samples | None:
    """The saturated samples usable as lower bounds (finite values; None if none), each with a positive std error.

    A bound without a positive, finite std error of its own borrows the median relative std error of the
    ordinary samples in its channel times its value, floored at their median std error.
    """
    ok = np.all(np.isfinite(saturated.value), axis=1)
    if not ok.all():
        notes.append(f"{int((~ok).sum())} saturated samples without a finite value carry no bound and are ignored")
    if not ok.any():
        return None
    b = saturated.subset(ok)
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.nanmedian(np.where(ordinary.value != 0, ordinary.std_error / np.abs(ordinary.value), np.nan), axis=0)
    borrowed = np.fmax(rel * np.abs(b.value), np.median(ordinary.std_error, axis=0))
    se = np.where(np.isfinite(b.std_error) & (b.std_error > 0), b.std_error, borrowed)
    return Samples(b.wi, b.wo, b.value, se, b.lower_bound, b.std_error_assumed, (), b.source, b.direction_cov)


def _join(ordinary: Samples, bounds: Samples) -> Samples:
    """The ordinary samples followed by the lower bounds, as one row set (lower_bound flags the bounds)."""
    wi, wo, value, se = (np.concatenate([getattr(ordinary, k), getattr(bounds, k)]) for k in
                         ("wi", "wo", "value", "std_error"))  # fmt: skip
    flags = np.concatenate([np.zeros(ordinary.n, dtype=bool), np.ones(bounds.n, dtype=bool)])
    both = ordinary.direction_cov.size and bounds.direction_cov.size
    cov = np.concatenate([ordinary.direction_cov, bounds.direction_cov]) if both else np.zeros((0, 4, 4))
    return Samples(wi, wo, value, se, flags, ordinary.std_error_assumed, (), ordinary.source, cov)


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
    lower_bounds: str = "constrain",
    warn: bool = True,
    footprint: bool = False,
) -> FitResult:
    """Fit spec's model to the samples (values in 1/sr); see the module docstring for losses and errors.

    ``starts``: the spec's initial guess plus starts - 1 random points inside the bounds (seeded); the
    lowest cost wins. ``lower_bounds``: "constrain" (default) or "exclude" the saturated samples. Warnings
    are collected in the result and, with ``warn``, also issued as FitWarning. ``footprint``: rows with a
    ``direction_cov`` are predicted as the model's mean over their footprint (model/fit/footprint.py), what
    a tile or a blurred frame reads, instead of its value at their centre.
    """
    if loss not in LOSSES or robust not in ROBUST or starts < 1 or lower_bounds not in LOWER_BOUNDS:
        raise FitError(
            f"fit: loss {loss!r} (one of {LOSSES}), robust {robust!r} (one of {ROBUST}), starts {starts} >= 1, "
            f"lower_bounds {lower_bounds!r} (one of {LOWER_BOUNDS})"
        )
    # Which samples enter: the ordinary ones above the horizon, and the saturated ones as lower bounds.
    notes = list(samples.notes)  # what deserves less trust than it seems, in the order it was found
    s, saturated = _usable(samples, lower_bounds, notes)
    n, c = s.n, s.channels
    labels = spec.labels(c)
    _check_determined(spec, s, samples.n, len(labels), notes)
    bound_notes = notes if lower_bounds == "constrain" else []  # excluded bounds' notes do not concern the fit
    bounds = _bounds(s, samples.subset(saturated), bound_notes) if saturated.any() else None
    constrain = lower_bounds == "constrain" and bounds is not None
    n_bounds = bounds.n if constrain and bounds is not None else 0

    # The solve, in the optimiser's coordinates, from several starts.
    box = _Box.of(spec, c)
    rng = np.random.default_rng(seed)
    tries = _starts(spec, s, box, starts, rng)
    # The ordinary samples come first in the rows, so the first n rows of any prediction are theirs.
    rows = _join(s, bounds) if constrain and bounds is not None else s
    best, agreeing, full = solve_staged(
        lambda r: Problem(spec, r, loss, weighted, box.is_log, footprint), rows, tries, (box.lo, box.hi), robust,
        f_scale, rng,
    )  # fmt: skip
    if not best.success:
        notes.append(f"the optimiser stopped without converging: {best.message}")
    ux: Array = best.x
    x = full.native(ux)

    # The model, its goodness of fit and uncertainties, and how far it falls short of the lower bounds.
    model = _model(spec, spec.values(x, c), notes)
    pred = full.rows.predict(spec, x)
    resid = (pred[:n] - s.value) / s.std_error
    chi2 = float(np.sum(resid**2))
    dof = n * c - len(labels)
    cov, null = _covariance(full, ux, x, box.is_log, n, c)
    cov, err = _std_errors(cov, null, chi2, dof, labels, notes)
    _note_at_bounds(ux, x, box, labels, notes)
    bound_chi2 = 0.0
    if bounds is not None:
        pred_b = pred[n:] if constrain else Rows(bounds, footprint).predict(spec, x)
        bound_chi2 = _shortfall(bounds, pred_b, constrain, notes)

    if warn:
        for note in notes:
            warnings.warn(f"{spec.name}: {note}", FitWarning, stacklevel=2)
    return FitResult(
        spec.name, model, tuple(labels), x, err, cov, resid, chi2, dof, loss, robust, float(best.cost), n,
        samples.n - n - n_bounds, starts, agreeing, s.std_error_assumed, tuple(notes), n_bounds, bound_chi2,
    )  # fmt: skip


def _usable(samples: Samples, lower_bounds: str, notes: list[str]) -> tuple[Samples, npt.NDArray[np.bool_]]:
    """The ordinary samples above the horizon, and the mask of the saturated ones there (the lower bounds)."""
    up = (samples.wi[:, 2] > 0) & (samples.wo[:, 2] > 0)
    saturated = samples.lower_bound & up
    n_lower = int(saturated.sum())
    if n_lower and lower_bounds == "exclude":
        notes.append(f"{n_lower} saturated (lower-bound) samples excluded from the fit")
    if (~up).any():
        notes.append(f"{int((~up).sum())} samples at or below the horizon excluded")
    return samples.subset(up & ~samples.lower_bound), saturated


def _check_determined(spec: FitSpec, s: Samples, n_given: int, p: int, notes: list[str]) -> None:
    """Raise FitError where the samples cannot determine the ``p`` fitted numbers; note a one-plane sample set."""
    n, c = s.n, s.channels
    fields = [q.name for q in spec.params]
    if n < len(fields) or n * c <= p:
        raise FitError(
            f"{spec.name}: {n} usable samples x {c} channels ({n_given - n} excluded) cannot determine "
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


@dataclass(frozen=True, eq=False)
class _Box:
    """The fitted numbers' bounds in the optimiser's coordinates (the log of log-scaled ones), and which are log."""

    lo: Array
    hi: Array
    is_log: npt.NDArray[Any]  # booleans

    @classmethod
    def of(cls, spec: FitSpec, channels: int) -> _Box:
        """The bounds of spec's parameters, each repeated over the channels it has a value for."""
        sizes = spec.sizes(channels)
        lo = np.concatenate([np.full(k, q.to_internal(q.lo)) for q, k in zip(spec.params, sizes, strict=True)])
        hi = np.concatenate([np.full(k, q.to_internal(q.hi)) for q, k in zip(spec.params, sizes, strict=True)])
        is_log = np.concatenate([np.full(k, q.log) for q, k in zip(spec.params, sizes, strict=True)])
        return cls(lo, hi, is_log)


def _starts(spec: FitSpec, s: Samples, box: _Box, starts: int, rng: np.random.Generator) -> list[Array]:
    """The spec's initial guess, then starts - 1 points drawn uniformly just inside the box (optimiser coordinates)."""
    x0 = spec.initial(s)
    inner = box.lo + 1e-6 * (box.hi - box.lo), box.hi - 1e-6 * (box.hi - box.lo)
    first = np.where(box.is_log, np.log(np.where(box.is_log, x0, 1.0)), x0)
    return [first] + [rng.uniform(*inner) for _ in range(starts - 1)]


def _model(spec: FitSpec, values: dict[str, Any], notes: list[str]) -> Model:
    """Spec's model with these values; unvalidated, with a note, where the best fit breaks one of its rules."""
    try:
        return spec.build(values)
    except ParameterError as exc:
        notes.append(f"the best fit breaks a rule of the model ({exc}); the returned model is unvalidated")
        return spec.build(values, validate=False)


def _covariance(
    full: Problem, ux: Array, x: Array, is_log: npt.NDArray[Any], n: int, c: int
) -> tuple[Array, npt.NDArray[np.bool_] | None]:
    """The fitted numbers' covariance (native units) by the sandwich formula, from the ordinary samples' rows;
    and which numbers the data do not constrain (None where the Jacobian has full rank)."""
    # Chain rule d/dnative = d/du / (dnative/du), column-normalised for the SVD. Only the ordinary samples'
    # rows (the first n c): a lower bound is not a measurement, and an active one would otherwise count as
    # one, at its value, and claim a precision a one-sided bound cannot give.
    jn = jacobian(full.residuals, ux, full.groups, c)[: n * c]
    nu = full.nu[: n * c]
    jn /= np.where(is_log, x, 1.0)
    norms = np.sqrt(np.einsum("ij,ij->j", jn, jn))
    norms = np.where(norms > 0, norms, 1.0)
    jn /= norms
    # J's singular values and right vectors are those of its (P, P) R factor: no (M, P) left vectors to form.
    r_factor = cast(Array, np.linalg.qr(jn, mode="r"))
    _, sv, vt = np.linalg.svd(r_factor)
    keep = sv > RANK_TOL * sv[0]
    ainv = (vt[keep].T / sv[keep] ** 2) @ vt[keep]
    if np.all(nu == 1.0):
        meat = r_factor.T @ r_factor
    else:
        jw = jn * nu[:, None]
        meat = jw.T @ jw
    cov = ainv @ meat @ ainv / np.outer(norms, norms)
    return cov, None if keep.all() else np.abs(vt[~keep]).max(axis=0) > 0.1


def _std_errors(
    cov: Array, null: npt.NDArray[np.bool_] | None, chi2: float, dof: int, labels: list[str], notes: list[str]
) -> tuple[Array, Array]:
    """(covariance, std errors): scaled by the reduced chi2 where residuals exceed the noise; inf if unconstrained."""
    red = chi2 / dof
    if red > 1.0 + 3.0 * np.sqrt(2.0 / dof):
        cov *= red
        notes.append(
            f"residuals exceed the noise (reduced chi2 {red:.3g}): std errors scaled by sqrt({red:.3g}); "
            "the model misses structure in the data or the std errors are underestimated"
        )
    err = np.sqrt(np.maximum(np.diag(cov), 0.0))
    if null is not None:
        err = np.where(null, np.inf, err)
        notes.append(f"the data do not constrain {', '.join(np.array(labels)[null])} (Jacobian rank deficient)")
    return cov, err


def _note_at_bounds(ux: Array, x: Array, box: _Box, labels: list[str], notes: list[str]) -> None:
    """Note the fitted numbers at (within 1e-6 of the span of) a bound: their std errors ignore it."""
    span = box.hi - box.lo
    at_bound = (ux - box.lo < 1e-6 * span) | (box.hi - ux < 1e-6 * span)
    if at_bound.any():
        names = ", ".join(f"{labels[i]} = {x[i]:.4g}" for i in np.flatnonzero(at_bound))
        notes.append(f"at a bound: {names}; their std errors assume the bound is not there")


def _shortfall(bounds: Samples, pred_b: Array, constrain: bool, notes: list[str]) -> float:
    """chi2 of the model's shortfalls below the lower bounds (model ``pred_b``); a note names those far below."""
    short = np.maximum((bounds.value - pred_b) / bounds.std_error, 0.0)
    below = (short > BOUND_TOLERANCE).any(axis=1)
    if below.any():
        why = (
            "even as constraints: the model cannot reach the saturated peak" if constrain else
            "they were excluded (lower_bounds='exclude'); constraining the fit with them would lift it"
        )  # fmt: skip
        notes.append(
            f"the fit lies more than {BOUND_TOLERANCE:g} std errors below {int(below.sum())} of {bounds.n} "
            f"saturated lower bounds (by up to {short.max():.3g}): {why}"
        )
    return float(np.sum(short**2))
