"""Lambert: the ideal diffuse reflector, f = rho_d / pi."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from model._params import Channel, channel
from model.base import Array, Model, Pair


@dataclass(frozen=True)
class Lambert(Model):
    """Ideal diffuse reflection.

    Parameters:
        rho_d: diffuse albedo in [0, 1], dimensionless, scalar or per channel. The directional
            albedo equals rho_d at every incident direction.
    """

    rho_d: Channel = 0.5

    def __post_init__(self) -> None:
        object.__setattr__(self, "rho_d", channel("Lambert", "rho_d", self.rho_d, 0.0, 1.0))

    def _eval(self, p: Pair) -> Array:
        return np.broadcast_to(p.param(self.rho_d) / np.pi, (*p.cos_i.shape[:-1], len(p.param(self.rho_d))))
