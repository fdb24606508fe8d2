"""Normalised (modified) Phong: f = rho_d / pi + rho_s (n + 2) / (2 pi) cos^n(alpha_r).

alpha_r is the angle between wo and the mirror direction of wi. The (n + 2)/(2 pi) factor (Lewis 1994,
Lafortune and Willems) makes the specular lobe's directional albedo exactly rho_s at normal incidence
and at most rho_s elsewhere (the lobe is clipped by the horizon), so rho_d + rho_s <= 1 conserves
energy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from model._params import Channel, albedo_sum, channel, scalar
from model.base import Array, Model, Pair


@dataclass(frozen=True)
class Phong(Model):
    """Normalised Phong.

    Parameters:
        rho_d: diffuse albedo in [0, 1], scalar or per channel.
        rho_s: specular albedo at normal incidence in [0, 1], scalar or per channel;
            rho_d + rho_s <= 1 is required so the model conserves energy.
        n: Phong exponent in [0, 1e6], dimensionless; larger is shinier.
    """

    rho_d: Channel = 0.0
    rho_s: Channel = 0.5
    n: float = 20.0

    def __post_init__(self) -> None:
        name = type(self).__name__
        object.__setattr__(self, "rho_d", channel(name, "rho_d", self.rho_d, 0.0, 1.0))
        object.__setattr__(self, "rho_s", channel(name, "rho_s", self.rho_s, 0.0, 1.0))
        object.__setattr__(self, "n", scalar(name, "n", self.n, 0.0, 1e6))
        albedo_sum(name, self.rho_d, self.rho_s)

    def _eval(self, p: Pair) -> Array:
        # cos(alpha_r) = wo . reflect(wi) = 2 cos_i cos_o - wi . wo, without forming the mirror vector.
        cos_r = 2.0 * p.cos_i * p.cos_o - np.sum(p.wi * p.wo, axis=-1, keepdims=True)
        n = p.dtype.type(self.n)
        lobe = (n + 2.0) / (2.0 * np.pi) * np.power(np.clip(cos_r, 0.0, 1.0), n)
        return p.param(self.rho_d) / np.pi + p.param(self.rho_s) * lobe
