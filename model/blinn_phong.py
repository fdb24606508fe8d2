"""Normalised Blinn-Phong: f = rho_d / pi + rho_s N(n) cos^n(theta_h).

The normalisation N(n) is exact: the specular lobe's directional albedo is rho_s at normal incidence,
from the closed form of the integral of cos^n(theta_o / 2) cos(theta_o) over the hemisphere. The
common approximation (n + 8)/(8 pi) (Akenine-Moeller and Haines) is available as
``normalization="approx"``; it overestimates the lobe's albedo by up to 7.5 % (near n = 10) and by
under 1 % for n > 200.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from model._params import Channel, albedo_sum, channel, choice, scalar
from model.base import Array, Model, Pair


def blinn_phong_norm(n: float) -> float:
    """Exact normalisation N(n) in 1/sr: rho_s is then the lobe's albedo at normal incidence."""
    c0 = 2.0 ** -0.5

    def antiderivative(c: float) -> float:
        return 2.0 * c ** (n + 4.0) / (n + 4.0) - c ** (n + 2.0) / (n + 2.0)

    # The integral over theta_o in [0, pi/2] with c = cos(theta_o / 2) in [1/sqrt 2, 1].
    integral = 2.0 * np.pi * 4.0 * (antiderivative(1.0) - antiderivative(c0))
    return float(1.0 / integral)


@dataclass(frozen=True)
class BlinnPhong(Model):
    """Normalised Blinn-Phong.

    Parameters:
        rho_d: diffuse albedo in [0, 1], scalar or per channel.
        rho_s: specular albedo at normal incidence in [0, 1], scalar or per channel;
            rho_d + rho_s <= 1 is required.
        n: exponent in [0, 1e6] of cos(theta_h), dimensionless.
        normalization: "exact" (default) or "approx" for (n + 8)/(8 pi).
    """

    rho_d: Channel = 0.0
    rho_s: Channel = 0.5
    n: float = 50.0
    normalization: str = "exact"

    #: The approximate normalisation overshoots at small n, so only "exact" promises albedo <= 1.
    exemption = "normalization='approx' overestimates the lobe albedo by up to 7.5 % (near n = 10)"

    def __post_init__(self) -> None:
        name = type(self).__name__
        object.__setattr__(self, "rho_d", channel(name, "rho_d", self.rho_d, 0.0, 1.0))
        object.__setattr__(self, "rho_s", channel(name, "rho_s", self.rho_s, 0.0, 1.0))
        object.__setattr__(self, "n", scalar(name, "n", self.n, 0.0, 1e6))
        choice(name, "normalization", self.normalization, ("exact", "approx"))
        albedo_sum(name, self.rho_d, self.rho_s)

    @property
    def norm(self) -> float:
        """The lobe normalisation in 1/sr."""
        n = float(self.n)
        return blinn_phong_norm(n) if self.normalization == "exact" else (n + 8.0) / (8.0 * np.pi)

    def conserves_energy(self) -> bool:
        """The exact normalisation always does; the approximate one only without headroom to spare."""
        return self.normalization == "exact"

    def lobe(self) -> tuple[str, float, float]:
        """The Blinn-Phong lobe as (distribution, equivalent alpha, share of samples) for sampling."""
        alpha = float(np.sqrt(2.0 / (float(self.n) + 2.0)))
        return "blinn_phong", alpha, 0.5 if np.any(np.asarray(self.rho_d) > 0) else 0.9

    def _eval(self, p: Pair) -> Array:
        lobe = self.norm * np.power(np.clip(p.cos_h, 0.0, 1.0), p.dtype.type(self.n))
        return p.param(self.rho_d) / np.pi + p.param(self.rho_s) * lobe
