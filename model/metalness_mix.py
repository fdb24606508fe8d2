"""The PBR notes' diffuse/specular mix weighted by metalness k (LearnOpenGL / Karis 2013 style).

    F0 = (1 - k) f0_dielectric + k base_color
    F  = Schlick(cos_d, F0)
    f  = (1 - F)(1 - k) base_color / pi + D G F / (4 cos_i cos_o)

with D = GGX at alpha = roughness^2 and G = Smith-Schlick with k_G = alpha / 2, exactly as the notes
this project started from. The (1 - F) factor moves into the specular lobe the energy it reflects.
Compare :class:`model.metal_roughness.MetalRoughness`, the glTF form, which uses exact
height-correlated Smith masking.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from model import fresnel, microfacet
from model._params import Channel, channel, scalar
from model.base import Array, Model, Pair


@dataclass(frozen=True)
class MetalnessMix(Model):
    """The notes' metalness mix.

    Parameters:
        base_color: albedo of the diffuse base and F0 of the metal, [0, 1], scalar or per channel.
        roughness: perceptual roughness r in (0, 1]; alpha = r^2 (alpha below 1e-4 is clamped).
        metalness: the notes' k in [0, 1]: 0 dielectric, 1 metal.
        f0_dielectric: normal-incidence reflectance of the dielectric case, [0, 1] (default 0.04).
    """

    base_color: Channel = 0.5
    roughness: float = 0.5
    metalness: float = 0.0
    f0_dielectric: float = 0.04

    energy_conserving = False
    exemption = "Smith-Schlick masking overestimates G near grazing, so the albedo can exceed 1 there"

    def __post_init__(self) -> None:
        name = type(self).__name__
        object.__setattr__(self, "base_color", channel(name, "base_color", self.base_color, 0.0, 1.0))
        object.__setattr__(self, "roughness", scalar(name, "roughness", self.roughness, 0.0, 1.0, lo_open=True))
        object.__setattr__(self, "metalness", scalar(name, "metalness", self.metalness, 0.0, 1.0))
        object.__setattr__(
            self, "f0_dielectric", scalar(name, "f0_dielectric", self.f0_dielectric, 0.0, 1.0)
        )

    @property
    def alpha(self) -> float:
        """Microfacet alpha = roughness^2."""
        return float(self.roughness) ** 2

    def _eval(self, p: Pair) -> Array:
        base = p.param(self.base_color)
        k = float(self.metalness)
        f = fresnel.schlick(p.cos_d, (1.0 - k) * float(self.f0_dielectric) + k * base)
        d = microfacet.ggx_d(p.cos_h, self.alpha)
        g = microfacet.masking("smith_schlick", p.cos_i, p.cos_o, p.cos_h, p.cos_d, self.alpha)
        spec = d * g * f / np.maximum(4.0 * p.cos_i * p.cos_o, p.tiny)
        return (1.0 - f) * (1.0 - k) * base / np.pi + spec

    def lobe(self) -> tuple[str, float, float]:
        """The microfacet lobe (distribution, alpha, share of samples) for importance sampling."""
        return "ggx", self.alpha, 0.5 + 0.4 * float(self.metalness)
