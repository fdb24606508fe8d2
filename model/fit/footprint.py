"""What a reading with a footprint measures: the model averaged over its directions' spread, by sigma points.

A tile of image mode, or a frame blurred by a continuous scan, reads the BRDF averaged over a footprint of
direction pairs, not its value at the footprint's centre. ``direction_cov`` (N, 4, 4) states the footprint
(with the pose's own error) as a covariance of the tangent components (wi_x, wi_y, wo_x, wo_y) of the local
unit vectors, a direction (x, y) standing for (x, y, sqrt(1 - x^2 - y^2)) (``rig.run.measuring.tiles``,
``rig.instrument.direction_uncertainty``). The mean of f over a footprint is f(centre) + 1/2 tr(H Sigma) + ...;
on a narrow lobe the curvature term is a bias of several standard errors at the peak and on the flanks.

The average here treats the footprint as the Gaussian N(centre, Sigma) in those components and integrates
along its principal axes with the three-point Gauss-Hermite rule (the unscented transform with
n + kappa = 3): for m axes of standard deviation s_k and unit vectors e_k,

    mean f ~ (1 - m / 3) f(c) + sum_k 1/6 [f(c + sqrt(3) s_k e_k) + f(c - sqrt(3) s_k e_k)],

exact for polynomials up to degree 5 along each axis (the Gaussian's fourth moment 3 s^4 included), 2 m + 1
evaluations. Only the ``MAX_AXES`` widest axes are averaged over: a tile's footprint is a patch of the
surface (two dimensions) and a scan's blur one more, while what is left is the pose's error, far smaller;
with at most three axes the centre's weight is never negative, so the average of a non-negative model is
never negative. Axes narrower than ``NEGLIGIBLE_STD`` are left out, so a row without covariance (or with
zero covariance) is predicted by the model at its centre, bit for bit as without this module.

Near the horizon: an axis whose sigma point on either side would come within ``MIN_COS`` of the horizon
(wi or wo) is dropped for that row, both points together, never clamped: a clamped point would sit where a
microfacet model's 1 / cos diverges and would weigh its grazing value into the mean, and dropping both keeps the
rule symmetric (unbiased to first order). Such a row is averaged over its other axes only; what its dropped axis
would add stays in the first-order angular variance (``model.fit.angular``), which a fit keeps beside the
average for the pose's share of the covariance (a random error, which an average does not capture).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from model.base import BRDF

Array = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

#: Principal axes of a footprint averaged over (the widest ones): 2 MAX_AXES + 1 evaluations at most.
MAX_AXES = 3
#: Axes with a standard deviation (tangent units, ~rad) at most this are not averaged over.
NEGLIGIBLE_STD = 1e-6
#: A sigma point's cos(theta) of wi or wo must exceed this, or its axis is dropped for the row.
MIN_COS = 0.01
#: The Gauss-Hermite rule's node (in standard deviations) and the weight of each side point.
NODE = float(np.sqrt(3.0))
SIDE_WEIGHT = 1.0 / 6.0


def _lift(xy: Array) -> Array:
    """Unit vectors (..., 3) from tangent components (..., 2) inside the unit disk."""
    z = np.sqrt(np.clip(1.0 - np.sum(xy * xy, axis=-1, keepdims=True), 0.0, None))
    out: Array = np.concatenate([xy, z], axis=-1)
    return out


@dataclass(frozen=True)
class SigmaPoints:
    """The sigma points of the rows that are averaged: ``rows`` (A,) their indices among N, ``wi``, ``wo``
    (A, 2 MAX_AXES, 3) the side points' unit vectors, ``weight`` (A, 2 MAX_AXES) the side weights (0 for an
    axis left out, whose points then sit at the centre) and ``centre_weight`` (A,)."""

    n: int
    rows: IntArray
    wi: Array
    wo: Array
    weight: Array
    centre_weight: Array

    @property
    def count(self) -> int:
        """How many rows are averaged (the others are predicted at their centre)."""
        return int(self.rows.size)

    def combine(self, centre: Array, points: Array) -> Array:
        """Footprint means (N, C) from the model at the centres (N, C) and at the side points (A * 2 MAX_AXES, C)."""
        c = centre.shape[1]
        out = np.array(centre, dtype=np.float64, copy=True)
        if self.count:
            side = points.reshape(self.count, 2 * MAX_AXES, -1)
            mean = self.centre_weight[:, None] * centre[self.rows] + np.einsum("ak,akc->ac", self.weight, side)
            out[self.rows] = np.broadcast_to(mean, (self.count, c))
        return out


def sigma_points(wi: npt.ArrayLike, wo: npt.ArrayLike, direction_cov: npt.ArrayLike) -> SigmaPoints:
    """The sigma points of each row's footprint N(centre, direction_cov) (see the module docstring).

    ``wi``, ``wo`` (N, 3) unit vectors above the horizon; ``direction_cov`` (N, 4, 4) over (wi_x, wi_y,
    wo_x, wo_y), or empty (0, 4, 4) for none.
    """
    wi, wo = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
    direction_cov = np.asarray(direction_cov, dtype=np.float64)
    n = wi.shape[0]
    k = 2 * MAX_AXES
    if direction_cov.size == 0:
        return SigmaPoints(n, np.zeros(0, dtype=np.int64), np.zeros((0, k, 3)), np.zeros((0, k, 3)),
                           np.zeros((0, k)), np.zeros(0))  # fmt: skip
    cov = 0.5 * (direction_cov + np.swapaxes(direction_cov, 1, 2))
    lam, vec = np.linalg.eigh(cov)  # ascending: the widest axes last
    std = np.sqrt(np.clip(lam[:, -MAX_AXES:], 0.0, None))  # (N, MAX_AXES)
    axes = vec[:, :, -MAX_AXES:]  # (N, 4, MAX_AXES)
    wide = std > NEGLIGIBLE_STD
    rows = np.flatnonzero(wide.any(axis=1))
    centre = np.concatenate([wi[rows, :2], wo[rows, :2]], axis=1)  # (A, 4)
    step = NODE * std[rows, None, :] * axes[rows]  # (A, 4, MAX_AXES)
    # Points ordered axis by axis: (+ axis 0, - axis 0, + axis 1, ...).
    offsets = np.stack([step, -step], axis=-1).reshape(rows.size, 4, k)
    pts = centre[:, :, None] + offsets  # (A, 4, k)
    xy_i, xy_o = np.moveaxis(pts[:, :2], 1, -1), np.moveaxis(pts[:, 2:], 1, -1)  # (A, k, 2)
    limit = 1.0 - MIN_COS**2
    inside = (np.sum(xy_i**2, axis=-1) < limit) & (np.sum(xy_o**2, axis=-1) < limit)  # (A, k)
    used = wide[rows] & inside.reshape(rows.size, MAX_AXES, 2).all(axis=-1)  # (A, MAX_AXES)
    # An axis left out (narrow, or crossing the horizon) has its points at the centre and weight 0.
    keep = np.repeat(used, 2, axis=1)  # (A, k)
    xy_i = np.where(keep[..., None], xy_i, centre[:, None, :2])
    xy_o = np.where(keep[..., None], xy_o, centre[:, None, 2:])
    weight = np.where(keep, SIDE_WEIGHT, 0.0)
    centre_weight = 1.0 - used.sum(axis=1) / 3.0
    return SigmaPoints(n, rows.astype(np.int64), _lift(xy_i), _lift(xy_o), weight, centre_weight)


def footprint_average(model: BRDF, wi: npt.ArrayLike, wo: npt.ArrayLike, direction_cov: npt.ArrayLike) -> Array:
    """The model's mean (N, C) in 1/sr over each row's footprint (its value at the centre where there is none)."""
    wi, wo = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
    n = wi.shape[0]
    sp = sigma_points(wi, wo, direction_cov)
    centre = np.asarray(model.eval(wi, wo), dtype=np.float64).reshape(n, -1)
    if not sp.count:
        return centre
    points = np.asarray(model.eval(sp.wi.reshape(-1, 3), sp.wo.reshape(-1, 3)), dtype=np.float64)
    return sp.combine(centre, points.reshape(sp.count * 2 * MAX_AXES, -1))
