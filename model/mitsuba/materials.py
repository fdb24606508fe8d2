"""Every model of :mod:`model` as a Mitsuba 3 BSDF: a native plugin where one matches, else ``gonio_model``.

:func:`to_mitsuba` returns a :class:`MitsubaMaterial`: the scene-dict entry, whether it is a native
Mitsuba plugin, which plugin, and why (so the renderer comparison can say which path it used).

Native only where Mitsuba computes the same function (tests/simulator/test_materials.py checks each):

- :class:`model.Lambert` -> ``diffuse`` (reflectance = rho_d). Exact.
- :class:`model.CookTorrance` with a GGX or Beckmann distribution, exact separable Smith masking,
  conductor or dielectric Fresnel, rho_d = 0 -> ``roughconductor`` (alpha, distribution, eta, k;
  specular_reflectance 1). Dielectric Fresnel is the conductor formula at k = 0 (the same function,
  total internal reflection included; they agree to 2e-14 in float64), so it maps with k = 0.
  The 1982 form is 4x the Walter form: specular_reflectance = 4 (a float: Mitsuba accepts floats
  above 1 but rejects RGB reflectances above 1).
  GGX: exact (float32 rounding). Beckmann: Mitsuba's G1 is a rational fit within 0.35 %, so f is
  within :data:`BECKMANN_REL_TOL` (0.7 %; 0.62 % measured in tests/model/test_mitsuba_oracle.py).
  Only where every channel's normal-incidence reflectance F0 >= :data:`F0_MIN_NATIVE`: Mitsuba's
  float32 Fresnel has an absolute error near 2e-7, which is 3.6e-3 relative for a nearly
  index-matched interface (eta 1.01, F0 2.5e-5) but at most 3.5e-5 relative at F0 = 2e-3.
- The same Cook-Torrance with a Lambertian term rho_d > 0 (max rho_d < 1) -> ``blendbsdf``, because
  the sum rho_d/pi + spec equals (1 - w) [spec / (1 - w)] + w [rho_d / (w pi)] with w = max rho_d:
  a ``roughconductor`` with the float specular_reflectance 1/(1 - w) and a ``diffuse`` with
  reflectance rho_d / w <= 1.

Everything else goes through the Python plugin (:mod:`model.mitsuba.plugin`), which evaluates the
model itself, float64 inside, to float32 precision:

- Phong, Blinn-Phong, Ward, Ashikhmin-Shirley, Oren-Nayar, Lafortune, Kajiya-Kay, MERL tables and any
  other object with ``eval``: Mitsuba has no such plugin (its ``measured`` reads RGL files only; stock
  Mitsuba renders them from the tables :mod:`model.mitsuba.tabulated` writes).
- Cook-Torrance with a Blinn-Phong distribution, height-correlated Smith, Smith-Schlick, V-groove or
  no masking, Schlick Fresnel, F0 < 2e-3, or rho_d reaching 1: no Mitsuba plugin computes those.
- glTF :class:`model.MetalRoughness` is not ``principled``: principled uses separable Smith masking
  (glTF: height-correlated) and a Disney diffuse with retro-reflection (glTF: (1 - F) Lambert).
  Measured at roughness 0.5: principled / model between 0.64 and 1.00 for metallic 1 and between
  0.68 and 1.66 for metallic 0.
- A dielectric Cook-Torrance over a Lambertian base is not ``roughplastic``: roughplastic weights its
  diffuse base by (1 - F(theta_i)) (1 - F(theta_o)) and internal reflections, where the model adds
  rho_d / pi; measured ratio 0.11 to 2.56 (alpha 0.3, eta 1.5).
- :class:`model.MetalnessMix`: Smith-Schlick masking and Schlick Fresnel.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field
from typing import Any

import mitsuba as mi
import numpy as np

from model import fresnel
from model._params import Channel
from model.base import BRDF
from model.cook_torrance import CookTorrance
from model.kajiya_kay import KajiyaKay
from model.lambert import Lambert
from model.merl import MerlTable
from model.metal_roughness import MetalRoughness
from model.metalness_mix import MetalnessMix
from model.mitsuba import plugin as gonio_plugin
from model.mitsuba.variant import kind_of

#: Relative agreement of native GGX plugins with the model: float32 rounding (measured 1e-5 and below,
#: up to 1e-4 where Mitsuba's float32 Fresnel meets F0 near F0_MIN_NATIVE or grazing half vectors).
NATIVE_REL_TOL = 1e-4
#: Relative agreement of native Beckmann plugins: (1 + 0.35 %)^2 - 1, Mitsuba's G1 fit on both directions.
BECKMANN_REL_TOL = (1.0 + 3.5e-3) ** 2 - 1.0
#: Smallest normal-incidence Fresnel reflectance (every channel) for which roughconductor is used.
F0_MIN_NATIVE = 2e-3

_WHY_NOT_NATIVE: dict[type, str] = {
    MetalRoughness: (
        "glTF metal-roughness is not Mitsuba's principled (separable Smith and Disney diffuse with "
        "retro-reflection against glTF's height-correlated Smith and (1 - F) Lambert)"
    ),
    MetalnessMix: "Smith-Schlick masking and Schlick Fresnel: no Mitsuba plugin computes them",
    KajiyaKay: "Mitsuba has no Kajiya-Kay plugin (and the model is not reciprocal)",
    MerlTable: "Mitsuba has no MERL reader (its measured plugin reads RGL .bsdf files only)",
}


@dataclass(frozen=True)
class MitsubaMaterial:
    """A model as a Mitsuba BSDF: scene-dict entry, whether native, plugin name, and why."""

    bsdf: dict[str, Any] = field(repr=False)
    native: bool
    plugin: str
    note: str

    def to_dict(self) -> dict[str, Any]:
        """A fresh copy of the scene-dict entry; registers ``gonio_model`` for the active rgb variant."""
        if not self.native:
            variant = mi.variant()
            if variant is not None and kind_of(variant) == "rgb":
                gonio_plugin.ensure_registered()
        return copy.deepcopy(self.bsdf)

    @property
    def needs_evaluated_calls(self) -> bool:
        """Whether llvm renders need :func:`model.mitsuba.plugin.evaluated_calls` (the Python plugin)."""
        return not self.native


def _spectrum(value: Channel | np.ndarray) -> float | dict[str, Any]:
    """A parameter as a Mitsuba float (one channel) or ``rgb`` texture (three)."""
    arr = np.atleast_1d(np.asarray(value, dtype=np.float64))
    if arr.size == 1:
        return float(arr[0])
    return {"type": "rgb", "value": [float(x) for x in arr]}


def _channels(model: BRDF) -> int | None:
    channels = getattr(model, "channels", None)
    if channels not in (None, 1, 3):
        raise ValueError(f"{type(model).__name__} has {channels} channels; Mitsuba's rgb variants need 1 or 3")
    return channels


def _python(model: BRDF, why: str) -> MitsubaMaterial:
    return MitsubaMaterial(gonio_plugin.plugin_dict(model), False, gonio_plugin.PLUGIN, f"Python plugin: {why}")


def _lambert(model: Lambert) -> MitsubaMaterial:
    spec = {"type": "diffuse", "reflectance": _spectrum(model.rho_d)}
    return MitsubaMaterial(spec, True, "diffuse", "native diffuse: reflectance = rho_d, exact")


def _cook_torrance(model: CookTorrance) -> MitsubaMaterial:
    """roughconductor or blendbsdf where the physics matches; otherwise the Python plugin."""
    if model.distribution not in ("ggx", "beckmann"):
        return _python(model, f"{model.distribution} distribution: Mitsuba has GGX and Beckmann only")
    if model.masking != "smith":
        return _python(model, f"{model.masking} masking: Mitsuba's microfacet masking is separable exact Smith only")
    if model.fresnel == "schlick":
        return _python(model, "Schlick Fresnel: roughconductor computes the exact conductor Fresnel")
    eta = np.atleast_1d(np.asarray(model.eta, dtype=np.float64))
    k = np.atleast_1d(np.asarray(model.k if model.fresnel == "conductor" else 0.0, dtype=np.float64))
    f0 = fresnel.f0_from_ior(eta, k)
    if np.any(f0 < F0_MIN_NATIVE):
        return _python(
            model,
            f"F0 = {float(f0.min()):.2g} < {F0_MIN_NATIVE:g} (nearly index-matched): Mitsuba's float32 Fresnel "
            "would be off by more than 1e-4 relative",
        )
    rho_d = np.atleast_1d(np.asarray(model.rho_d, dtype=np.float64))
    w_max = float(rho_d.max())
    if w_max >= 1.0:
        return _python(model, "rho_d reaches 1: no blendbsdf weight leaves room for the specular lobe")
    form_scale = 4.0 if model.form == "cook_torrance_1982" else 1.0
    spec: dict[str, Any] = {
        "type": "roughconductor",
        "distribution": model.distribution,
        "alpha": float(model.alpha),
        "eta": _spectrum(eta),
        "k": _spectrum(k),
    }
    k_note = "" if model.fresnel == "conductor" else ", k = 0"
    parts = [f"{model.distribution} roughconductor ({model.fresnel} Fresnel{k_note})"]
    if model.form == "cook_torrance_1982":
        parts.append("specular_reflectance 4 for the 1982 form")
    accuracy = "exact" if model.distribution == "ggx" else f"within {BECKMANN_REL_TOL:.1%} (Mitsuba's Beckmann G1 fit)"
    if w_max <= 0.0:
        if form_scale != 1.0:
            spec["specular_reflectance"] = form_scale
        return MitsubaMaterial(spec, True, "roughconductor", f"native {', '.join(parts)}: {accuracy}")
    # Mitsuba stores the weight in float32: pick the float32 value at or above max rho_d so that
    # rho_d / w <= 1 holds exactly, and derive both scales from that stored value.
    w = np.float32(w_max)
    if float(w) < w_max:
        w = np.nextafter(w, np.float32(np.inf))
    wf = float(w)
    if wf >= 1.0:
        return _python(model, "rho_d rounds to 1 in float32: no blendbsdf weight leaves room for the specular lobe")
    spec["specular_reflectance"] = form_scale / (1.0 - wf)
    diffuse = {"type": "diffuse", "reflectance": _spectrum(np.minimum(rho_d / wf, 1.0))}
    blend = {"type": "blendbsdf", "weight": wf, "bsdf_0": spec, "bsdf_1": diffuse}
    note = f"native blendbsdf of {', '.join(parts)} and diffuse, weight max(rho_d) = {wf:.6g}: {accuracy}"
    return MitsubaMaterial(blend, True, "blendbsdf", note)


def to_mitsuba(model: BRDF, *, allow_native: bool = True) -> MitsubaMaterial:
    """The Mitsuba BSDF of ``model`` (f_r in 1/sr): native where exact, else the Python plugin.

    ``allow_native=False`` forces the Python plugin, e.g. to compare both paths on one model.
    """
    _channels(model)
    if not allow_native:
        return _python(model, "native plugins disabled by the caller")
    # Exact types only: a subclass may override the physics that makes the mapping exact.
    if type(model) is Lambert:
        return _lambert(model)
    if type(model) is CookTorrance:
        return _cook_torrance(model)
    why = _WHY_NOT_NATIVE.get(type(model), f"Mitsuba has no {type(model).__name__} plugin")
    return _python(model, why)
