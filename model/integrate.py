"""Integration over the hemisphere with a selectable accuracy: quadrature or importance-sampled Monte Carlo.

Quadrature is Gauss-Legendre in cos(theta) times the trapezoid rule in phi: exact for polynomials in
cos(theta) and smooth in phi, excellent for diffuse or broad lobes, and unable to resolve a lobe
narrower than its grid. Monte Carlo mixes cosine-weighted sampling with sampling of the model's
microfacet lobe (when it declares one, with the share of samples it should get) and weights by the
mixture density (one-sample balance heuristic), so narrow lobes converge too; it returns a standard
error. The cosine share never drops below 10 %, so diffuse parts stay covered.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from model import microfacet
from model.base import BRDF
from model.geometry import reflect

Array = npt.NDArray[np.floating]


@dataclass(frozen=True)
class Estimate:
    """An integral's value and its standard error (0 for quadrature, whose error is not estimated)."""

    value: Array
    stderr: Array


def hemisphere_quadrature(n_theta: int = 64, n_phi: int = 128) -> tuple[Array, Array]:
    """Directions (n_theta * n_phi, 3) and solid-angle weights (sr) summing to 2 pi."""
    if n_theta < 1 or n_phi < 1:
        raise ValueError(f"quadrature needs n_theta >= 1 and n_phi >= 1; got {n_theta}, {n_phi}")
    x, w = np.polynomial.legendre.leggauss(n_theta)
    mu = 0.5 * (x + 1.0)
    wmu = 0.5 * w
    phi = (np.arange(n_phi) + 0.5) * (2.0 * np.pi / n_phi)
    s = np.sqrt(1.0 - mu * mu)
    dirs = np.stack(
        [np.outer(s, np.cos(phi)), np.outer(s, np.sin(phi)), np.repeat(mu[:, None], n_phi, axis=1)],
        axis=-1,
    ).reshape(-1, 3)
    weights = np.repeat(wmu * (2.0 * np.pi / n_phi), n_phi)
    return dirs, weights


def _cosine_sample(u1: Array, u2: Array) -> Array:
    r = np.sqrt(u1)
    phi = 2.0 * np.pi * u2
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1.0 - u1))], axis=-1)


def _lobe_of(model: BRDF) -> tuple[str, float, float] | None:
    """(distribution, alpha, share of samples) of a model's microfacet lobe, if it declares one."""
    lobe = getattr(model, "lobe", None)
    return lobe() if callable(lobe) else None


def directional_albedo(
    model: BRDF,
    wi: npt.ArrayLike,
    n: int = 16384,
    method: str = "quadrature",
    rng: np.random.Generator | int | None = 0,
) -> Estimate:
    """Directional albedo: integral of f(wi, wo) cos(theta_o) over the hemisphere (dimensionless).

    n is the number of evaluations; "quadrature" splits it as n/2 x ... (1:2 theta:phi), "mc" draws
    n importance samples with the given seed or generator.
    """
    w = np.asarray(wi, dtype=float)
    if method == "quadrature":
        n_theta = max(1, int(np.sqrt(n / 2)))
        dirs, weights = hemisphere_quadrature(n_theta, max(1, n // n_theta))
        f = np.asarray(model.eval(w, dirs))
        integrand = f * (dirs[:, 2] * weights).reshape((-1,) + (1,) * (f.ndim - 1))
        value = integrand.sum(axis=0)
        return Estimate(value, np.zeros_like(value))
    if method == "mc":
        if isinstance(rng, int | np.integer) and not isinstance(rng, bool):
            return _albedo_mc(model, w, n, _draws(n, int(rng)))
        return _albedo_mc(model, w, n, _Draws(np.random.default_rng(rng).random((n, 3))))
    raise ValueError(f"method = {method!r}: expected 'quadrature' or 'mc'")


class _Draws:
    """The uniform numbers (n, 3) of one Monte Carlo albedo and what follows from them alone, each made once.

    A seeded albedo at several incidences (material.json states five) draws the same numbers at each, so the
    cosine-weighted directions and each lobe's half vectors are the same arrays for all of them.
    """

    def __init__(self, u: Array) -> None:
        self.u = u
        self._half: tuple[tuple[str, float], Array] | None = None  # the last lobe's only: a batch sees many

    @functools.cached_property
    def cosine(self) -> Array:
        """Cosine-weighted directions (n, 3) from u[:, 0] and u[:, 1]."""
        return _cosine_sample(self.u[:, 0], self.u[:, 1])

    def half(self, kind: str, alpha: float) -> Array:
        """Half vectors (n, 3) of the ``kind`` lobe at ``alpha`` (as microfacet.sample_half_vector draws them)."""
        key = (kind, alpha)
        if self._half is None or self._half[0] != key:
            self._half = key, microfacet.half_vectors(kind, alpha, self.u[:, 0], self.u[:, 1])[0]
        return self._half[1]


@functools.lru_cache(maxsize=2)
def _draws(n: int, seed: int) -> _Draws:
    """The draws of a seeded albedo (``rng`` an int), shared by every call with the same n and seed."""
    u = np.random.default_rng(seed).random((n, 3))
    u.setflags(write=False)
    return _Draws(u)


def prepare_albedo(n: int, seed: int = 0) -> None:
    """Draw what a seeded ``directional_albedo(..., n, method="mc", rng=seed)`` needs before any model is known."""
    _ = _draws(n, seed).cosine


def _albedo_mc(model: BRDF, wi: Array, n: int, draws: _Draws) -> Estimate:
    u = draws.u
    lobe = _lobe_of(model)
    dirs = draws.cosine
    if lobe is not None:
        h = draws.half(lobe[0], lobe[1])
        use_lobe = u[:, 2] < lobe[2]
        dirs = np.where(use_lobe[:, None], reflect(wi, h), dirs)
    cos_o = dirs[:, 2]
    pdf = np.maximum(cos_o, 0.0) / np.pi
    if lobe is not None:
        hh = dirs + wi
        hh = hh / np.maximum(np.linalg.norm(hh, axis=-1, keepdims=True), 1e-300)
        cos_h = hh[:, 2]
        d_cos = microfacet.distribution_d(lobe[0], cos_h, lobe[1]) * cos_h
        pdf_lobe = d_cos / np.maximum(4.0 * np.abs(np.sum(wi * hh, axis=-1)), 1e-300)
        pdf = (1.0 - lobe[2]) * pdf + lobe[2] * pdf_lobe
    f = np.asarray(model.eval(wi, dirs))
    ok = (cos_o > 0) & (pdf > 0)
    weight = np.where(ok, np.maximum(cos_o, 0.0) / np.where(ok, pdf, 1.0), 0.0)
    x = f * weight.reshape((-1,) + (1,) * (f.ndim - 1))
    return Estimate(x.mean(axis=0), x.std(axis=0, ddof=1) / np.sqrt(n))


def integrate_hemisphere(
    func: Callable[[Array], Array], n: int = 16384, method: str = "quadrature",
    rng: np.random.Generator | int | None = 0,
) -> Estimate:
    """Integral over the upper hemisphere of func(directions (N, 3)) -> (N, ...) with respect to solid angle."""
    if method == "quadrature":
        n_theta = max(1, int(np.sqrt(n / 2)))
        dirs, weights = hemisphere_quadrature(n_theta, max(1, n // n_theta))
        vals = np.asarray(func(dirs))
        # An explicit weighted sum, not tensordot: BLAS threads contend with the caller's on 2 cores.
        value = np.sum(weights.reshape((-1,) + (1,) * (vals.ndim - 1)) * vals, axis=0)
        return Estimate(value, np.zeros_like(value))
    if method == "mc":
        g = np.random.default_rng(rng)
        u = g.random((n, 2))
        # Uniform over the hemisphere: pdf 1 / (2 pi).
        z = u[:, 0]
        r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
        phi = 2.0 * np.pi * u[:, 1]
        dirs = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
        vals = np.asarray(func(dirs)) * (2.0 * np.pi)
        return Estimate(vals.mean(axis=0), vals.std(axis=0, ddof=1) / np.sqrt(n))
    raise ValueError(f"method = {method!r}: expected 'quadrature' or 'mc'")
