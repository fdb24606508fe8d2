"""Physical checks a user can run on any BRDF (analytic, tabulated or fitted): reciprocity, energy, sanity.

Each returns a small report with the worst case found, so a failed check says where it failed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from model.base import BRDF
from model.geometry import spherical_to_vector
from model.integrate import directional_albedo

Array = npt.NDArray[np.floating]


def random_hemisphere(n: int, rng: np.random.Generator) -> Array:
    """n directions uniform over the upper hemisphere, shape (n, 3)."""
    z = rng.random(n)
    phi = 2.0 * np.pi * rng.random(n)
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


@dataclass(frozen=True)
class ReciprocityReport:
    """Worst relative asymmetry |f(wi, wo) - f(wo, wi)| / max(|f|) over the pairs tried."""

    max_rel_error: float
    worst_wi: Array
    worst_wo: Array
    tolerance: float

    @property
    def passed(self) -> bool:
        """True when the worst asymmetry is within the tolerance."""
        return self.max_rel_error <= self.tolerance


def check_reciprocity(
    model: BRDF, n: int = 10_000, rng: np.random.Generator | int | None = 0, tolerance: float = 1e-9
) -> ReciprocityReport:
    """Evaluate f both ways on n random upper-hemisphere pairs and report the worst relative asymmetry."""
    g = np.random.default_rng(rng)
    wi, wo = random_hemisphere(n, g), random_hemisphere(n, g)
    a = np.asarray(model.eval(wi, wo), dtype=float).reshape(n, -1)
    b = np.asarray(model.eval(wo, wi), dtype=float).reshape(n, -1)
    scale = np.maximum(np.maximum(np.abs(a), np.abs(b)), 1e-300)
    rel = np.max(np.abs(a - b) / scale, axis=-1)
    i = int(np.argmax(rel))
    return ReciprocityReport(float(rel[i]), wi[i], wo[i], tolerance)


@dataclass(frozen=True)
class EnergyReport:
    """Directional albedo per incident zenith angle, with the largest one and where it occurs."""

    theta_i: Array
    albedo: Array
    stderr: Array
    max_albedo: float
    theta_at_max: float
    tolerance: float

    @property
    def passed(self) -> bool:
        """True when no albedo exceeds 1 by more than the tolerance plus three standard errors."""
        margin = self.tolerance + 3.0 * np.max(self.stderr, initial=0.0)
        return bool(self.max_albedo <= 1.0 + margin)


def check_energy(
    model: BRDF,
    theta_i: npt.ArrayLike | None = None,
    n: int = 65_536,
    method: str = "auto",
    rng: np.random.Generator | int | None = 0,
    tolerance: float = 1e-3,
) -> EnergyReport:
    """Directional albedo at several incident zenith angles (radians; default 0 to 89 degrees).

    method "auto" uses importance-sampled Monte Carlo for models that declare a microfacet lobe and
    quadrature otherwise: a (cos theta, phi) grid cannot resolve a narrow lobe near grazing (measured:
    albedo 11 instead of 0.90 at alpha 0.05, theta_i 85 deg, n = 256; still 0.14 off at n = 65536),
    and would report violations that are not there.
    """
    th = np.radians(np.linspace(0.0, 89.0, 12)) if theta_i is None else np.asarray(theta_i, dtype=float)
    if method == "auto":
        method = "mc" if callable(getattr(model, "lobe", None)) else "quadrature"
    g = np.random.default_rng(rng)
    values, errors = [], []
    for t in th:
        est = directional_albedo(model, spherical_to_vector(t, 0.0), n=n, method=method, rng=g)
        values.append(np.max(np.atleast_1d(est.value)))
        errors.append(np.max(np.atleast_1d(est.stderr)))
    alb, err = np.array(values), np.array(errors)
    i = int(np.argmax(alb))
    return EnergyReport(th, alb, err, float(alb[i]), float(th[i]), tolerance)


@dataclass(frozen=True)
class SanityReport:
    """Counts of non-finite and negative values over a sweep of extreme and random directions."""

    n_evaluated: int
    n_nonfinite: int
    n_negative: int

    @property
    def passed(self) -> bool:
        """True when every value was finite and non-negative."""
        return self.n_nonfinite == 0 and self.n_negative == 0


def extreme_pairs(dtype: npt.DTypeLike = np.float64) -> tuple[Array, Array]:
    """Direction pairs at the numerical extremes the project tests: grazing, equal, opposite, mirrored."""
    eps = [0.0, 1e-12, 1e-7, 1e-3]
    dirs = [np.array([np.sqrt(max(0.0, 1.0 - e * e)), 0.0, e]) for e in eps]
    dirs += [np.array([0.0, 0.0, 1.0]), np.array([0.6, 0.0, 0.8]), np.array([-0.6, 0.0, 0.8])]
    dirs += [-d for d in dirs[:2]] + [np.array([0.6, 0.0, -0.8])]
    wi, wo = [], []
    for a in dirs:
        for b in dirs:
            wi.append(a)
            wo.append(b)
            wo.append(np.array([-a[0], -a[1], a[2]]))  # nearly opposite azimuth: h near-horizontal
            wi.append(a)
    return np.array(wi, dtype=dtype), np.array(wo, dtype=dtype)


def check_sanity(model: BRDF, n: int = 2000, rng: np.random.Generator | int | None = 0) -> SanityReport:
    """Evaluate at the extreme pairs (float64 and float32) and at n random pairs; count bad values."""
    g = np.random.default_rng(rng)
    total = nonfinite = negative = 0
    batches = [extreme_pairs(np.float64), extreme_pairs(np.float32)]
    batches.append((random_hemisphere(n, g), random_hemisphere(n, g)))
    for wi, wo in batches:
        f = np.asarray(model.eval(wi, wo))
        total += f.size
        nonfinite += int(np.count_nonzero(~np.isfinite(f)))
        negative += int(np.count_nonzero(f < 0))
    return SanityReport(total, nonfinite, negative)
