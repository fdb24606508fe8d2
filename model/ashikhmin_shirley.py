"""Ashikhmin-Shirley (2000): an anisotropic Phong lobe with Schlick Fresnel over a coupled diffuse term.

    f_s = sqrt((n_u + 1)(n_v + 1)) / (8 pi) * cos_h^e / (cos_d max(cos_i, cos_o)) * F(cos_d)
    e   = (n_u h_x^2 + n_v h_y^2) / (1 - h_z^2)
    f_d = 28 rho_d / (23 pi) (1 - rho_s) (1 - (1 - cos_i/2)^5) (1 - (1 - cos_o/2)^5)

with F Schlick's approximation from rho_s. The diffuse term loses exactly the energy the specular
term's Fresnel gains, so the model is reciprocal and conserves energy for rho_d, rho_s in [0, 1].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from model import fresnel
from model._params import Channel, channel, scalar
from model.base import Array, Model, Pair


@dataclass(frozen=True)
class AshikhminShirley(Model):
    """Ashikhmin-Shirley anisotropic Phong.

    Parameters:
        rho_d: diffuse albedo in [0, 1], scalar or per channel.
        rho_s: specular reflectance at normal incidence (Schlick F0) in [0, 1], scalar or per channel.
        n_u: Phong exponent along the tangent (x), in [0, 1e6].
        n_v: exponent along the bitangent (y), in [0, 1e6]; None means n_u (isotropic).
    """

    rho_d: Channel = 0.5
    rho_s: Channel = 0.05
    n_u: float = 100.0
    n_v: float | None = None

    def __post_init__(self) -> None:
        name = type(self).__name__
        object.__setattr__(self, "rho_d", channel(name, "rho_d", self.rho_d, 0.0, 1.0))
        object.__setattr__(self, "rho_s", channel(name, "rho_s", self.rho_s, 0.0, 1.0))
        object.__setattr__(self, "n_u", scalar(name, "n_u", self.n_u, 0.0, 1e6))
        nv = self.n_u if self.n_v is None else self.n_v
        object.__setattr__(self, "n_v", scalar(name, "n_v", nv, 0.0, 1e6))

    def _eval(self, p: Pair) -> Array:
        nu, nv = float(self.n_u), float(self.n_v if self.n_v is not None else self.n_u)
        h = p.h
        hx2, hy2 = h[..., 0:1] ** 2, h[..., 1:2] ** 2
        # (n_u hx^2 + n_v hy^2) / (hx^2 + hy^2): 1 - hz^2 computed from the components, and at
        # h = n (where it is 0/0) cos_h^e = 1 whatever e is, so any finite value will do.
        sxy = hx2 + hy2
        e = np.where(sxy > 0, (nu * hx2 + nv * hy2) / np.maximum(sxy, p.tiny), 0.5 * (nu + nv))
        cos_h = np.clip(p.cos_h, 0.0, 1.0)
        rs = p.param(self.rho_s)
        spec = (
            np.sqrt((nu + 1.0) * (nv + 1.0)) / (8.0 * np.pi) * np.power(cos_h, e)
            / np.maximum(p.cos_d * np.maximum(p.cos_i, p.cos_o), p.tiny)
            * fresnel.schlick(p.cos_d, rs)
        )
        def falloff(c: Array) -> Array:
            return 1.0 - (1.0 - 0.5 * c) ** 5

        diff = 28.0 / (23.0 * np.pi) * p.param(self.rho_d) * (1.0 - rs) * falloff(p.cos_i) * falloff(p.cos_o)
        return diff + spec
