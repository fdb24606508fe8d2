"""Where to measure next: the captures that most reduce the expected error of a fitted BRDF.

The error that matters to a user is not a parameter's std error but how far the fitted BRDF is from the
true one over the directions it will be used at. This module measures that error and, to first order,
predicts it from a fit, then picks the captures that shrink the prediction most (a greedy I-optimal, or
"integrated variance", design; Atkinson, Donev and Tobias, Optimum Experimental Designs, ch. 10).

Error measure. Over a fixed set of test pairs drawn cosine-distributed on both hemispheres (zenith up to
``max_theta_deg``; the rig does not reach grazing), the relative RMS difference of f_r summed over
channels, sqrt(mean |f_fit - f_true|^2 / mean |f_true|^2). Drawing cosine-distributed weights each pair
by cos(theta_i) cos(theta_o): an error counts as much as the light it misplaces. The scale-free variant
removes each channel's best common factor first: a measured BRDF's scale comes from the reference
calibration, which no choice of directions changes, so the shape error is what a sweep design decides.

Prediction. Linearise the model in the fit's coordinates u (log for log-scale parameters): with g_t the
sensitivities df/du at test pair t and Sigma the covariance of u, the expected squared error is
trace(A Sigma) with A = sum_t g_t g_t^T / sum_t |f_t|^2. Sigma is the inverse Fisher information of the
samples measured so far, sum g g^T / sigma^2, plus a weak prior (std ``PRIOR_SD`` in u) so that directions
the data do not yet constrain stay finite instead of dominating by an infinite amount.

Choice. A candidate capture c gives one reading per channel with noise S_c = diag(sigma_c^2); adding it
changes Sigma by the Woodbury update Sigma - K^T (S_c + K G_c^T)^-1 K, K = G_c Sigma, so it lowers the
expected squared error by trace((S_c + K G_c^T)^-1 K A K^T). The batch is chosen greedily, updating
Sigma after each pick; nothing is re-fitted inside a batch. sigma_c is the relative noise the rig
achieves (its exposure control aims at a fixed SNR) times the fitted value there.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from model.base import Model
from model.fit.samples import FitError
from model.fit.spec import FitSpec
from model.geometry import degrees_to_vector

Array = npt.NDArray[np.floating]
IntArray = npt.NDArray[np.intp]

#: Prior std of each fit coordinate (a factor e^3 for log-scale parameters): weak, only keeps Sigma finite.
PRIOR_SD = 3.0
#: Central-difference step in the fit's coordinates, relative to max(1, |u|).
STEP = 1e-5


@dataclass(frozen=True)
class ErrorPairs:
    """Direction pairs wi, wo (N, 3), cosine-distributed up to a zenith limit, at which errors are measured."""

    wi: Array
    wo: Array
    max_theta_deg: float


def cosine_zeniths(rng: np.random.Generator, n: int, max_theta_deg: float) -> Array:
    """n zenith angles (deg) drawn cosine-weighted over the cap up to max_theta_deg."""
    c2 = np.cos(np.radians(max_theta_deg)) ** 2
    # cos^2(theta) uniform in [cos^2(max), 1] is the cosine-weighted distribution restricted to the cap.
    out: Array = np.degrees(np.arccos(np.sqrt(rng.uniform(c2, 1.0, n))))
    return out


def error_pairs(n: int = 4000, *, max_theta_deg: float = 80.0, seed: int = 12345, isotropic: bool = True) -> ErrorPairs:
    """n cosine-distributed pairs with zeniths up to max_theta_deg (deg); phi_i = 0 for isotropic materials."""
    if n < 1 or not 0.0 < max_theta_deg <= 90.0:
        raise FitError(f"error_pairs: need n >= 1 and 0 < max_theta_deg <= 90; got n = {n}, {max_theta_deg}")
    rng = np.random.default_rng(seed)
    th_i, th_o = cosine_zeniths(rng, n, max_theta_deg), cosine_zeniths(rng, n, max_theta_deg)
    ph_i = np.zeros(n) if isotropic else rng.uniform(0.0, 360.0, n)
    ph_o = rng.uniform(0.0, 360.0, n)
    return ErrorPairs(degrees_to_vector(th_i, ph_i), degrees_to_vector(th_o, ph_o), max_theta_deg)


def brdf_error(fitted: Model, truth: Model, pairs: ErrorPairs, *, scale_free: bool = False) -> float:
    """Relative cosine-weighted RMS difference of two BRDFs over the test pairs (dimensionless).

    ``scale_free`` first scales each channel of the fit by the factor that fits the truth best, leaving
    the error of the shape: what a sweep's design decides, apart from the calibration's common scale.
    """
    f = np.asarray(fitted.eval(pairs.wi, pairs.wo), dtype=np.float64)
    t = np.asarray(truth.eval(pairs.wi, pairs.wo), dtype=np.float64)
    f, t = np.broadcast_arrays(f.reshape(len(f), -1), t.reshape(len(t), -1))
    if scale_free:
        f = f * (np.sum(f * t, axis=0) / np.maximum(np.sum(f * f, axis=0), 1e-300))
    return float(np.sqrt(np.sum((f - t) ** 2) / np.sum(t**2)))


def _internal(spec: FitSpec, x_native: Array, channels: int) -> tuple[Array, Array]:
    """The fit's coordinates u of native values x, and which coordinates are logarithmic."""
    is_log = np.concatenate([np.full(k, p.log) for p, k in zip(spec.params, spec.sizes(channels), strict=True)])
    x = np.asarray(x_native, dtype=np.float64)
    return np.where(is_log, np.log(np.where(is_log, x, 1.0)), x), is_log


def sensitivities(spec: FitSpec, x_native: npt.ArrayLike, wi: Array, wo: Array, channels: int) -> Array:
    """df_r/du (N, C, P) in 1/sr per fit coordinate at the pairs, by central differences (u: log where log)."""
    u, is_log = _internal(spec, np.asarray(x_native, dtype=np.float64), channels)

    def f(v: Array) -> Array:
        x = np.where(is_log, np.exp(np.where(is_log, v, 0.0)), v)
        m = spec.build(spec.values(x, channels), validate=False)
        with np.errstate(all="ignore"):
            out = np.asarray(m.eval(wi, wo), dtype=np.float64).reshape(len(wi), -1)
        return np.broadcast_to(out, (len(wi), channels))

    g = np.empty((len(wi), channels, u.size))
    for j in range(u.size):
        h = np.zeros_like(u)
        h[j] = STEP * max(1.0, abs(float(u[j])))
        g[:, :, j] = (f(u + h) - f(u - h)) / (2.0 * h[j])
    return np.nan_to_num(g, nan=0.0, posinf=0.0, neginf=0.0)


def fisher(g: Array, sigma: Array) -> Array:
    """Fisher information (P, P) of readings with sensitivities g (N, C, P) and noise sigma (N, C) in 1/sr."""
    gw = g / sigma[:, :, None]
    return np.einsum("ncp,ncq->pq", gw, gw)


def covariance(info: Array) -> Array:
    """Covariance (P, P) of the fit coordinates from the information plus the weak prior (see PRIOR_SD)."""
    m = info + np.eye(len(info)) / PRIOR_SD**2
    return np.linalg.inv(0.5 * (m + m.T))


def error_weight(g_test: Array, f_test: Array) -> Array:
    """A (P, P) such that trace(A Sigma) is the expected squared relative error over the test pairs."""
    return np.einsum("tcp,tcq->pq", g_test, g_test) / float(np.sum(f_test**2))


def expected_error(a: Array, cov: Array) -> float:
    """First-order expected relative RMS error of the fitted BRDF (dimensionless) for covariance cov."""
    return float(np.sqrt(max(np.trace(a @ cov), 0.0)))


def _gains(cov: Array, g: Array, s2: Array, a: Array) -> Array:
    k = np.einsum("mcp,pq->mcq", g, cov)
    m = np.einsum("mcq,mdq->mcd", k, g) + s2[:, :, None] * np.eye(g.shape[1])
    n = np.einsum("mcq,qr,mdr->mcd", k, a, k)
    return np.trace(np.linalg.solve(m, n), axis1=1, axis2=2)


@dataclass(frozen=True)
class Batch:
    """Chosen candidate indices in pick order, the predicted relative RMS error before and after each pick."""

    indices: IntArray
    error_before: float
    error_after: Array


def choose_batch(cov: Array, g_cand: Array, sigma_cand: Array, a: Array, k: int) -> Batch:
    """k candidates (of M, sensitivities (M, C, P), noise (M, C) in 1/sr) that most lower trace(A Sigma), greedily."""
    if k < 1 or k > len(g_cand):
        raise FitError(f"choose_batch: asked for {k} captures from {len(g_cand)} candidates")
    s2 = np.maximum(sigma_cand, 1e-300) ** 2
    cov = cov.copy()
    before = expected_error(a, cov)
    picked: list[int] = []
    after = np.empty(k)
    taken = np.zeros(len(g_cand), dtype=bool)
    for step in range(k):
        gains = np.where(taken, -np.inf, _gains(cov, g_cand, s2, a))
        j = int(np.argmax(gains))
        picked.append(j)
        taken[j] = True
        gc = g_cand[j]
        kk = gc @ cov
        cov = cov - kk.T @ np.linalg.solve(np.diag(s2[j]) + kk @ gc.T, kk)
        cov = 0.5 * (cov + cov.T)
        after[step] = expected_error(a, cov)
    return Batch(np.asarray(picked, dtype=np.intp), before, after)


def pooled(g: Array, sigma: Array, owner: IntArray, m: int) -> tuple[Array, Array]:
    """Each of m candidates' readings (rows of g (N, C, P), noise sigma (N, C) in 1/sr; ``owner`` (N,) names the
    candidate of each row) as P virtual readings of unit noise with the same information: what choose_batch
    needs of a capture that gives many readings (image mode's tiles).

    A candidate's information F = sum g g^T / sigma^2 is (P, P), of rank at most P; with F = L L^T the rows of
    L^T, each with noise 1, carry exactly F, so choose_batch's update of Sigma by a pick is the update by all its
    readings at once. Returns g (m, P, P) and sigma (m, P) of ones.
    """
    gw = g / np.maximum(sigma, 1e-300)[:, :, None]
    p = g.shape[-1]
    info = np.zeros((m, p, p))
    np.add.at(info, owner, np.einsum("ncp,ncq->npq", gw, gw))
    values, vectors = np.linalg.eigh(0.5 * (info + np.transpose(info, (0, 2, 1))))
    root = vectors * np.sqrt(np.maximum(values, 0.0))[:, None, :]  # L = V sqrt(lambda): L L^T = F
    return np.transpose(root, (0, 2, 1)), np.ones((m, p))
