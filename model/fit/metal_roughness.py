"""The glTF metal-roughness material closest to any BRDF: a projection, with its error reported.

Game engines and glTF viewers take one material model, metal-roughness (:class:`model.MetalRoughness`:
base colour per channel, metallic, roughness). A material measured and fitted here is usually something
else (a conductor with an exact complex index, a plastic, Ward, a MERL table), so exporting it means
projecting it: find the metal-roughness parameters whose BRDF is closest, and say how close that is.

Distance. What a camera collects from a unit area of the sample under a unit light is f cos_i cos_o
(irradiance falls with cos_i, the area in view shrinks with cos_o), so the projection uses

    E^2 = int int (f_mr - f)^2 cos_i^2 cos_o^2 dw_i dw_o  /  int int f^2 cos_i^2 cos_o^2 dw_i dw_o,

summed over channels: Ngan et al.'s cosine-weighted L2 made symmetric in the two directions (theirs
weights cos_i only, which is not reciprocal and gives grazing views, which a camera sees edge-on,
full weight). The fit minimises exactly the E it reports, and E is reported as ``rms_rel``.

Samples. Noise-free values of the source at random direction pairs: wi cosine-distributed, wo from a
mixture of cosine-distributed directions (:data:`COSINE_SHARE`) and mirror reflections about GGX half
vectors at the roughnesses :data:`LOBE_ALPHAS`, each sample weighted by target / sampling density.
Cosine sampling alone puts only ~alpha^2 of its pairs in a specular peak: for a plastic at alpha 0.1,
E of one fixed projection estimated from 10^5 such pairs ranged over 0.057-0.092 for five seeds, and
the fit followed whichever peak samples it drew. With the mixture, three seeds gave E = 6.06-6.10 %
against 6.10 % by quadrature; it resolves peaks down to alpha ~0.03. The weights reach the fit
through :class:`model.fit.samples.Samples`' std_error (1 / sqrt(weight), loss "l2", weighted): here
they are importance weights, not noise, so the fit's chi2 means nothing and is not reported. A
relative std error (each pair's error a fraction of f) was tried and rejected: it gives dark tails the
same say as the highlight and does not minimise E.

Error. E is estimated again on :data:`ERROR_SAMPLES` fresh pairs (not the fitted ones, so it is not
optimistic), per channel and pooled, together with the worst relative difference |f_mr - f| / f over
pairs with both directions within :data:`GRAZING_DEG` of the normal (f floored at :data:`REL_FLOOR`
times the material's RMS value, so zeros of f do not divide), and where that worst pair lies.
For example: a gold GGX conductor (alpha 0.3) projects to metallic 1, roughness
0.549 (sqrt 0.3 = 0.548) with E = 1.5 % (Schlick against exact Fresnel, height-correlated against
separable Smith); a Lambert to metallic 0, roughness 1 with E = 0.9 % and up to 240 % near 80 deg in
blue, the white F(0.04) lobe and (1 - F) diffuse weight glTF's fresnel_mix forces on every dielectric;
a metal-roughness source comes back to rounding.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from model import microfacet
from model.base import BRDF
from model.fit.samples import Samples
from model.fit.solve import fit
from model.fit.spec import FitSpec, Param
from model.geometry import reflect
from model.metal_roughness import MetalRoughness
from model.serialize import is_serialisable, to_json_dict

Array = npt.NDArray[np.float64]

#: Smallest fitted perceptual roughness: alpha = 1e-4, the clamp of model.microfacet.
ROUGHNESS_MIN = 0.01
#: What the projection varies: base colour per channel, one metallic and one roughness.
METAL_ROUGHNESS = FitSpec(
    "metal_roughness", MetalRoughness,
    (
        Param("base_color", 0.0, 1.0, 0.5, per_channel=True),
        Param("metallic", 0.0, 1.0, 0.5, channel_ok=False),
        Param("roughness", ROUGHNESS_MIN, 1.0, 0.5, log=True, channel_ok=False),
    ),
)  # fmt: skip
#: Share of wo drawn cosine-distributed; the rest is split evenly among the GGX lobes below.
COSINE_SHARE = 0.5
#: GGX roughnesses whose mirror lobes the samples resolve (peaks narrower than the smallest are undersampled).
LOBE_ALPHAS: tuple[float, ...] = (0.03, 0.1, 0.3)
#: Pairs the projection is fitted to (to_metal_roughness's default).
FIT_SAMPLES = 4000
#: Fresh pairs on which the reported error is estimated.
ERROR_SAMPLES = 50_000
#: Zenith angle (degrees, either direction) beyond which pairs count as grazing for the worst difference.
GRAZING_DEG = 80.0
#: Floor of the denominator of the worst relative difference, as a fraction of the source's RMS value.
REL_FLOOR = 0.01


@dataclass(frozen=True, eq=False)
class MetalRoughnessFit:
    """The metal-roughness material closest to ``source`` and how far it is (see the module docstring).

    ``rms_rel``: E pooled over channels (dimensionless; 0.01 = 1 %); ``rms_rel_per_channel`` the same per
    channel; ``worst_rel`` the largest |f_mr - f| / f away from grazing, at ``worst_at_deg`` = (theta_i,
    theta_o, phi_o - phi_i) in degrees; ``starts_agreeing`` of ``starts`` fit starts reached the optimum.
    """

    material: MetalRoughness
    source: BRDF
    rms_rel: float
    rms_rel_per_channel: tuple[float, ...]
    worst_rel: float
    worst_at_deg: tuple[float, float, float]
    n_fit: int
    n_error: int
    starts: int
    starts_agreeing: int

    def error_dict(self) -> dict[str, Any]:
        """The projection error as plain JSON values, with what each number means."""
        return {
            "rms_rel": self.rms_rel,
            "rms_rel_per_channel": list(self.rms_rel_per_channel),
            "worst_rel": self.worst_rel,
            "worst_at_deg": dict(zip(("theta_i", "theta_o", "phi_o_minus_phi_i"), self.worst_at_deg, strict=True)),
            "grazing_limit_deg": GRAZING_DEG,
            "metric": "rms_rel: relative L2 difference of f cos(theta_i) cos(theta_o) over both hemispheres; "
            "worst_rel: max |f_mr - f| / f with both zenith angles <= grazing_limit_deg",
            "n_fit_samples": self.n_fit,
            "n_error_samples": self.n_error,
            "fit_starts_agreeing": f"{self.starts_agreeing}/{self.starts}",
        }  # fmt: skip

    def summary(self) -> str:
        """One line: the material and its error."""
        m = self.material
        return (
            f"{type(self.source).__name__} -> metal-roughness base_color {np.round(np.atleast_1d(m.base_color), 4)}, "
            f"metallic {m.metallic:.4f}, roughness {m.roughness:.4f}: error {self.rms_rel:.2%} RMS, worst "
            f"{self.worst_rel:.1%} within {GRAZING_DEG:g} deg (at theta_i, theta_o, dphi = "
            f"{', '.join(f'{a:.0f}' for a in self.worst_at_deg)} deg)"
        )


def _cosine(u1: Array, u2: Array) -> Array:
    r, phi = np.sqrt(u1), 2.0 * np.pi * u2
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.maximum(0.0, 1.0 - u1))], axis=-1)


def sample_pairs(n: int, rng: np.random.Generator) -> tuple[Array, Array, Array]:
    """Up to n pairs (wi, wo) above the horizon and their weights cos_i^2 cos_o^2 / density (sr^2)."""
    u = rng.random((n, 5))
    wi = _cosine(u[:, 0], u[:, 1])
    k = len(LOBE_ALPHAS)
    # Component 0 is the cosine lobe, component j >= 1 the GGX lobe LOBE_ALPHAS[j - 1].
    lobe = np.minimum(((u[:, 4] - COSINE_SHARE) / (1.0 - COSINE_SHARE) * k).astype(int), k - 1)
    comp = np.where(u[:, 4] < COSINE_SHARE, 0, 1 + lobe)
    wo = _cosine(u[:, 2], u[:, 3])
    for j, alpha in enumerate(LOBE_ALPHAS, start=1):
        pick = comp == j
        h, _ = microfacet.half_vectors("ggx", alpha, u[pick, 2], u[pick, 3])
        wo[pick] = reflect(wi[pick], h)
    ok = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    wi, wo = wi[ok], wo[ok]
    cos_i, cos_o = wi[:, 2], wo[:, 2]
    s = wi + wo
    h = s / np.linalg.norm(s, axis=-1, keepdims=True)
    cos_d = np.sum(wi * h, axis=-1)
    density_o = COSINE_SHARE * cos_o / np.pi
    for alpha in LOBE_ALPHAS:
        density_o = density_o + (1 - COSINE_SHARE) / k * microfacet.ggx_d(h[:, 2], alpha) * h[:, 2] / (4.0 * cos_d)
    # Target density cos_i^2 cos_o^2; sampling density (cos_i / pi) density_o, both per sr^2.
    return wi, wo, np.pi * cos_i * cos_o**2 / density_o


def _values(model: BRDF, wi: Array, wo: Array) -> Array:
    """The model's f_r in 1/sr as (N, C) float64, C = 1 for scalar models."""
    f = np.asarray(model.eval(wi, wo), dtype=np.float64)
    return f.reshape(len(wi), -1)


def _usable(model: BRDF, wi: Array, wo: Array) -> npt.NDArray[np.bool_]:
    """Pairs where the source has data (a MERL table may not); all pairs for analytic models."""
    has_data = getattr(model, "has_data", None)
    return np.asarray(has_data(wi, wo), dtype=bool) if callable(has_data) else np.ones(len(wi), dtype=bool)


@functools.lru_cache(maxsize=4)
def seeded_pairs(samples: int, seed: int) -> tuple[tuple[Array, Array, Array], tuple[Array, Array, Array]]:
    """The pairs :func:`to_metal_roughness` fits to (``samples``) and those it measures the error on (read-only).

    They depend on no model, so they are drawn once per process (an export standby draws them before the fit).
    """
    fit_rng, error_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    drawn = sample_pairs(samples, fit_rng), sample_pairs(ERROR_SAMPLES, error_rng)
    for a in (*drawn[0], *drawn[1]):
        a.setflags(write=False)
    return drawn


def _error(
    source: BRDF, material: MetalRoughness, pairs: tuple[Array, Array, Array]
) -> tuple[float, tuple[float, ...], float, tuple[float, float, float], int]:
    """(E pooled, E per channel, worst relative difference, (theta_i, theta_o, dphi) deg, pairs used)."""
    wi, wo, w = pairs
    keep = _usable(source, wi, wo)
    wi, wo, w = wi[keep], wo[keep], w[keep]
    f = _values(source, wi, wo)
    g = np.broadcast_to(_values(material, wi, wo), f.shape)
    d2 = np.sum(w[:, None] * (g - f) ** 2, axis=0)
    f2 = np.sum(w[:, None] * f**2, axis=0)
    per_channel = tuple(float(x) for x in np.sqrt(d2 / np.maximum(f2, 1e-300)))
    pooled = float(np.sqrt(d2.sum() / f2.sum()))
    floor = REL_FLOOR * float(np.sqrt(f2.sum() / (w.sum() * f.shape[1])))
    cos_max = np.cos(np.radians(GRAZING_DEG))
    inside = (wi[:, 2] >= cos_max) & (wo[:, 2] >= cos_max)
    rel = np.where(inside[:, None], np.abs(g - f) / np.maximum(np.abs(f), floor), -1.0)
    i = int(np.argmax(rel.max(axis=1)))
    theta = np.degrees(np.arccos(np.clip([wi[i, 2], wo[i, 2]], -1.0, 1.0)))
    dphi = np.degrees(np.arctan2(wo[i, 1], wo[i, 0]) - np.arctan2(wi[i, 1], wi[i, 0])) % 360.0
    where = (float(theta[0]), float(theta[1]), float(min(dphi, 360.0 - dphi)))
    return pooled, per_channel, float(max(rel[i].max(), 0.0)), where, len(wi)


def to_metal_roughness(model: BRDF, *, samples: int = FIT_SAMPLES, seed: int = 0) -> MetalRoughnessFit:
    """The glTF metal-roughness material closest to ``model`` (any BRDF, f_r in 1/sr) and its error."""
    if samples < 100:
        raise ValueError(f"to_metal_roughness: samples = {samples}; need at least 100 direction pairs")
    (wi, wo, w), error_pairs = seeded_pairs(samples, seed)
    keep = _usable(model, wi, wo)
    wi, wo, w = wi[keep], wo[keep], w[keep]
    f = _values(model, wi, wo)
    name = type(model).__name__
    if f.shape[1] not in (1, 3):
        raise ValueError(f"{name} has {f.shape[1]} channels; glTF's base colour takes 1 (grey) or 3 (RGB)")
    if not np.all(np.isfinite(f)):
        raise ValueError(f"{name} returned non-finite values at {int((~np.isfinite(f)).any(axis=1).sum())} pairs")
    if not np.any(f > 0):
        raise ValueError(f"{name} is zero at every sampled pair: no metal-roughness material is black (F0 >= 0.04)")
    # Importance weights as std errors (see the module docstring); normalised only for readable numbers.
    se = np.broadcast_to(1.0 / np.sqrt(w / w.mean())[:, None], f.shape)
    result = fit(METAL_ROUGHNESS, Samples(wi, wo, f, se, source=name), loss="l2", weighted=True, warn=False)
    material = result.model
    assert isinstance(material, MetalRoughness)
    pooled, per_channel, worst, where, n_error = _error(model, material, error_pairs)
    return MetalRoughnessFit(
        material, model, pooled, per_channel, worst, where, len(wi), n_error, result.n_starts, result.n_starts_agreeing
    )


def _source_description(model: BRDF) -> dict[str, Any]:
    """The source as JSON: its parameters where it has a JSON form, else its class name."""
    if is_serialisable(model):
        return to_json_dict(model)
    return {"model": type(model).__name__, "source": str(getattr(model, "source", ""))}


def gltf_material(fit: MetalRoughnessFit, name: str) -> dict[str, Any]:
    """A glTF 2.0 material object (factors linear, dimensionless) with the projection's error in extras."""
    m = fit.material
    rgb = np.broadcast_to(np.atleast_1d(np.asarray(m.base_color, dtype=np.float64)), (3,))
    return {
        "name": name,
        "pbrMetallicRoughness": {
            "baseColorFactor": [*(float(np.clip(c, 0.0, 1.0)) for c in rgb), 1.0],
            "metallicFactor": float(m.metallic),
            "roughnessFactor": float(m.roughness),
        },
        "extras": {
            "source_model": _source_description(fit.source),
            "projection_error": fit.error_dict(),
            "note": "the metal-roughness material nearest to source_model; projection_error says how far (0 = exact)",
        },
    }
