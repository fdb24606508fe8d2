"""The objective of one fit: residuals over fixed sample rows, their Jacobian, and the staged multi-start solve.

Directions never change during a fit, so everything a model evaluation derives from them alone (half
vector, cosines) is computed once per row set, in a :class:`model.base.Pair` whose cached properties every
evaluation reuses. On large row sets (:data:`COMPILED_ROWS` and more) a model that has a compiled path of its
own (it overrides ``Model.eval``, as CookTorrance does with model/kernels.py) is evaluated through it
instead: at a million pairs the kernel is several times quicker than the numpy path even with the cached
geometry (bench/fit); below about 100,000 pairs the numpy path is as fast and steadier (the kernel's threads
wake up per call). Both give the same values.

Lower bounds. Rows flagged ``lower_bound`` (saturated readings: the truth is at least the value) are
one-sided constraints: their residual is the ordinary one (in the loss's coordinates) clipped at zero from
above, r = min(0, r), so a model at or above the bound costs nothing and one below it is pulled up like an
ordinary sample. The
squared hinge 0.5 min(0, r)^2 has a continuous gradient (only its curvature jumps at the bound), which is
all a trust-region Gauss-Newton method needs; a softplus smoothing was not used because it also penalises
models just above the bound and so biases the fit upwards.

Staging. Several starts are screened on a seeded subsample of :data:`SCREEN_SAMPLES` rows; the winner is then
refined on subsamples growing :data:`STAGE_GROWTH`-fold and polished on all rows, so the solve on all rows
(its iterations the costliest, most of each the Jacobian's model evaluations) starts within
the subsample's statistical scatter of its optimum. The answer is the optimum on all rows either way; only
the path to it changes. Solves with many residuals go through model/fit/tall.py, which hands the optimiser
P + 1 residuals with the same cost.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from model.base import Model, Pair
from model.fit.footprint import MAX_AXES, SigmaPoints, sigma_points
from model.fit.samples import Samples
from model.fit.spec import FitSpec
from model.fit.tall import solve_tall

if TYPE_CHECKING:
    from scipy import optimize

Array = npt.NDArray[np.float64]
Groups = list[list[tuple[int, int | None]]]
#: Rows on which several starts are screened before the best is polished on more of them.
SCREEN_SAMPLES = 2000
#: Each refinement stage has this many times the rows of the one before; the last has all rows.
STAGE_GROWTH = 20
#: Most evaluations a refinement stage (neither the screen nor the last) may spend.
STAGE_MAX_NFEV = 30
#: Row sets at least this large are evaluated by a model's own (compiled) eval where it has one.
COMPILED_ROWS = 100_000
#: Problems with at least this many residuals are solved through P + 1 projected ones (model/fit/tall.py).
TALL_RESIDUALS = 300_000


class Rows:
    """Fixed sample rows with their geometry computed once (a Pair, whose properties cache) and the hinge mask.

    ``footprint``: rows with a direction covariance are predicted as the model's mean over their footprint
    (model/fit/footprint.py: the side sigma points get a Pair of their own); the others at their centre.
    """

    def __init__(self, s: Samples, footprint: bool = False) -> None:
        self.n, self.c = s.n, s.channels
        self.pair = Pair(s.wi, s.wo)
        self.hinge = s.lower_bound if s.lower_bound.any() else None
        self.sigma: SigmaPoints | None = None
        self.sigma_pair: Pair | None = None
        if footprint and s.direction_cov.size:
            sp = sigma_points(s.wi, s.wo, s.direction_cov)
            if sp.count:
                self.sigma, self.sigma_pair = sp, Pair(sp.wi.reshape(-1, 3), sp.wo.reshape(-1, 3))

    def predict(self, spec: FitSpec, x_native: Array, *, validate: bool = False) -> Array:
        """Model values (N, C) in 1/sr at the rows (all above the horizon) for native parameters x."""
        m = spec.build(spec.values(x_native, self.c), validate=validate)
        f = np.broadcast_to(_values(m, self.pair, self.n), (self.n, self.c))
        if self.sigma is None or self.sigma_pair is None:
            return f
        k = self.sigma.count * 2 * MAX_AXES
        points = np.broadcast_to(_values(m, self.sigma_pair, k), (k, self.c))
        return self.sigma.combine(f, points)


def _values(m: Model, pair: Pair, n: int) -> Array:
    """The model's values (n, C or 1) at a pair's rows: its compiled path on large sets where it has one."""
    if n >= COMPILED_ROWS and type(m).eval is not Model.eval:
        return np.asarray(m.eval(pair.wi, pair.wo), dtype=np.float64).reshape(n, -1)
    with np.errstate(all="ignore"):
        out = np.asarray(m._eval(pair), dtype=np.float64)
    return out


def transform(loss: str, cos_i: Array) -> tuple[Callable[[Array], Array], bool]:
    """The loss's transform g of BRDF values and whether it is curved (not the identity)."""
    if loss == "log":
        return (lambda f: np.log1p(np.maximum(f * cos_i, -1.0 + 1e-12))), True
    if loss == "cbrt":
        return np.cbrt, True
    return (lambda f: f), False


def jacobian(
    f: Callable[[Array], Array],
    x: Array,
    groups: Groups,
    channels: int,
    f0: Array | None = None,
    out: Array | None = None,
) -> Array:
    """Finite-difference Jacobian (M, P) in the optimiser's coordinates, one evaluation per group of columns.

    Per-channel parameters of one field touch disjoint residuals (their own channel), so a group perturbs
    them together and each column keeps only its channel's rows: a GGX conductor on RGB costs 3
    evaluations per Jacobian instead of 7. Forward differences when f0 = f(x) is given (inside the
    optimiser), central ones otherwise (for the covariance). Columns are filled in a (P, M) buffer and
    returned transposed: contiguous column writes, quicker than strided ones at a million rows. ``out``
    is such a buffer from an earlier call with the same groups (its zeros stay where they were), or None.
    """
    base = f0 if f0 is not None else f(x)
    out = np.zeros((x.size, base.size)) if out is None else out
    for grp in groups:
        h = np.zeros_like(x)
        cols = [j for j, _ in grp]
        h[cols] = (1.5e-8 if f0 is not None else 1e-6) * np.maximum(1.0, np.abs(x[cols]))
        diff = f(x + h) - base if f0 is not None else (f(x + h) - f(x - h)) / 2.0
        for j, ch in grp:
            if ch is None:
                np.divide(diff, h[j], out=out[j])
            else:
                np.divide(diff[ch::channels], h[j], out=out[j, ch::channels])
    return out.T


class Problem:
    """The objective of one fit over a set of sample rows, in the optimiser's coordinates u."""

    def __init__(
        self, spec: FitSpec, s: Samples, loss: str, weighted: bool, is_log: Array, footprint: bool = False
    ) -> None:
        self.spec, self.c, self.is_log = spec, s.channels, is_log
        self.rows = Rows(s, footprint)
        cos_i, cos_o = s.wi[:, 2:3], s.wo[:, 2:3]
        self.g, curved = transform(loss, cos_i)
        s_noise = (self.g(s.value + s.std_error) - self.g(s.value - s.std_error)) / 2.0 if curved else s.std_error
        scale = s_noise if weighted else np.ones_like(s.value)
        w = np.ones_like(cos_i)
        if loss == "cosine_l2":
            w = cos_i * np.sqrt(np.sqrt(1.0 - cos_i**2) * np.sqrt(1.0 - cos_o**2))
        self.w_over, self.gy = w / scale, self.g(s.value)
        #: std of each objective residual implied by the std errors (1 for the weighted losses)
        self.nu = np.broadcast_to(w * s_noise / scale, s.value.shape).ravel()
        self.hinge = None if self.rows.hinge is None else np.repeat(self.rows.hinge, self.c)
        self.groups: Groups = []
        i = 0
        for q, k in zip(spec.params, spec.sizes(self.c), strict=True):
            self.groups.append([(i + ch, ch if q.per_channel else None) for ch in range(k)])
            i += k
        self._last: tuple[Array, Array] | None = None
        self._buffer: Array | None = None

    def native(self, u: Array) -> Array:
        """Optimiser coordinates to native parameter values."""
        return np.where(self.is_log, np.exp(np.where(self.is_log, u, 0.0)), u)

    def predict(self, u: Array) -> Array:
        """Model values (N, C) in 1/sr at the rows for optimiser coordinates u."""
        return self.rows.predict(self.spec, self.native(u))

    def residuals(self, u: Array) -> Array:
        """The objective's residual vector (N C,); lower-bound rows clipped to min(0, r)."""
        r = np.subtract(self.g(self.predict(u)), self.gy)
        r *= self.w_over
        r = r.ravel()
        if self.hinge is not None:
            np.minimum(r, 0.0, out=r, where=self.hinge)
        self._last = (u.copy(), r)
        return r

    def jac(self, u: Array, reuse: bool = False) -> Array:
        """Forward-difference Jacobian, reusing the residuals just computed at u (and with ``reuse`` its buffer)."""
        f0 = self._last[1] if self._last is not None and np.array_equal(self._last[0], u) else self.residuals(u)
        if not reuse:
            return jacobian(self.residuals, u, self.groups, self.c, f0)
        if self._buffer is None:
            self._buffer = np.zeros((u.size, f0.size))
        return jacobian(self.residuals, u, self.groups, self.c, f0, self._buffer)

    def solve(
        self, u0: Array, bounds: tuple[Array, Array], robust: str | None, f_scale: float, max_nfev: int | None = None
    ) -> optimize.OptimizeResult:
        """One bounded trust-region run from u0 (through projected residuals when there are many)."""
        if self.rows.n * self.c >= TALL_RESIDUALS:
            jac = functools.partial(self.jac, reuse=True)
            return solve_tall(self.residuals, jac, u0, bounds, robust, f_scale, max_nfev)
        from scipy import optimize  # here: the report's processes use the fit's types, never the solver

        return optimize.least_squares(
            self.residuals, u0, jac=self.jac, bounds=bounds, loss=robust or "linear", f_scale=f_scale,
            x_scale="jac", max_nfev=max_nfev,
        )  # fmt: skip


def stage_sizes(n: int, starts: int) -> list[int]:
    """Rows of the successive solves: a screen of SCREEN_SAMPLES, then STAGE_GROWTH-fold growth, then all n.

    One start on at most STAGE_GROWTH x SCREEN_SAMPLES rows is solved on all rows directly (no screen to do).
    """
    if n <= SCREEN_SAMPLES or (starts == 1 and n <= STAGE_GROWTH * SCREEN_SAMPLES):
        return [n]
    sizes = [SCREEN_SAMPLES]
    # A stage within 4x of all rows saves too little over polishing on all of them at once.
    while sizes[-1] * STAGE_GROWTH * 4 <= n:
        sizes.append(sizes[-1] * STAGE_GROWTH)
    return [*sizes, n]


def solve_staged(
    make: Callable[[Samples], Problem],
    s: Samples,
    tries: Sequence[Array],
    bounds: tuple[Array, Array],
    robust: str | None,
    f_scale: float,
    rng: np.random.Generator,
) -> tuple[optimize.OptimizeResult, int, Problem]:
    """Screen the starts, refine the winner stage by stage, polish on all rows (see the module docstring).

    Returns the final optimiser result, how many starts reached the winner's cost, and the problem on all rows.
    """
    sizes = stage_sizes(s.n, len(tries))
    stages = [make(s.subset(rng.choice(s.n, k, replace=False))) for k in sizes[:-1]]
    full = make(s)
    stages.append(full)
    results = [stages[0].solve(u, bounds, robust, f_scale) for u in tries]
    best = min(results, key=lambda r: r.cost)
    agreeing = sum(r.cost <= best.cost * (1 + 1e-6) + 1e-12 for r in results)
    for i, stage in enumerate(stages[1:], start=2):
        # A refinement only brings the start closer: where it does not converge quickly (a flat or
        # degenerate cost) the last stage, not a stage between, is where the remaining iterations belong.
        best = stage.solve(best.x, bounds, robust, f_scale, None if i == len(stages) else STAGE_MAX_NFEV)
    return best, int(agreeing), full
