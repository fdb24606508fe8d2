"""The stock-Mitsuba BSDF closest to any model, with the difference measured by Mitsuba itself.

A file that names ``gonio_model`` renders only where gonio is installed; a material library wants files
that stock Mitsuba 3 renders. :func:`native_projection` gives every model such a BSDF:

- models :func:`model.mitsuba.materials.to_mitsuba` maps natively (Lambert, GGX / Beckmann Cook-Torrance
  with exact Smith and exact Fresnel, with or without a Lambertian term) keep that exact mapping;
- everything else (Schlick Fresnel, Phong, Ward, metal-roughness, ...) is projected onto the native
  family ``diffuse`` + ``roughconductor`` (GGX, exact Smith, conductor Fresnel per channel: gonio's
  ``ggx_conductor+lambert``, which to_mitsuba writes as a ``blendbsdf``), fitted to the model's noise-free
  values at the direction pairs of :func:`model.fit.metal_roughness.sample_pairs` (cosine-weighted, with
  GGX-lobe pairs so specular peaks are resolved), and if that fit lands outside what maps natively
  (F0 below ``F0_MIN_NATIVE``), onto ``diffuse`` alone. A Cook-Torrance source (Schlick Fresnel, other
  masking: the ladder's usual candidates) starts the fit at its own parameters (:func:`warm_start`); other
  sources get the family's own guess and a random start.

Error. Whichever path, Mitsuba evaluates the BSDF it was given (``bsdf.eval`` divided by cos(theta) of
its ``wo``) on a fixed grid of directions, :data:`GRID_THETA_DEG` for both zenith angles (to 80 deg),
:data:`GRID_DPHI_DEG` for phi_o - phi_i and :data:`GRID_PHI_I_DEG` for phi_i (anisotropic models), and
that is compared with the gonio model at the same float32-rounded directions:

    rms_rel = sqrt( sum (f_mitsuba - f)^2 / sum f^2 )   over pairs and channels, unweighted,

per channel as well, and the worst |f_mitsuba - f| / f (f floored at :data:`REL_FLOOR` times the model's
RMS value on the grid). A uniform angle grid samples a narrow peak coarsely; the mirror configurations
(dphi 180, theta_o = theta_i) are on it, so a peak's height is compared, its width between grid points is
not. For native mappings the number is float32 rounding (GGX) or Mitsuba's Beckmann G1 fit.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np
import numpy.typing as npt

from model.base import BRDF
from model.cook_torrance import CookTorrance
from model.fit.metal_roughness import sample_pairs
from model.fit.samples import Samples
from model.fit.solve import fit
from model.fit.spec import LAMBERT, FitSpec, ggx_conductor
from model.geometry import spherical_to_vector
from model.mitsuba.materials import MitsubaMaterial, to_mitsuba
from model.mitsuba.variant import pick_variant, use_variant

Array = npt.NDArray[np.float64]

#: Zenith angles (degrees) of the error grid, for both directions.
GRID_THETA_DEG: tuple[float, ...] = tuple(float(t) for t in range(0, 81, 5))
#: Azimuth differences phi_o - phi_i (degrees) of the error grid.
GRID_DPHI_DEG: tuple[float, ...] = tuple(float(p) for p in range(0, 181, 10))
#: Incident azimuths (degrees): an anisotropic model differs along and across its tangent.
GRID_PHI_I_DEG: tuple[float, ...] = (0.0, 45.0, 90.0)
#: Floor of the worst relative difference's denominator, as a fraction of the model's RMS value.
REL_FLOOR = 0.01
#: Direction pairs the projection is fitted to.
FIT_SAMPLES = 2000
#: Fit starts (the spec's guess plus random ones); each costs a least-squares solve.
FIT_STARTS = 2
#: The native family non-native models are projected onto, richest first.
FAMILIES: tuple[FitSpec, ...] = (ggx_conductor(rho_d=True), LAMBERT)


@dataclass(frozen=True, eq=False)
class NativeProjection:
    """A stock-Mitsuba BSDF for ``source``: the gonio model it equals, its Mitsuba form and the error.

    ``exact`` is True when to_mitsuba maps the source itself natively (no projection); ``native_model``
    is the gonio model whose Mitsuba form ``material`` is (the source itself when exact); ``error`` holds
    the Mitsuba-evaluated difference (see the module docstring) as plain JSON values.
    """

    source: BRDF
    native_model: BRDF
    material: MitsubaMaterial
    exact: bool
    error: dict[str, Any]

    @property
    def bsdf(self) -> dict[str, Any]:
        """A fresh copy of the scene-dict entry (plain data, stock plugins only)."""
        return copy.deepcopy(self.material.bsdf)

    def summary(self) -> str:
        """One line: the mapping and its error (relative RMS over the grid, in percent)."""
        how = "exact mapping" if self.exact else f"projection onto {self.material.note}"
        return (
            f"stock Mitsuba {self.material.plugin} ({how}): relative RMS difference {self.error['rms_rel']:.2%}, "
            f"worst {self.error['worst_rel']:.1%} over the {self.error['pairs']}-pair grid, evaluated by Mitsuba"
        )


@functools.lru_cache(maxsize=4)
def grid_pairs(phi_i_deg: tuple[float, ...] = GRID_PHI_I_DEG) -> tuple[Array, Array]:
    """The error grid (wi, wo), each (N, 3), float32-rounded as Mitsuba sees them; phi_i slowest (read-only).

    Built once per process (every stock form's error is taken on it): an export standby builds it before the fit.
    """
    ti, to, dphi = np.meshgrid(np.radians(GRID_THETA_DEG), np.radians(GRID_THETA_DEG), np.radians(GRID_DPHI_DEG),
                               indexing="ij")  # fmt: skip
    wi, wo = [], []
    for phi in np.radians(phi_i_deg):
        wi.append(spherical_to_vector(ti.ravel(), np.full(ti.size, phi)))
        wo.append(spherical_to_vector(to.ravel(), phi + dphi.ravel()))
    f32 = np.float32
    return (_frozen(np.concatenate(wi).astype(f32).astype(np.float64)),
            _frozen(np.concatenate(wo).astype(f32).astype(np.float64)))  # fmt: skip


def _frozen(a: Array) -> Array:
    """``a`` made read-only: a cached array handed to every caller must not be changed by one."""
    a.setflags(write=False)
    return a


def mitsuba_values(bsdf: dict[str, Any], wi: Array, wo: Array, variant: str | None = None) -> Array:
    """Mitsuba's f_r in 1/sr of a scene-dict BSDF at model-convention pairs (N, 3) each; returns (N, 3).

    Radiance mode: Mitsuba's ``si.wi`` is the model's ``wo`` (the camera) and its ``wo`` the light.
    """
    name = variant or pick_variant("rgb")
    with use_variant(name):
        obj = mi.load_dict(copy.deepcopy(bsdf))
        ctx = mi.BSDFContext()
        view, light = wo.astype(np.float32), wi.astype(np.float32)
        if dr.is_jit_v(mi.Float):
            si = dr.zeros(mi.SurfaceInteraction3f, len(view))
            si.wi = mi.Vector3f(np.ascontiguousarray(view.T))
            value = np.array(obj.eval(ctx, si, mi.Vector3f(np.ascontiguousarray(light.T))), dtype=np.float64).T
        else:
            rows = []
            for a, b in zip(view, light, strict=True):
                si = dr.zeros(mi.SurfaceInteraction3f)
                si.wi = mi.Vector3f(*(float(x) for x in a))
                rows.append(list(obj.eval(ctx, si, mi.Vector3f(*(float(x) for x in b)))))
            value = np.array(rows, dtype=np.float64)
    cos = np.maximum(light[:, 2].astype(np.float64), 1e-12)
    return np.asarray(value.reshape(len(view), 3) / cos[:, None], dtype=np.float64)


def _values(model: BRDF, wi: Array, wo: Array) -> Array:
    return np.asarray(model.eval(wi, wo), dtype=np.float64).reshape(len(wi), -1)


def _grid_values(model: BRDF) -> Array:
    """The model's values on the whole error grid (read-only): an export takes them three times."""
    try:
        return _kept_grid_values(model)  # type: ignore[arg-type]
    except TypeError:  # a model that does not hash (a table of arrays) is evaluated each time
        return _values(model, *grid_pairs())


@functools.lru_cache(maxsize=2)
def _kept_grid_values(model: BRDF) -> Array:
    # Keyed by the model's value (frozen dataclasses hash their fields): equal models have equal values.
    return _frozen(_values(model, *grid_pairs()))


def _rms(g: Array, f: Array, w: Array) -> tuple[float, list[float]]:
    d2, f2 = np.sum(w[:, None] * (g - f) ** 2, axis=0), np.sum(w[:, None] * f**2, axis=0)
    return float(np.sqrt(d2.sum() / max(f2.sum(), 1e-300))), [float(x) for x in np.sqrt(d2 / np.maximum(f2, 1e-300))]


def grid_error(
    source: BRDF, bsdf: dict[str, Any], variant: str | None = None, *, isotropic: bool = True
) -> dict[str, Any]:
    """How far Mitsuba's ``bsdf`` is from ``source`` on the grid (module docstring), as JSON values.

    For an ``isotropic`` BSDF (every one :func:`native_projection` builds) Mitsuba evaluates the phi_i = 0
    slice only, since its other slices are the same numbers (the source is evaluated on all of them); an
    anisotropic one (a tabulated anisotropic model) is evaluated by Mitsuba on every slice.
    """
    name = variant or pick_variant("rgb")
    wi, wo = grid_pairs()
    f = _grid_values(source)
    if isotropic:
        slice_wi, slice_wo = grid_pairs(GRID_PHI_I_DEG[:1])
        g = np.tile(mitsuba_values(bsdf, slice_wi, slice_wo, name), (len(GRID_PHI_I_DEG), 1))
    else:
        g = mitsuba_values(bsdf, wi, wo, name)
    f = np.broadcast_to(f, g.shape) if f.shape[1] == 1 else f
    rms, per_channel = _rms(g, f, np.ones(len(f)))
    # What a camera sees of a unit area under a unit light, f cos_i cos_o, over the solid-angle measure.
    sin_i, sin_o = np.hypot(wi[:, 0], wi[:, 1]), np.hypot(wo[:, 0], wo[:, 1])
    rms_cos, _ = _rms(g, f, (wi[:, 2] * wo[:, 2]) ** 2 * sin_i * sin_o)
    floor = REL_FLOOR * float(np.sqrt(np.mean(f**2)))
    rel = np.abs(g - f) / np.maximum(np.abs(f), max(floor, 1e-300))
    i = int(np.argmax(rel.max(axis=1)))
    theta = np.degrees(np.arccos(np.clip([wi[i, 2], wo[i, 2]], -1.0, 1.0)))
    dphi = float(np.degrees(np.arctan2(wo[i, 1], wo[i, 0]) - np.arctan2(wi[i, 1], wi[i, 0])) % 360.0)
    return {
        "rms_rel": rms,
        "rms_rel_per_channel": per_channel,
        "rms_rel_cosine_weighted": rms_cos,
        "worst_rel": float(rel[i].max()),
        "worst_at_deg": {"theta_i": float(theta[0]), "theta_o": float(theta[1]),
                         "phi_o_minus_phi_i": min(dphi, 360.0 - dphi)},
        "pairs": len(wi),
        "grid_deg": {"theta_i": list(GRID_THETA_DEG), "theta_o": list(GRID_THETA_DEG),
                     "phi_o_minus_phi_i": list(GRID_DPHI_DEG), "phi_i": list(GRID_PHI_I_DEG)},
        "metric": "rms_rel: sqrt(sum (f_mitsuba - f)^2 / sum f^2) over the grid and channels, f_r in 1/sr; "
                  "rms_rel_cosine_weighted: the same with weights cos^2(theta_i) cos^2(theta_o) sin(theta_i) "
                  f"sin(theta_o) (f cos cos over solid angle: what a camera sees); worst_rel: max |f_mitsuba - f| / "
                  f"max(f, {REL_FLOOR:g} x RMS f)",
        "evaluated_by": f"mitsuba {mi.__version__} ({name}) against gonio's eval",
    }  # fmt: skip


#: Significant digits a renderer's measured error is kept to (``rounded_error``).
ERROR_DIGITS = 4


def rounded_error(error: dict[str, Any], digits: int = ERROR_DIGITS) -> dict[str, Any]:
    """``grid_error``'s metrics (relative, dimensionless) to ``digits`` significant digits; the rest as it is.

    Mitsuba's ``measured`` plugin reading one table gives them differing in their last bits from one process to the
    next: they are a renderer's measured error, not exact numbers, and the files that hold them must not vary.
    """

    def r(x: float) -> float:
        return float(f"{x:.{digits}g}")

    scalars = {k: r(error[k]) for k in ("rms_rel", "rms_rel_cosine_weighted", "worst_rel")}
    return {**error, **scalars, "rms_rel_per_channel": [r(x) for x in error["rms_rel_per_channel"]]}


def _constant(value: Any) -> Any:
    arr = np.atleast_1d(np.asarray(value, dtype=np.float64))
    return (lambda _samples: arr.copy()) if arr.size > 1 else float(arr[0])


def warm_start(spec: FitSpec, source: BRDF) -> FitSpec | None:
    """``spec`` started from a Cook-Torrance source's own rho_d, alpha and Fresnel (None for other sources).

    The usual candidates of the ladder are Cook-Torrance variants (Schlick Fresnel, other masking); started at
    their own parameters one start reaches the optimum the random starts find (on Lambert + GGX with Schlick
    Fresnel: the same error to 4 digits, with one start instead of several).
    """
    if spec.model is not CookTorrance or type(source) is not CookTorrance:
        return None
    if source.fresnel == "schlick":
        root = np.sqrt(np.clip(np.atleast_1d(np.asarray(source.f0, dtype=np.float64)), 1e-4, 0.95))
        eta, k = (1.0 + root) / (1.0 - root), np.zeros_like(root)  # the dielectric with that F0
    else:
        eta = np.atleast_1d(np.asarray(source.eta, dtype=np.float64))
        k = np.atleast_1d(np.asarray(source.k if source.fresnel == "conductor" else 0.0, dtype=np.float64))
    start = {"rho_d": source.rho_d, "alpha": source.alpha, "eta": eta, "k": k}
    params = []
    for p in spec.params:
        lo, hi = (p.lo * 1.0001, p.hi * 0.9999) if p.log else (p.lo, p.hi)
        params.append(dataclasses.replace(p, init=_constant(np.clip(start[p.name], lo, hi))))
    return dataclasses.replace(spec, params=tuple(params))


@functools.lru_cache(maxsize=4)
def fit_pairs(seed: int = 0) -> tuple[Array, Array, Array]:
    """The FIT_SAMPLES pairs (wi, wo, weight) a projection is fitted to (read-only; they depend on no model)."""
    wi, wo, w = sample_pairs(FIT_SAMPLES, np.random.default_rng(seed))
    return _frozen(wi), _frozen(wo), _frozen(w)


def _fit_family(spec: FitSpec, source: BRDF, seed: int) -> BRDF:
    wi, wo, w = fit_pairs(seed)
    f = _values(source, wi, wo)
    # Importance weights as std errors, as model.fit.metal_roughness does (their chi2 means nothing).
    se = np.broadcast_to(1.0 / np.sqrt(w / w.mean())[:, None], f.shape)
    samples = Samples(wi, wo, f, se, source=type(source).__name__)
    warm = warm_start(spec, source)
    result = fit(warm or spec, samples, loss="l2", starts=1 if warm else FIT_STARTS, seed=seed, weighted=True,
                 warn=False)  # fmt: skip
    return result.model


def native_projection(model: BRDF, *, seed: int = 0, variant: str | None = None) -> NativeProjection:
    """The stock-Mitsuba BSDF of ``model`` (f_r in 1/sr): exact where to_mitsuba maps it, else projected."""
    mat = to_mitsuba(model)
    if mat.native:
        return NativeProjection(model, model, mat, True, grid_error(model, mat.bsdf, variant))
    f = _grid_values(model)
    if not np.all(np.isfinite(f)) or not np.any(f > 0):
        raise ValueError(f"{type(model).__name__}: values not finite or all zero on the grid; nothing to project")
    for spec in FAMILIES:
        fitted = _fit_family(spec, model, seed)
        projected = to_mitsuba(fitted)
        if projected.native:
            error = grid_error(model, projected.bsdf, variant)
            return NativeProjection(model, fitted, projected, False, error)
    raise ValueError(f"{type(model).__name__}: no native Mitsuba projection mapped natively")  # Lambert always does
