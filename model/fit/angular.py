"""Angular uncertainty in a fit: a reading's error includes how much the BRDF changes within its directions' error.

A measured direction pair is known to a covariance (the tangent components wi_x, wi_y, wo_x, wo_y of the
local unit vectors; a direction (x, y) stands for (x, y, sqrt(1 - x^2 - y^2))). To first order the
reading's value then varies by the model's gradient along those components, so its effective variance is

    var_eff = var_photometric + g Sigma g^T,     g = d f / d (wi_x, wi_y, wo_x, wo_y),

evaluated at the fitted model (central differences). On a steep lobe's flank the angular term dominates
and the point counts for what it is; on a flat diffuse sample it vanishes. The fit is repeated with the
effective errors until they settle, since g depends on the fit.

The same covariance also holds a tile's or a blurred frame's footprint, which the reading averages over:
``fit_with_angular`` predicts such rows as the model's footprint mean (second order and beyond: the
curvature of a narrow lobe, model/fit/footprint.py) rather than its value at the centre, unless told not to.
It keeps the first-order variance beside the mean: the covariance also holds the pose's and the
calibration's errors, random offsets of the directions that a mean does not capture, and the table does
not say which share is which. For a footprint's share that variance is conservative (the mean has
already absorbed it): readings on a lobe's flanks are weighted less than they could be, never biased.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from model.base import BRDF
from model.fit.samples import Samples
from model.fit.solve import FitResult, fit
from model.fit.spec import FitSpec

Array = npt.NDArray[np.float64]

#: Step (in tangent-component units, ~radians) of the central differences.
STEP = 1e-5


def _lift(x: Array, y: Array) -> Array:
    z2 = np.clip(1.0 - x * x - y * y, 1e-16, None)
    out: Array = np.stack([x, y, np.sqrt(z2)], axis=-1)
    return out


def gradient(model: BRDF, samples: Samples) -> Array:
    """d f / d (wi_x, wi_y, wo_x, wo_y), (N, C, 4) in 1/sr per unit tangent component."""
    wi, wo = samples.wi, samples.wo
    base = [wi[:, 0], wi[:, 1], wo[:, 0], wo[:, 1]]
    cols = []
    for k in range(4):
        plus = [b + (STEP if j == k else 0.0) for j, b in enumerate(base)]
        minus = [b - (STEP if j == k else 0.0) for j, b in enumerate(base)]
        fp = np.asarray(model.eval(_lift(plus[0], plus[1]), _lift(plus[2], plus[3])), dtype=np.float64)
        fm = np.asarray(model.eval(_lift(minus[0], minus[1]), _lift(minus[2], minus[3])), dtype=np.float64)
        d = (fp - fm) / (2 * STEP)
        cols.append(d.reshape(samples.n, -1))
    out: Array = np.stack(cols, axis=-1)
    c = samples.channels
    return np.broadcast_to(out, (samples.n, c, 4)) if out.shape[1] == 1 else out


def angular_variance(model: BRDF, samples: Samples) -> Array:
    """The angular share of each reading's variance, (N, C) in (1/sr)^2 (zeros without direction_cov)."""
    if samples.direction_cov.size == 0:
        return np.zeros_like(samples.value)
    g = gradient(model, samples)
    out: Array = np.einsum("nci,nij,ncj->nc", g, samples.direction_cov, g)
    return np.maximum(out, 0.0)


def with_angular(samples: Samples, photometric_se: Array, variance: Array) -> Samples:
    """The samples with std_error sqrt(photometric^2 + angular variance)."""
    se = np.sqrt(np.square(photometric_se) + variance)
    return Samples(samples.wi, samples.wo, samples.value, se, samples.lower_bound, samples.std_error_assumed,
                   samples.notes, samples.source, samples.direction_cov)  # fmt: skip


def angular_share(photometric_se: Array, variance: Array) -> Array:
    """Fraction of each reading's effective variance that is angular, (N, C) in [0, 1]."""
    total = np.square(photometric_se) + variance
    out: Array = np.where(total > 0, variance / np.where(total > 0, total, 1.0), 0.0)
    return out


def fit_with_angular(
    spec: FitSpec, samples: Samples, loss: str = "l2", *, starts: int = 4, seed: int = 0, iterations: int = 4,
    tol: float = 0.01, footprint: bool = True,
) -> tuple[FitResult, Array]:
    """Fit ``spec`` with effective errors (photometric plus angular, see the module), iterated to a fixed point.

    Returns the last fit and each sample's angular variance (N, C) in (1/sr)^2 at it; without
    ``direction_cov`` it is one ordinary fit and zeros. Stops when no error moves by more than ``tol``
    (relative) or after ``iterations`` fits. ``footprint``: predict rows with a covariance as the model's
    mean over it (model/fit/footprint.py; False: at their centre, as before the mean existed).
    """
    average = footprint and samples.direction_cov.size > 0
    result = fit(spec, samples, loss, None, starts=starts, seed=seed, footprint=average)
    if samples.direction_cov.size == 0:
        return result, np.zeros_like(samples.value)
    photometric = samples.std_error
    variance = angular_variance(result.model, samples)
    for _ in range(iterations - 1):
        current = with_angular(samples, photometric, variance)
        result = fit(spec, current, loss, None, starts=starts, seed=seed, footprint=average)
        new = angular_variance(result.model, samples)
        old_se, new_se = np.sqrt(photometric**2 + variance), np.sqrt(photometric**2 + new)
        variance = new
        if np.max(np.abs(new_se / old_se - 1.0)) < tol:
            break
    return result, variance
