"""Least squares over millions of residuals: the same cost, handed to the optimiser as P + 1 residuals.

scipy's trust-region solver takes an SVD of the (M, P) Jacobian, copies it and rescales its columns on
every iteration: at a million RGB samples (M = 3.3 million) that was most of a fit, more than the residuals
and the Jacobian themselves.
None of it is needed, because for P parameters the cost is unchanged by projecting the residual vector r
onto a fixed orthonormal basis Q (M, P) and keeping the length of what is left:

    r~(u) = [Q^T r(u), |r(u) - Q Q^T r(u)|],   |r~(u)|^2 = |r(u)|^2 for every u.

The optimiser minimises |r~|^2, which is the same function of u as |r|^2, so it has the same minimum,
gradient (J~^T r~ = J^T r) and stopping tests; only its Gauss-Newton model differs, and not at all where Q
was taken: with Q spanning the Jacobian's columns at the start, J~^T J~ = J^T J there. Q comes from one
orthonormalisation at the start of the solve, which the staged fit places near the optimum; should the
Jacobian turn far out of span(Q) on the way (DRIFT_TOL), the solve goes on from where it stopped with a new Q.
On a million RGB samples of a table the model cannot match, the last stage reaches the same cost (10 digits)
as least_squares on all residuals, in a fraction of its time (docs/benchmarks.md, the fit).

Robust losses act on each residual, not on projections, so they are folded in first: r_i is replaced by
sign(r_i) C sqrt(rho(r_i^2 / C^2)) (C = f_scale), whose squares sum to the robust cost scipy minimises,
and the optimiser runs with the plain loss.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

if TYPE_CHECKING:
    from scipy import optimize

Array = npt.NDArray[np.float64]
#: A solve whose Jacobian turned further than this (sine of the angle) out of span(Q) is continued with a new Q.
DRIFT_TOL = 0.1
#: At most this many bases per solve.
MAX_BASES = 4


def _robust(kind: str, z: Array) -> tuple[Array, Array]:
    """scipy's robust loss rho(z) and rho'(z) for z = (r / f_scale)^2."""
    if kind == "soft_l1":
        t = 1.0 + z
        return 2.0 * (np.sqrt(t) - 1.0), 1.0 / np.sqrt(t)
    if kind == "huber":
        big = z > 1.0
        root = np.sqrt(np.where(big, z, 1.0))
        return np.where(big, 2.0 * root - 1.0, z), np.where(big, 1.0 / root, 1.0)
    if kind == "cauchy":
        return np.log1p(z), 1.0 / (1.0 + z)
    raise ValueError(f"robust loss {kind!r}; expected soft_l1, huber or cauchy")


def _basis(jt: Array) -> Array:
    """Orthonormal rows (P, M) spanning the rows of jt (P, M), the transposed Jacobian.

    CholeskyQR2 (two Gram matrices, two (P, P) x (P, M) products) where jt is well enough conditioned,
    checked; Householder QR otherwise. Everything stays in the (P, M) layout of the Jacobian's buffer: at
    millions of rows, (P, P) x (P, M) is many times quicker than the same product as (M, P) x (P, P), and
    than numpy's QR.
    """
    norms = np.sqrt(np.einsum("ij,ij->i", jt, jt))
    qt = jt / np.where(norms > 0, norms, 1.0)[:, None]
    try:
        for _ in range(2):
            qt = np.linalg.inv(np.linalg.cholesky(qt @ qt.T)) @ qt
        if np.abs(qt @ qt.T - np.eye(qt.shape[0])).max() < 1e-12:
            return qt
    except np.linalg.LinAlgError:
        pass
    q, _ = np.linalg.qr(jt.T)
    return np.ascontiguousarray(q.T)


class _Projected:
    """The residuals r~(u) and their Jacobian for one basis Q (see the module docstring)."""

    def __init__(
        self, fun: Callable[[Array], Array], jac: Callable[[Array], Array], robust: str | None, f_scale: float
    ) -> None:
        self.fun, self.jac_full, self.robust, self.c = fun, jac, robust, f_scale
        self.qt: Array | None = None
        self.drift = 0.0
        self._at: tuple[Array, Array, Array] | None = None  # u, d r^/d r, perp

    def _scaled(self, u: Array) -> tuple[Array, Array]:
        """The residuals with the robust loss folded in, and their derivative with respect to r."""
        r = self.fun(u)
        if self.robust is None:
            return r, np.ones(0)
        z = (r / self.c) ** 2
        rho, drho = _robust(self.robust, z)
        root = np.sqrt(rho)
        scaled = np.sign(r) * self.c * root
        # d/dr of sign(r) C sqrt(rho(r^2/C^2)) = rho' |r| / (C sqrt(rho)); its limit at r = 0 is 1.
        tiny = root <= 1e-150
        slope = np.where(tiny, 1.0, drho * np.abs(r) / (self.c * np.where(tiny, 1.0, root)))
        return scaled, slope

    def _jt(self, u: Array, slope: Array) -> Array:
        """The full Jacobian at u, transposed to (P, M), the robust loss's slope applied."""
        jt = np.ascontiguousarray(self.jac_full(u).T)
        return jt * slope if slope.size else jt

    def start(self, u: Array) -> None:
        """Take Q from the Jacobian's columns at u."""
        _, slope = self._scaled(u)
        self.qt = _basis(self._jt(u, slope))

    def residuals(self, u: Array) -> Array:
        """r~(u): P projections and the length of the rest."""
        assert self.qt is not None
        r, slope = self._scaled(u)
        c = self.qt @ r
        perp = r - c @ self.qt
        self._at = (u.copy(), slope, perp)
        return np.append(c, np.linalg.norm(perp))

    def jac(self, u: Array) -> Array:
        """The Jacobian of r~ (P + 1, P), from the full Jacobian at u."""
        assert self.qt is not None
        if self._at is None or not np.array_equal(self._at[0], u):
            self.residuals(u)
        assert self._at is not None
        _, slope, perp = self._at
        jt = self._jt(u, slope)
        top = self.qt @ jt.T
        # How far the Jacobian's columns have turned out of span(Q) since it was taken (0: not at all).
        norm2 = np.einsum("ij,ij->i", jt, jt)
        outside = 1.0 - np.einsum("ij,ij->j", top, top) / np.where(norm2 > 0, norm2, 1.0)
        self.drift = float(np.sqrt(np.clip(np.where(norm2 > 0, outside, 0.0), 0.0, 1.0).max()))
        length = float(np.linalg.norm(perp))
        # d|perp|/du = perp^T J / |perp|; where perp vanishes (an exact fit) so does its contribution.
        last = jt @ perp / length if length > 1e-150 else np.zeros(jt.shape[0])
        return np.vstack([top, last[None, :]])


def solve_tall(
    fun: Callable[[Array], Array],
    jac: Callable[[Array], Array],
    u0: Array,
    bounds: tuple[Array, Array],
    robust: str | None,
    f_scale: float,
    max_nfev: int | None = None,
) -> optimize.OptimizeResult:
    """scipy's bounded trust-region least squares on the projected residuals; the result's cost is the full one.

    ``fun`` returns the M residuals at u, ``jac`` their (M, P) Jacobian at u right after ``fun(u)`` (it may
    reuse one buffer between calls: it is consumed at once).
    """
    from scipy import optimize  # here, as in model/fit/problem.py

    p = _Projected(fun, jac, robust, f_scale)
    u, nfev, njev = np.asarray(u0, dtype=np.float64), 0, 0
    budget = 100 * u.size if max_nfev is None else max_nfev  # least_squares' own default for one run
    for _ in range(MAX_BASES):
        p.start(u)
        res = optimize.least_squares(p.residuals, u, jac=p.jac, bounds=bounds, x_scale="jac", max_nfev=budget - nfev)
        nfev, njev = nfev + res.nfev, njev + res.njev
        # Far from where Q was taken the Gauss-Newton model degrades (the minimum does not move): go on
        # from there with a fresh Q, within the same budget of evaluations.
        if p.drift <= DRIFT_TOL or nfev >= budget:
            break
        u = res.x
    res.nfev, res.njev = nfev, njev
    return res
