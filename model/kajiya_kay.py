"""Kajiya-Kay (1989) fibre shading, for brushed or fibrous samples with a tangent direction T.

    f = k_d / pi sin(T, wi) + k_s (sin(T, wi) sin(T, wo) - (T . wi)(T . wo))^p

The specular term peaks on the cone of mirror directions about the fibre (T . wo = -T . wi).
T = (cos phi_t, sin phi_t, 0) lies in the sample plane. This is a shading model, not a physical
BRDF: the diffuse term depends on the light direction alone (so the model is not reciprocal unless
k_d = 0) and neither term is normalised (no energy promise). It is here to fit renders and legacy data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from model._params import Channel, channel, scalar
from model.base import Array, Model, Pair


@dataclass(frozen=True)
class KajiyaKay(Model):
    """Kajiya-Kay fibre model.

    Parameters:
        k_d: diffuse weight in [0, 1], scalar or per channel.
        k_s: specular weight in 1/sr, [0, 1e3], scalar or per channel.
        p: specular exponent in [0, 1e6].
        phi_t: azimuth of the fibre tangent in the sample plane, radians.
    """

    k_d: Channel = 0.3
    k_s: Channel = 0.5
    p: float = 50.0
    phi_t: float = 0.0

    reciprocal = False
    energy_conserving = False
    exemption = "shading model: the diffuse term depends on wi only and neither term is normalised"

    def __post_init__(self) -> None:
        name = type(self).__name__
        object.__setattr__(self, "k_d", channel(name, "k_d", self.k_d, 0.0, 1.0))
        object.__setattr__(self, "k_s", channel(name, "k_s", self.k_s, 0.0, 1e3))
        object.__setattr__(self, "p", scalar(name, "p", self.p, 0.0, 1e6))
        object.__setattr__(self, "phi_t", scalar(name, "phi_t", self.phi_t, -1e3, 1e3))

    def _eval(self, pr: Pair) -> Array:
        t = np.array([np.cos(self.phi_t), np.sin(self.phi_t), 0.0], dtype=pr.dtype)
        ti = np.sum(pr.wi * t, axis=-1, keepdims=True)
        to = np.sum(pr.wo * t, axis=-1, keepdims=True)
        si = np.sqrt(np.maximum(0.0, 1.0 - ti * ti))
        so = np.sqrt(np.maximum(0.0, 1.0 - to * to))
        cone = np.clip(si * so - ti * to, 0.0, 1.0)
        return pr.param(self.k_d) / np.pi * si + pr.param(self.k_s) * np.power(cone, pr.dtype.type(self.p))
