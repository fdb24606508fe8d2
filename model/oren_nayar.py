"""Oren-Nayar (1994) rough diffuse reflection, the qualitative model.

    f = rho_d / pi (A + B max(0, cos(phi_i - phi_o)) sin(a) tan(b)),
    A = 1 - 0.5 s^2 / (s^2 + 0.33),  B = 0.45 s^2 / (s^2 + 0.09),
    a = max(theta_i, theta_o),  b = min(theta_i, theta_o),

with s = sigma, the standard deviation of the facet slope angle in radians. sigma = 0 is Lambert.

Energy: the qualitative model is a fit, not an exact integral, and near grazing its directional albedo
exceeds rho_d by up to 1.52 % (measured: 1.0152 at rho_d = 1, sigma = 0.2, theta_i = 89.99 deg, with
400k-point quadrature). It therefore promises albedo <= 1 only for rho_d <= 0.985.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from model._params import Channel, channel, scalar
from model.base import Array, Model, Pair


@dataclass(frozen=True)
class OrenNayar(Model):
    """Oren-Nayar qualitative model.

    Parameters:
        rho_d: albedo of the facets in [0, 1], scalar or per channel.
        sigma: facet slope-angle standard deviation in radians, [0, pi/2].
    """

    rho_d: Channel = 0.5
    sigma: float = 0.3

    def __post_init__(self) -> None:
        name = type(self).__name__
        object.__setattr__(self, "rho_d", channel(name, "rho_d", self.rho_d, 0.0, 1.0))
        object.__setattr__(self, "sigma", scalar(name, "sigma", self.sigma, 0.0, np.pi / 2))

    exemption = "the qualitative fit overshoots rho_d by up to 1.52 % near grazing (sigma ~ 0.2)"

    #: Largest rho_d for which the overshoot above still leaves the albedo <= 1.
    RHO_D_MAX_CONSERVING = 0.985

    def conserves_energy(self) -> bool:
        """Albedo <= 1 is promised for rho_d <= 0.985 (see the module docstring)."""
        return bool(np.all(np.asarray(self.rho_d) <= self.RHO_D_MAX_CONSERVING))

    def _eval(self, p: Pair) -> Array:
        s2 = float(self.sigma) ** 2
        a = 1.0 - 0.5 * s2 / (s2 + 0.33)
        b = 0.45 * s2 / (s2 + 0.09)
        ci, co = p.cos_i, p.cos_o
        # cos(phi_i - phi_o) from the projected vectors; 0 when either is at the pole (undefined).
        dxy = p.wi[..., 0:1] * p.wo[..., 0:1] + p.wi[..., 1:2] * p.wo[..., 1:2]
        si = np.sqrt(np.maximum(0.0, 1.0 - ci * ci))
        so = np.sqrt(np.maximum(0.0, 1.0 - co * co))
        cos_dphi = np.where(si * so > 0, dxy / np.maximum(si * so, p.tiny), 0.0)
        # sin(a) tan(b) with a the larger angle: sin of the smaller cosine, tan of the larger one.
        sin_a = np.where(ci < co, si, so)
        tan_b = np.where(ci < co, so / np.maximum(co, p.tiny), si / np.maximum(ci, p.tiny))
        return p.param(self.rho_d) / np.pi * (a + b * np.maximum(0.0, cos_dphi) * sin_a * tan_b)
