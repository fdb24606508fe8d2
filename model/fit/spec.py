"""What a fit varies: a declarative parameter spec per model, and ready-made specs for common fits.

A :class:`FitSpec` names the model class, the fields fitted (bounds, initial guess, whether one value per
channel or one shared by all, whether optimised in log space) and the fields held fixed. Log space is used
for scale-like parameters (roughness, exponents) whose plausible values span decades, so a step means the
same relative change everywhere and random starts spread evenly across the decades.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from model._params import ParameterError
from model.base import Model
from model.blinn_phong import BlinnPhong
from model.cook_torrance import CookTorrance
from model.fit.samples import FitError, Samples
from model.lambert import Lambert
from model.ward import Ward

Init = float | Callable[[Samples], npt.ArrayLike]


@dataclass(frozen=True)
class Param:
    """One fitted field: bounds [lo, hi] in the field's own units, initial guess, channel and scale options.

    ``init`` is a number or a function of the samples returning one value or one per channel.
    ``channel_ok``: the model accepts one value per channel for this field. ``anisotropic``: the field
    describes shape across azimuth, so samples confined to one plane cannot determine it.
    """

    name: str
    lo: float
    hi: float
    init: Init
    per_channel: bool = False
    log: bool = False
    channel_ok: bool = True
    anisotropic: bool = False

    def __post_init__(self) -> None:
        if not self.lo < self.hi or (self.log and self.lo <= 0):
            raise ParameterError(f"Param {self.name}: bounds [{self.lo}, {self.hi}] invalid (log needs lo > 0)")
        if self.per_channel and not self.channel_ok:
            raise ParameterError(f"Param {self.name}: the model takes one value for all channels")

    def to_internal(self, v: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """Native value(s) to the optimiser's coordinate (log for log parameters)."""
        a = np.asarray(v, dtype=np.float64)
        return np.log(a) if self.log else a

    def to_native(self, u: npt.ArrayLike) -> npt.NDArray[np.float64]:
        """The optimiser's coordinate back to the field's units."""
        a = np.asarray(u, dtype=np.float64)
        return np.exp(a) if self.log else a


@dataclass(frozen=True, eq=False)
class FitSpec:
    """A model class, the fields to fit (see :class:`Param`) and the fields held fixed."""

    name: str
    model: type[Model]
    params: tuple[Param, ...]
    fixed: Mapping[str, Any] = field(default_factory=dict)

    def _with(self, names: tuple[str, ...], per_channel: bool) -> FitSpec:
        known = {p.name for p in self.params}
        unknown = set(names) - known
        if unknown:
            raise ParameterError(f"{self.name}: no fitted parameter named {sorted(unknown)}; fitted: {sorted(known)}")
        ps = tuple(dataclasses.replace(p, per_channel=per_channel) if p.name in names else p for p in self.params)
        return dataclasses.replace(self, params=ps)

    def per_channel(self, *names: str) -> FitSpec:
        """A copy fitting one value per channel for the named fields."""
        return self._with(names, True)

    def shared(self, *names: str) -> FitSpec:
        """A copy fitting one value shared by all channels for the named fields."""
        return self._with(names, False)

    def sizes(self, channels: int) -> list[int]:
        """Number of optimiser coordinates per parameter for C channels."""
        return [channels if p.per_channel else 1 for p in self.params]

    def labels(self, channels: int) -> list[str]:
        """One label per fitted number, e.g. rho_d_r, rho_d_g, rho_d_b, alpha."""
        suffix = list("rgb") if channels == 3 else [str(c) for c in range(channels)]
        out: list[str] = []
        for p, k in zip(self.params, self.sizes(channels), strict=True):
            out += [f"{p.name}_{suffix[c]}" for c in range(k)] if p.per_channel and channels > 1 else [p.name]
        return out

    @property
    def anisotropic(self) -> tuple[str, ...]:
        """Names of the fitted fields that samples confined to one plane cannot determine."""
        return tuple(p.name for p in self.params if p.anisotropic)

    def values(self, x_native: npt.ArrayLike, channels: int) -> dict[str, Any]:
        """Field values (float, or tuple per channel) from a flat vector of native parameter values."""
        x = np.asarray(x_native, dtype=np.float64)
        out: dict[str, Any] = {}
        i = 0
        for p, k in zip(self.params, self.sizes(channels), strict=True):
            out[p.name] = tuple(float(v) for v in x[i : i + k]) if p.per_channel else float(x[i])
            i += k
        return out

    def build(self, values: Mapping[str, Any], *, validate: bool = True) -> Model:
        """The model with these fitted values; unvalidated on request (inside the optimiser's loop only).

        The optimiser may probe points that violate a cross-parameter rule (e.g. Phong's rho_d + rho_s
        <= 1) or step just past a bound when differencing; building without validation keeps the
        objective smooth there. Results handed to users are always built validated.
        """
        merged = {**self.fixed, **values}
        if validate:
            return self.model(**merged)
        obj = object.__new__(self.model)
        for f in dataclasses.fields(self.model):  # type: ignore[arg-type]
            if f.name in merged:
                v = merged[f.name]
            elif f.default is not dataclasses.MISSING:
                v = f.default
            else:
                v = f.default_factory()  # type: ignore[operator]
            object.__setattr__(obj, f.name, v)
        return obj

    def initial(self, samples: Samples) -> npt.NDArray[np.float64]:
        """Initial native parameter vector for these samples, clipped inside the bounds."""
        parts = []
        for p, k in zip(self.params, self.sizes(samples.channels), strict=True):
            v = p.init(samples) if callable(p.init) else p.init
            a = np.asarray(v, dtype=np.float64).reshape(-1)
            a = np.broadcast_to(a, (k,)) if a.size in (1, k) else np.full(k, float(np.mean(a)))
            # Strictly inside: trust-region methods need an interior start, log parameters a positive one.
            span = p.hi - p.lo
            parts.append(np.clip(a, p.lo + 1e-6 * span, p.hi - 1e-6 * span))
        return np.concatenate(parts)


def diffuse_albedo_guess(quantile: float) -> Callable[[Samples], npt.NDArray[np.float64]]:
    """An initial rho_d per channel: pi times a quantile of the values (the floor under any lobe)."""

    def guess(s: Samples) -> npt.NDArray[np.float64]:
        used = s.value[~s.lower_bound]
        if used.size == 0:
            raise FitError("no samples left to guess an initial diffuse albedo from")
        return np.clip(np.pi * np.quantile(used, quantile, axis=0), 1e-3, 0.99)

    return guess


#: Lambert with one albedo per channel: one parameter per channel.
LAMBERT = FitSpec("lambert", Lambert, (Param("rho_d", 0.0, 1.0, diffuse_albedo_guess(0.5), per_channel=True),))

_ALPHA = Param("alpha", 1e-3, 1.0, 0.2, log=True, channel_ok=False)


def lambert_ggx(fresnel: str = "dielectric") -> FitSpec:
    """Lambert (rho_d per channel) plus one GGX lobe, exact Smith; Fresnel "dielectric" (eta) or "schlick" (f0).

    The dielectric variant is 5 parameters on RGB (rho_d x 3, alpha, eta), a plastic-like material.
    """
    rho_d = Param("rho_d", 0.0, 1.0, diffuse_albedo_guess(0.1), per_channel=True)
    if fresnel == "dielectric":
        f = Param("eta", 1.01, 4.0, 1.5)
    elif fresnel == "schlick":
        f = Param("f0", 0.0, 1.0, 0.04)
    else:
        raise ParameterError(f"lambert_ggx: fresnel = {fresnel!r}; expected 'dielectric' or 'schlick'")
    fixed = {"distribution": "ggx", "masking": "smith", "fresnel": fresnel}
    return FitSpec(f"lambert+ggx_{fresnel}", CookTorrance, (rho_d, _ALPHA, f), fixed)


def ggx_conductor(rho_d: bool = False) -> FitSpec:
    """A GGX conductor: complex index eta + i k per channel and alpha (7 parameters on RGB), optional rho_d."""
    ps = [
        Param("eta", 0.02, 10.0, 1.0, per_channel=True),
        Param("k", 0.0, 20.0, 3.0, per_channel=True),
        _ALPHA,
    ]
    if rho_d:
        ps.insert(0, Param("rho_d", 0.0, 1.0, diffuse_albedo_guess(0.1), per_channel=True))
    fixed = {"distribution": "ggx", "masking": "smith", "fresnel": "conductor"}
    return FitSpec("ggx_conductor" + ("+lambert" if rho_d else ""), CookTorrance, tuple(ps), fixed)


def blinn_phong() -> FitSpec:
    """Normalised Blinn-Phong: rho_d per channel, rho_s shared, exponent n (log, 1..1e4)."""
    return FitSpec(
        "blinn_phong", BlinnPhong,
        (
            Param("rho_d", 0.0, 1.0, diffuse_albedo_guess(0.1), per_channel=True),
            Param("rho_s", 0.0, 1.0, 0.2),
            Param("n", 1.0, 1e4, 50.0, log=True, channel_ok=False),
        ),
    )  # fmt: skip


def ward_anisotropic(variant: str = "balanced") -> FitSpec:
    """Ward with rho_d per channel, rho_s shared and two slopes alpha_x, alpha_y (6 parameters on RGB)."""
    return FitSpec(
        f"ward_anisotropic_{variant}", Ward,
        (
            Param("rho_d", 0.0, 1.0, diffuse_albedo_guess(0.1), per_channel=True),
            Param("rho_s", 0.0, 1.0, 0.2),
            Param("alpha_x", 1e-3, 1.0, 0.2, log=True, channel_ok=False, anisotropic=True),
            Param("alpha_y", 1e-3, 1.0, 0.2, log=True, channel_ok=False, anisotropic=True),
        ),
        {"variant": variant},
    )  # fmt: skip
