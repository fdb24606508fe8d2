"""Any model as an RGL ``.bsdf`` file, the tabulated material stock Mitsuba 3 renders with its ``measured`` plugin.

The format is Dupuy & Jakob 2018, "An Adaptive Parameterization for Efficient Material Acquisition and
Rendering" (a Mitsuba tensor file, :mod:`model.mitsuba.tensor_file`). What Mitsuba's ``measured`` plugin
(``src/bsdfs/measured.cpp``) does with it, and so what this module writes:

- For the camera direction wi (Mitsuba's ``si.wi``: the model's ``wo``) at elevation theta_i and azimuth
  phi_i and the light wo, the half vector m is mapped to the unit square, u_m = (sqrt(2 theta_m / pi),
  (phi_m - phi_i + pi) / 2 pi) (phi_m itself, not relative, when anisotropic).
- ``vndf`` (phi_i x theta_i x n x n, float32) is a density over u_m for each tabulated incidence; Mitsuba
  builds a continuous marginal warp of it (``Marginal2D<Float, 2, true>``) and *inverts* u_m to a point of
  the unit square, ``sample``.
- ``rgb`` (phi_i x theta_i x 3 x s x s) is interpolated bilinearly at ``sample`` (and linearly between the
  tabulated theta_i, phi_i); with ``jacobian`` = 1 the result is multiplied by ndf(u_m) / (4 sigma(u_wi)),
  ``ndf`` and ``sigma`` being tables over the unit square (bilinear, not normalised). That product is
  Mitsuba's ``eval``: f_r cos(theta_light).
- ``luminance`` (phi_i x theta_i x s x s) is only importance sampling: renders draw ``sample`` from it, then
  the VNDF warp, then divide by the product of both densities, so any positive table keeps them unbiased.

So the file holds, at each node of the sample grid, f_r cos divided by ndf/(4 sigma) at the very direction
the warp maps that node to: Mitsuba's eval reproduces the model exactly at the nodes (to float32) and
interpolates in between. This module builds the warps with Mitsuba's own ``MarginalContinuous2D`` classes,
so the nodes' directions are the ones the plugin computes.

The NDF. Interpolation is good where the stored ratio f cos / (D / 4 sigma) is smooth, i.e. where D follows
the model's lobe. It is derived from the model's retro-reflection as Dupuy et al. 2015 ("Extracting
microfacet-based BRDF parameters from arbitrary materials with power iterations") do: a microfacet BRDF at
wi = wo = w has f(w, w) = F D(w) G1(w) / (4 cos^2) with Smith's G1(w) = cos / sigma(w), so D(w) is proportional
to f(w, w) cos(theta) sigma(w), iterated :data:`NDF_ITERATIONS` times from D = f cos^2 (sigma depends on D).
The retro-reflection taken is the excess over its minimum below 80 deg, so that a diffuse base does not
flatten the lobe's share; and D is mixed half and half (:data:`NDF_FLOOR_WEIGHT`) with a GGX NDF of alpha
:data:`NDF_FLOOR_ALPHA`, so that every direction gets samples (a diffuse-only model, whose excess is zero,
mixes that GGX with the uniform NDF, GGX alpha 1). Measured with the default grid (Mitsuba evaluating the
file on projection.py's grid): this mix keeps Lambert, Oren-Nayar, Phong n = 30 and n = 300 and Lambert +
GGX (alpha 0.05 and 0.2, Schlick) all within 3.2 % relative RMS, where the raw retro-reflection NDF
(diffuse base included) mixed with GGX alpha 0.2 was 23 % off for the alpha = 0.05 lobe, and mixed with 5 %
of the uniform NDF 15 % off for alpha 0.2.

Anisotropy. The format allows it (phi_i tabulated, absolute phi_m), and the plugin can fold phi_i by a
symmetry the table's phi_i range declares (``m_reduction`` = 2 pi / range: 4 folds the incidence into
x <= 0, y <= 0, 2 into y <= 0). Those foldings are not used: an incidence with y = 0 exactly (any view in
the x-z plane, a gonioreflectometer's in-plane sweep) folds to y = -0, which drjit's atan2 turns into
phi_i = +pi, outside a folded table's range [-pi, -pi / 2], so Mitsuba reads another incidence's slice
(measured: 5.6 % low for Ward at a view in the x-z plane, and its directional albedo there 17 % low).
Anisotropic models are tabulated over the whole turn, from -pi to pi, where +pi is a node. :func:`symmetry`
still tells an isotropic model from the rest (and says which mirror or half-turn symmetry the rest have).

Sizes (float32, 8-byte aligned) at the default grid: isotropic 0.8 MB; anisotropic, with the default 22.5 deg
azimuth step (17 azimuths), 13.4 MB; :attr:`Tabulated.size_bytes` says the exact figure.

One file past 400 lines on purpose: the NDF, the warps and the tables are one construction whose nodes
must be the directions Mitsuba's plugin computes; split, that invariant would span modules.
"""

from __future__ import annotations

import functools
import json
import os
import tempfile
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np
import numpy.typing as npt

from model.base import BRDF
from model.mitsuba.projection import grid_error, rounded_error
from model.mitsuba.tensor_file import tensor_bytes
from model.mitsuba.variant import pick_variant, use_variant
from model.serialize import to_json_dict
from model.version import gonio_version

Array = npt.NDArray[np.float64]

#: Allowed range of each TabulationGrid field (inclusive).
LIMITS: dict[str, tuple[int, int]] = {"samples": (4, 256), "theta_i": (2, 90), "phi_i": (2, 46), "ndf": (8, 128)}
#: Power iterations of the retro-reflection NDF (measured on Phong, Lambert + GGX, Ward and Oren-Nayar: after 6
#: it differs from 10 iterations' by at most 2e-6 of its peak, after 4 by 8e-5, after 2 by 3e-3).
NDF_ITERATIONS = 6
#: Share of the GGX NDF in the mix, and its alpha (see the module docstring).
NDF_FLOOR_WEIGHT = 0.5
NDF_FLOOR_ALPHA = 0.3
#: Directions are evaluated at most this far from the normal (the table's last theta node is 90 deg).
THETA_EVAL_MAX = np.radians(89.5)
#: Relative tolerance of the symmetry tests (the models' own float64 rounding is far below it).
SYMMETRY_RTOL = 1e-7
#: Rec. 709 luminance weights (what the ``luminance`` field is made of).
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


@dataclass(frozen=True)
class TabulationGrid:
    """Resolution of a tabulation: each field's range is in :data:`LIMITS`.

    samples: the s x s sample grid per tabulated incidence (the ``rgb`` field's last two axes).
    theta_i: incidence elevations, uniform from 0 to 90 deg.
    phi_i: incidence azimuths per quarter turn, ends included, uniform (anisotropic models only; 5 is a 22.5
        deg step, 17 azimuths over the turn).
    ndf: the n x n ``ndf``, ``sigma`` and ``vndf`` tables over the unit square.
    """

    samples: int = 32
    theta_i: int = 24
    phi_i: int = 5
    ndf: int = 64

    def __post_init__(self) -> None:
        for name, (lo, hi) in LIMITS.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or not lo <= value <= hi:
                raise ValueError(f"TabulationGrid.{name} = {value!r}; expected an integer in [{lo}, {hi}]")


@dataclass(frozen=True, eq=False)
class Tabulated:
    """A model tabulated in the RGL format: the tensor fields (read-only: the file is built once), and how."""

    model_name: str
    grid: TabulationGrid
    symmetry: int  # as symmetry() says: 0 isotropic (one azimuth); else 4, 2 or 1 (tabulated over the whole turn)
    fields: dict[str, npt.NDArray[Any]] = field(repr=False)

    @property
    def isotropic(self) -> bool:
        """Whether the table has a single incidence azimuth (Mitsuba then uses relative phi_m)."""
        return self.symmetry == 0

    @cached_property
    def _bytes(self) -> bytes:
        return tensor_bytes(self.fields)

    def to_bytes(self) -> bytes:
        """The ``.bsdf`` file's contents."""
        return self._bytes

    @property
    def size_bytes(self) -> int:
        """Size of the file in bytes."""
        return len(self._bytes)

    def write(self, path: str | os.PathLike[str]) -> Path:
        """Write the ``.bsdf`` file to ``path`` (beside it first, then renamed: never half written)."""
        target = Path(path)
        tmp = target.with_name(f".{target.name}.tmp")
        tmp.write_bytes(self.to_bytes())
        os.replace(tmp, target)
        return target

    def summary(self) -> str:
        """One line: resolution, symmetry and size."""
        t = self.fields["rgb"].shape
        how = "isotropic" if self.isotropic else "anisotropic, azimuths over the whole turn"
        return (f"RGL .bsdf ({how}): {t[0]} x {t[1]} incidences (phi_i x theta_i), {t[3]} x {t[4]} samples each, "
                f"{self.size_bytes / 1e6:.2f} MB")  # fmt: skip


def measured_bsdf(filename: str) -> dict[str, Any]:
    """The scene-dict entry of Mitsuba's ``measured`` plugin reading ``filename``."""
    return {"type": "measured", "filename": filename}


def _rgb(model: BRDF, wi: Array, wo: Array) -> Array:
    f = np.asarray(model.eval(wi, wo), dtype=np.float64).reshape(len(wi), -1)
    if f.shape[1] not in (1, 3):
        raise ValueError(f"{type(model).__name__}: {f.shape[1]} channels; an RGB .bsdf file holds 1 or 3")
    return np.array(np.broadcast_to(f, (len(wi), 3)))


def _sph(theta: Array, phi: Array) -> Array:
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)


def _u2theta(u: Array) -> Array:
    return np.asarray(u * u * (np.pi / 2.0))


def _u2phi(u: Array) -> Array:
    return np.asarray((2.0 * u - 1.0) * np.pi)


def _upper(n: int, rng: np.random.Generator) -> Array:
    z = rng.uniform(0.05, 1.0, n)
    phi = rng.uniform(-np.pi, np.pi, n)
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)


def symmetry(model: BRDF, pairs: int = 512, seed: int = 0) -> int:
    """0 if ``model`` is isotropic; else 4 (x and y mirrors), 2 (half turn) or 1 (none), tested at random pairs."""
    rng = np.random.default_rng(seed)
    wi, wo = _upper(pairs, rng), _upper(pairs, rng)
    f = _rgb(model, wi, wo)
    scale = max(float(np.abs(f).max()), 1e-300)

    def same(transform: Array) -> bool:
        g = _rgb(model, wi @ transform.T, wo @ transform.T)
        return bool(np.all(np.abs(g - f) <= SYMMETRY_RTOL * (np.abs(f) + 1e-9 * scale)))

    turns = rng.uniform(0.1, 2.0 * np.pi - 0.1, 3)
    rotations = [np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]]) for a in turns]
    if all(same(r) for r in rotations):
        return 0
    if same(np.diag([-1.0, 1.0, 1.0])) and same(np.diag([1.0, -1.0, 1.0])):
        return 4
    return 2 if same(np.diag([-1.0, -1.0, 1.0])) else 1


@dataclass(frozen=True)
class _Square:
    """The n x n nodes of the unit square (rows: u_y, phi; columns: u_x, theta) and their quadrature weights.

    Each is computed once (the NDF's power iterations read them a dozen times): use :func:`_square`, which
    keeps one per n for the process, so an export standby can build them before the fit.
    """

    n: int

    @functools.cached_property
    def u(self) -> tuple[Array, Array]:
        ux, uy = np.meshgrid(np.linspace(0.0, 1.0, self.n), np.linspace(0.0, 1.0, self.n))
        return _frozen(ux), _frozen(uy)

    @functools.cached_property
    def m(self) -> Array:
        ux, uy = self.u
        return _frozen(_sph(_u2theta(ux), _u2phi(uy)))

    @functools.cached_property
    def flat_m(self) -> Array:
        """``m`` as (n^2, 3)."""
        return self.m.reshape(-1, 3)

    @functools.cached_property
    def weights(self) -> Array:
        """Solid angle per node: trapezoid in u times d(omega)/du = 2 pi^2 u_x sin(theta)."""
        t = np.full(self.n, 1.0 / (self.n - 1))
        t[[0, -1]] *= 0.5
        ux, _ = self.u
        return _frozen(np.asarray(np.outer(t, t) * 2.0 * np.pi**2 * ux * np.sin(_u2theta(ux))))


def _frozen(a: Array) -> Array:
    a.setflags(write=False)  # shared by every tabulation in the process: no caller may change it
    return a


@functools.lru_cache(maxsize=4)
def _square(n: int) -> _Square:
    """The n x n square, shared by every tabulation at that resolution."""
    return _Square(n)


def prepare_tabulation(grid: TabulationGrid | None = None) -> None:
    """Build what :func:`tabulate` needs at ``grid`` that depends on no model (the unit square's nodes)."""
    sq = _square((grid or TabulationGrid()).ndf)
    _ = sq.flat_m, sq.weights


def _sigma(d: Array, sq: _Square, w: Array, isotropic: bool = False) -> Array:
    """Projected area sigma(w) = integral of D(m) max(0, w . m) over m, for directions w (..., 3).

    ``isotropic``: D and w on the square's nodes do not vary with azimuth (rows), so sigma is taken on the
    first row and repeated: n instead of n^2 integrals of n^2 nodes.
    """
    if isotropic:
        return np.broadcast_to(_sigma(d, sq, w[:1]), w.shape[:-1]).copy()
    m, q = sq.flat_m, (sq.weights * d).ravel()
    flat = w.reshape(-1, 3)
    out = np.concatenate([np.maximum(flat[i : i + 256] @ m.T, 0.0) @ q for i in range(0, len(flat), 256)])
    return out.reshape(w.shape[:-1])


def _normalise(d: Array, sq: _Square) -> Array:
    return np.asarray(d / np.sum(sq.weights * d * np.cos(_u2theta(sq.u[0]))))


def retro_ndf(model: BRDF, n: int, isotropic: bool) -> tuple[Array, Array]:
    """The NDF (n x n over the unit square, normalised: integral of D cos = 1) and sigma at the same nodes."""
    sq = _square(n)
    ux, _ = sq.u
    theta = np.minimum(_u2theta(ux), THETA_EVAL_MAX)
    w = _sph(theta, _u2phi(sq.u[1]))
    retro = (_rgb(model, w.reshape(-1, 3), w.reshape(-1, 3)) @ LUMINANCE).reshape(n, n)
    if isotropic:
        retro = np.broadcast_to(retro.mean(axis=0), retro.shape)
    if not np.all(np.isfinite(retro)):
        raise ValueError(f"{type(model).__name__}: retro-reflection f(w, w) not finite; it cannot be tabulated")
    below = np.degrees(_u2theta(ux)) <= 80.0
    excess = np.maximum(retro - retro[below].min(), 0.0)
    a2 = NDF_FLOOR_ALPHA**2
    ct = np.cos(_u2theta(ux))
    ggx = _normalise(a2 / (np.pi * ((a2 - 1.0) * ct**2 + 1.0) ** 2), sq)
    if excess.max() <= 1e-6 * max(float(np.abs(retro).max()), 1e-300):
        peak = _normalise(np.ones_like(ct), sq)  # no lobe: the uniform NDF (GGX alpha 1) takes its share
    else:
        peak = _normalise(excess * ct**2 + 1e-300, sq)
        for _ in range(NDF_ITERATIONS):
            peak = _normalise(excess * ct * _sigma(peak, sq, sq.m, isotropic) + 1e-300, sq)
    d = (1.0 - NDF_FLOOR_WEIGHT) * peak + NDF_FLOOR_WEIGHT * ggx
    return d, _sigma(d, sq, sq.m, isotropic)


def _points(x: Array, y: Array) -> Any:
    return mi.Point2f(np.ascontiguousarray(x, dtype=np.float32), np.ascontiguousarray(y, dtype=np.float32))


def _sample(warp: Any, x: Array, y: Array, phi: Array, theta: Array) -> tuple[Array, Array]:
    """Mitsuba's VNDF warp of sample-square points (x, y) at incidences (phi, theta), per lane: u_m (x, y)."""
    if dr.is_jit_v(mi.Float):
        u, _ = warp.sample(_points(x, y), mi.Vector2f(_points(phi, theta)))
        return np.array(u.x, dtype=np.float64), np.array(u.y, dtype=np.float64)
    out = [warp.sample(mi.Point2f(float(a), float(b)), mi.Vector2f(float(c), float(d)))[0]
           for a, b, c, d in zip(x, y, phi.astype(np.float32), theta.astype(np.float32), strict=True)]  # fmt: skip
    return np.array([o[0] for o in out], dtype=np.float64), np.array([o[1] for o in out], dtype=np.float64)


def _eval2d(table: Any, x: Array, y: Array) -> Array:
    """Mitsuba's bilinear interpolation of a 2D table (MarginalContinuous2D0, not normalised) at (x, y)."""
    if dr.is_jit_v(mi.Float):
        return np.array(table.eval(_points(x, y)), dtype=np.float64)
    return np.array([table.eval(mi.Point2f(float(a), float(b))) for a, b in zip(x, y, strict=True)], dtype=np.float64)


def _phi_nodes(isotropic: bool, per_quarter: int) -> Array:
    if isotropic:
        return np.zeros(1)
    # The whole turn, both ends included (the same direction): Mitsuba's folded ranges miss y = 0 (docstring).
    return np.asarray(np.linspace(-np.pi, np.pi, 4 * (per_quarter - 1) + 1))


def tabulate(model: BRDF, grid: TabulationGrid | None = None, *, variant: str | None = None) -> Tabulated:
    """``model`` (f_r in 1/sr) as an RGL .bsdf table for Mitsuba's ``measured`` plugin (module docstring)."""
    grid = grid or TabulationGrid()
    name = type(model).__name__
    sym = symmetry(model)
    ndf, sigma = retro_ndf(model, grid.ndf, sym == 0)
    sq = _square(grid.ndf)
    theta_i = np.linspace(0.0, np.pi / 2.0, grid.theta_i)
    phi_i = _phi_nodes(sym == 0, grid.phi_i)
    s = grid.samples
    sx, sy = (a.ravel() for a in np.meshgrid(np.linspace(0.0, 1.0, s), np.linspace(0.0, 1.0, s)))
    vndf = np.empty((len(phi_i), len(theta_i), grid.ndf, grid.ndf), np.float32)
    ux, _ = sq.u
    jac = ux * np.sin(_u2theta(ux))
    f32 = np.float32
    with use_variant(variant or pick_variant("rgb")):
        for p, phi in enumerate(phi_i):
            for t, th in enumerate(theta_i):
                view = _sph(np.array(min(th, THETA_EVAL_MAX)), np.array(phi))
                # The VNDF D(m) <wi . m> / sigma(wi) as a density over u_m (Mitsuba normalises it).
                vndf[p, t] = ndf * np.maximum(sq.m @ view, 0.0) * jac + 1e-12
        ndf32, sigma32 = ndf.astype(f32), sigma.astype(f32)
        warp = mi.MarginalContinuous2D2(vndf, [phi_i.astype(f32).tolist(), theta_i.astype(f32).tolist()], True)
        ndf_table = mi.MarginalContinuous2D0(ndf32, normalize=False, enable_sampling=False)
        sigma_table = mi.MarginalContinuous2D0(sigma32, normalize=False, enable_sampling=False)
        # Every incidence's nodes in one call each: lanes ordered (phi_i, theta_i, row, column) like the field.
        pp, tt = (a.ravel() for a in np.meshgrid(phi_i, theta_i, sx, indexing="ij")[:2])
        xs, ys = np.tile(sx, len(phi_i) * len(theta_i)), np.tile(sy, len(phi_i) * len(theta_i))
        ux_m, uy_m = _sample(warp, xs, ys, pp.astype(f32), tt.astype(f32))
        d = _eval2d(ndf_table, ux_m, uy_m)
        sig = _eval2d(sigma_table, np.sqrt(2.0 * tt / np.pi), (pp + np.pi) / (2.0 * np.pi))
    m = _sph(_u2theta(ux_m), _u2phi(uy_m) + (pp if sym == 0 else 0.0))
    view = _sph(np.minimum(tt, THETA_EVAL_MAX), pp)
    light = 2.0 * np.sum(m * view, axis=1, keepdims=True) * m - view
    cos_l = np.maximum(light[:, 2], 0.0)
    lit = light.copy()
    lit[:, 2] = np.maximum(lit[:, 2], 1e-4)  # continued to the horizon, where cos_l takes it to 0
    lit /= np.linalg.norm(lit, axis=1, keepdims=True)
    f = _rgb(model, lit, view) * (cos_l * 4.0 * sig / np.maximum(d, 1e-30))[:, None]
    rgb = np.moveaxis(f.reshape(len(phi_i), len(theta_i), s, s, 3), -1, 2).astype(f32)
    if not np.all(np.isfinite(rgb)) or np.any(rgb < 0.0):
        bad = "not finite" if not np.all(np.isfinite(rgb)) else "negative"
        raise ValueError(f"{name}: f_r is {bad} at some tabulated directions; it cannot be tabulated")
    if not np.any(rgb > 0.0):
        raise ValueError(f"{name}: f_r is zero at every tabulated direction; nothing to tabulate")
    lum = np.moveaxis(rgb, 2, -1) @ LUMINANCE.astype(f32)
    lum = np.maximum(lum, 1e-6 * float(lum.max())).astype(f32)
    try:
        what = json.dumps(to_json_dict(model))
    except TypeError:  # any object with eval tabulates; only gonio's models have a JSON form
        what = name
    description = f"gonio {gonio_version()}: {what}"
    fields: dict[str, npt.NDArray[Any]] = {
        "description": np.frombuffer(description.encode(), dtype=np.uint8),
        "theta_i": theta_i.astype(f32),
        "phi_i": phi_i.astype(f32),
        "ndf": ndf32,
        "sigma": sigma32,
        "vndf": vndf,
        "luminance": lum,
        "rgb": rgb,
        "jacobian": np.ones(1, np.uint8),
    }
    return Tabulated(name, grid, sym, fields)


def tabulated_error(model: BRDF, table: Tabulated, variant: str | None = None) -> dict[str, Any]:
    """Mitsuba's ``measured`` plugin reading ``table`` against ``model`` on projection.py's grid (rounded metrics)."""
    with tempfile.TemporaryDirectory(prefix="gonio-bsdf-") as tmp:
        path = table.write(Path(tmp) / "material.bsdf")
        return rounded_error(grid_error(model, measured_bsdf(str(path)), variant, isotropic=table.isotropic))

