"""Cook-Torrance microfacet BRDF: f = rho_d / pi + D G F / (4 cos_i cos_o).

The specular term is Walter et al.'s (2007) "4" form with D normalised over projected area
(see :mod:`model.microfacet`). Cook and Torrance (1982) wrote it as F D' G / (pi cos_i cos_o) with a
Beckmann D' = 1/(m^2 cos^4) exp(-tan^2/m^2) that lacks the 1/pi: D' = pi D. Substituting gives the
documented conversion

    f_1982 = F (pi D) G / (pi cos_i cos_o) = 4 f_walter,

so ``form="cook_torrance_1982"`` evaluates the 1982 formula literally (4x the Walter value, for
reproducing old fits) and :func:`walter_from_1982` converts values or fitted scales between the two.
The 1982 form does not conserve energy (its albedo reaches 4x the Walter albedo).

Fresnel: "conductor" (exact, complex index eta + i k per channel), "dielectric" (exact, real eta),
or "schlick" (from f0). Roughness alpha follows Walter (GGX alpha, Beckmann m); the PBR notes' and
glTF's "roughness" r maps to alpha = r^2.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from model import fresnel, microfacet, runtime
from model._params import Channel, ParameterError, channel, choice, scalar
from model.base import Array, Model, Pair

FRESNELS: tuple[str, ...] = ("conductor", "dielectric", "schlick")
FORMS: tuple[str, ...] = ("walter", "cook_torrance_1982")
#: Smallest batch (direction pairs) evaluated by the numba kernel in model.kernels; both paths agree
#: bit for bit in float64 (tests/model/test_kernels.py), so this only trades speed.
KERNEL_MIN_PAIRS = 4096
#: Pairs numpy evaluates in a process without numba before the first large batch loads it for the kernel.
#: Importing numba and loading a cached kernel costs about what numpy takes for a million GGX pairs
#: (docs/benchmarks.md, gonio analyze): a one-off analysis (some 10^5 pairs) never pays it, while a long fit or a
#: render pays it early on. Where numba is imported already (a run's HDR merge, the benchmarks), the kernel is used
#: at once.
#: The pairs are counted for the whole process (:func:`model.runtime.load_due`), over every CookTorrance.
KERNEL_LOAD_PAIRS = 1_000_000


def walter_from_1982(value_1982: npt.ArrayLike) -> Array:
    """Convert a BRDF value (or a fitted specular scale) from the 1982 pi form to the Walter 4 form."""
    return np.asarray(value_1982, dtype=float) / 4.0


def alpha_from_roughness(roughness: npt.ArrayLike) -> Array:
    """Microfacet alpha from perceptual roughness r, alpha = r^2 (Burley; PBR notes; glTF)."""
    r = np.asarray(roughness, dtype=float)
    return r * r


@dataclass(frozen=True)
class CookTorrance(Model):
    """Microfacet specular lobe over an optional Lambertian base.

    Parameters:
        alpha: roughness in (0, 10], dimensionless (GGX alpha or Beckmann RMS slope); values below
            1e-4 are clamped to 1e-4 (see :mod:`model.microfacet`).
        distribution: "ggx" (default), "beckmann" or "blinn_phong" (exponent 2/alpha^2 - 2, so
            alpha <= 1 there).
        masking: "smith" (exact separable, default), "smith_correlated", "smith_schlick"
            (k = alpha/2), "v_groove" or "none".
        fresnel: "conductor" (default), "dielectric" or "schlick".
        eta: real part of the relative index, (0, 100], scalar or per channel (conductor, dielectric).
        k: extinction coefficient, [0, 1000], scalar or per channel (conductor only).
        f0: normal-incidence reflectance in [0, 1], scalar or per channel (schlick only).
        rho_d: albedo of an added Lambertian term in [0, 1] (default 0: a pure conductor).
        form: "walter" (default) or "cook_torrance_1982" (4x larger; see the module docstring).
    """

    alpha: float = 0.1
    distribution: str = "ggx"
    masking: str = "smith"
    fresnel: str = "conductor"
    eta: Channel = 1.5
    k: Channel = 0.0
    f0: Channel = 0.04
    rho_d: Channel = 0.0
    form: str = "walter"

    exemption = (
        "energy is promised only for the Walter form with GGX or Beckmann, exact Smith masking and no "
        "Lambertian term (Blinn-Phong borrows Beckmann's Smith Lambda, an approximation: albedo 1.044 "
        "measured at alpha 1, theta_i 89 deg); "
        "the 1982 form is 4x larger, masking 'none' grows like 1/cos at grazing, Smith-Schlick and "
        "V-groove can overestimate G, and rho_d adds to a specular albedo that reaches F"
    )

    def __post_init__(self) -> None:
        name = type(self).__name__
        object.__setattr__(self, "alpha", scalar(name, "alpha", self.alpha, 0.0, 10.0, lo_open=True))
        choice(name, "distribution", self.distribution, microfacet.DISTRIBUTIONS)
        if self.distribution == "blinn_phong" and self.alpha > 1.0:
            raise ParameterError(
                f"{name}.alpha = {self.alpha!r} is outside (0, 1] for distribution 'blinn_phong': "
                "its exponent 2/alpha^2 - 2 would be negative"
            )
        choice(name, "masking", self.masking, microfacet.MASKINGS)
        choice(name, "fresnel", self.fresnel, FRESNELS)
        choice(name, "form", self.form, FORMS)
        object.__setattr__(self, "eta", channel(name, "eta", self.eta, 0.0, 100.0, lo_open=True))
        object.__setattr__(self, "k", channel(name, "k", self.k, 0.0, 1000.0))
        object.__setattr__(self, "f0", channel(name, "f0", self.f0, 0.0, 1.0))
        object.__setattr__(self, "rho_d", channel(name, "rho_d", self.rho_d, 0.0, 1.0))

    def conserves_energy(self) -> bool:
        """True for the Walter form, GGX or Beckmann, exact Smith, no Lambertian term (see exemption)."""
        return (
            self.form == "walter"
            and self.distribution in ("ggx", "beckmann")
            and self.masking in ("smith", "smith_correlated")
            and not np.any(np.asarray(self.rho_d) > 0)
        )

    def _channel_params(self) -> tuple[Channel, ...]:
        # Only the parameters the chosen Fresnel term reads decide the channel count.
        used = {"conductor": (self.eta, self.k), "dielectric": (self.eta,), "schlick": (self.f0,)}
        return (*used[self.fresnel], self.rho_d, self.alpha)

    def fresnel_term(self, p: Pair, cos_d: Array) -> Array:
        """Fresnel reflectance at the microfacet, (..., C)."""
        if self.fresnel == "conductor":
            return fresnel.conductor(cos_d, p.param(self.eta), p.param(self.k))
        if self.fresnel == "dielectric":
            return fresnel.dielectric(cos_d, p.param(self.eta))
        return fresnel.schlick(cos_d, p.param(self.f0), weight=p.schlick_weight if cos_d is p.cos_d else None)

    def specular(self, p: Pair) -> Array:
        """The microfacet term alone, without the Fresnel factor: D G / (4 cos_i cos_o), (..., 1)."""
        kept = self.distribution != "blinn_phong"  # Blinn-Phong takes neither
        smith = kept and self.distribution == "ggx" and self.masking in ("smith", "smith_correlated")
        d = microfacet.distribution_d(self.distribution, p.cos_h, self.alpha, sin2_cos2=p.sin2_cos2_h if kept else None)
        g = microfacet.masking(self.masking, p.cos_i, p.cos_o, p.cos_h, p.cos_d, self.alpha, self.distribution,
                               tan2=p.tan2 if smith else None)  # fmt: skip
        # Exact Smith and Smith-Schlick G vanish like cos at grazing, so G / cos stays finite; with
        # masking "none" the value grows like 1/cos, as that model says, and stays finite for cos > 0.
        den = p.four_cos
        scale = 4.0 if self.form == "cook_torrance_1982" else 1.0
        return scale * d * g / den

    def eval(self, wi: npt.ArrayLike, wo: npt.ArrayLike) -> Array:
        """BRDF value f_r in 1/sr (cosine excluded); the compiled kernel where it applies, else numpy."""
        # Below KERNEL_MIN_PAIRS the parallel kernel's wake-up after idle outweighs its speed over numpy.
        pairs = max(np.size(wi), np.size(wo)) // 3
        if pairs < KERNEL_MIN_PAIRS or not runtime.load_due("numba", pairs, KERNEL_LOAD_PAIRS):
            return super().eval(wi, wo)
        f = self.compiled_eval(wi, wo)
        return super().eval(wi, wo) if f is None else f

    def compiled_eval(self, wi: npt.ArrayLike, wo: npt.ArrayLike) -> Array | None:
        """f_r in 1/sr through the numba kernel (:mod:`model.kernels`), or None where it does not apply."""
        cls = type(self)
        # A subclass that changes the physics (any of these methods) must keep its own numpy path.
        if any(getattr(cls, name) is not getattr(CookTorrance, name) for name in ("_eval", "specular", "fresnel_term")):
            return None
        # Imported here so that numba loads at the first large evaluation, not with the package.
        from model import kernels

        params = kernels.MicrofacetParams(
            self.fresnel, eta=self.eta, k=self.k, f0=self.f0, rho_d=self.rho_d, alpha=self.alpha,
            scale=4.0 if self.form == "cook_torrance_1982" else 1.0, channels=self.channels,
        )  # fmt: skip
        return kernels.microfacet(wi, wo, self.distribution, self.masking, params)

    def _eval(self, p: Pair) -> Array:
        spec = self.specular(p) * self.fresnel_term(p, p.cos_d)
        return p.param(self.rho_d) / np.pi + spec

    def lobe(self) -> tuple[str, float, float]:
        """The microfacet lobe (distribution, alpha, share of samples) for importance sampling."""
        diffuse = bool(np.any(np.asarray(self.rho_d) > 0))
        return self.distribution, float(self.alpha), 0.5 if diffuse else 0.9
