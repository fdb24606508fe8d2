"""Lafortune et al. (1997) generalised cosine lobes.

    f = rho_d / pi + sum_j [C_x,j wi_x wo_x + C_y,j wi_y wo_y + C_z,j wi_z wo_z]^n_j

A lobe whose bracket is negative contributes 0. C = (-1, -1, 1) is a Phong lobe about the mirror
direction; |C_x| != |C_z| tilts it towards grazing (off-specular peaks), C_x = C_y = 1 makes it
retro-reflective. The coefficients absorb the lobe's scale, so the model is not normalised: its
albedo depends on C and n and can exceed 1 (use :func:`model.checks.check_energy` on a fit).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from model._params import Channel, ParameterError, channel, scalar
from model.base import Array, Model, Pair


@dataclass(frozen=True)
class LafortuneLobe:
    """One generalised cosine lobe: coefficients c_x, c_y, c_z (1/sr^(1/n), scalar or per channel)
    and exponent n in [0, 1e6], with the lobe's peak max|C|^n at most 1e30 1/sr so it stays finite
    in float32 (a larger peak is no physical reflectance)."""

    c_x: Channel = -1.0
    c_y: Channel = -1.0
    c_z: Channel = 1.0
    n: float = 10.0

    def __post_init__(self) -> None:
        for name in ("c_x", "c_y", "c_z"):
            object.__setattr__(self, name, channel("LafortuneLobe", name, getattr(self, name), -1e3, 1e3))
        object.__setattr__(self, "n", scalar("LafortuneLobe", "n", self.n, 0.0, 1e6))
        c_max = float(np.max(np.abs(np.concatenate([np.atleast_1d(self.c_x), np.atleast_1d(self.c_y),
                                                     np.atleast_1d(self.c_z)]))))
        if c_max > 1.0 and self.n * np.log10(c_max) > 30.0:
            raise ParameterError(
                f"LafortuneLobe: peak max|C|^n = {c_max:g}^{self.n:g} exceeds 1e30 1/sr; "
                "reduce the coefficients or the exponent n"
            )


@dataclass(frozen=True)
class Lafortune(Model):
    """Lafortune generalised cosine lobes over a Lambertian term.

    Parameters:
        rho_d: diffuse albedo in [0, 1], scalar or per channel.
        lobes: one or more :class:`LafortuneLobe`.
    """

    rho_d: Channel = 0.0
    lobes: tuple[LafortuneLobe, ...] = (LafortuneLobe(),)

    energy_conserving = False
    exemption = "lobe coefficients are unnormalised; the albedo depends on C and n and may exceed 1"

    def __post_init__(self) -> None:
        object.__setattr__(self, "rho_d", channel("Lafortune", "rho_d", self.rho_d, 0.0, 1.0))
        lobes = tuple(self.lobes)
        if not lobes or not all(isinstance(lobe, LafortuneLobe) for lobe in lobes):
            raise ParameterError(f"Lafortune.lobes = {self.lobes!r}: expected one or more LafortuneLobe")
        object.__setattr__(self, "lobes", lobes)

    def _channel_params(self) -> tuple[Channel, ...]:
        return (self.rho_d, *(c for lobe in self.lobes for c in (lobe.c_x, lobe.c_y, lobe.c_z)))

    def _eval(self, p: Pair) -> Array:
        prod = p.wi * p.wo
        f = p.param(self.rho_d) / np.pi
        for lobe in self.lobes:
            base = (
                p.param(lobe.c_x) * prod[..., 0:1]
                + p.param(lobe.c_y) * prod[..., 1:2]
                + p.param(lobe.c_z) * prod[..., 2:3]
            )
            f = f + np.power(np.maximum(base, 0.0), p.dtype.type(lobe.n))
        return f
