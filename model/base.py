"""The BRDF interface every model implements, and the shared evaluation scaffolding.

A model is a frozen dataclass of its parameters (validated on construction) with ``eval(wi, wo)``
returning f_r in 1/sr *without* the cosine factor. Directions are unit vectors (..., 3) in the local
frame (z = normal, both pointing away from the surface); they broadcast against each other. A model
whose parameters are all scalar returns shape (...); one with per-channel parameters (e.g. RGB)
returns (..., C). Directions at or below the horizon give 0, never NaN. float32 inputs are computed
in float32; anything else in float64.
"""

from __future__ import annotations

import abc
import dataclasses
from functools import cached_property
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from model import fresnel, microfacet
from model._params import Channel, as_column, channels_of
from model.geometry import float_dtype

Array = npt.NDArray[np.floating]

#: Floor for divisors such as cos_i cos_o. Products below it occur only within ~1e-15 rad of the
#: horizon; there the value is capped (at most ~1e38 even for alpha = 1e-4 and no masking) instead
#: of overflowing, in float32 as in float64. The dtype's own tiny (2e-308) would overflow 1/x.
DIVISOR_FLOOR = 1e-30


@runtime_checkable
class BRDF(Protocol):
    """Anything with ``eval(wi, wo) -> f_r`` in 1/sr, cosine excluded: models, tables, fits."""

    def eval(self, wi: npt.ArrayLike, wo: npt.ArrayLike) -> Array:
        """BRDF value in 1/sr for unit directions wi, wo (..., 3) in the local frame."""
        ...


class Pair:
    """A broadcast pair of directions with the derived quantities models share, computed once."""

    def __init__(self, wi: npt.ArrayLike, wo: npt.ArrayLike) -> None:
        dtype = float_dtype(wi, wo)
        a, b = np.broadcast_arrays(np.asarray(wi, dtype=dtype), np.asarray(wo, dtype=dtype))
        if a.shape[-1:] != (3,):
            raise ValueError(f"directions must have shape (..., 3); got {np.shape(wi)} and {np.shape(wo)}")
        self.wi: Array = a
        self.wo: Array = b
        self.dtype = dtype
        self.cos_i: Array = a[..., 2:3]
        self.cos_o: Array = b[..., 2:3]
        self.valid = (self.cos_i > 0) & (self.cos_o > 0)

    @property
    def tiny(self) -> float:
        """The divisor floor (see DIVISOR_FLOOR), well inside the working dtype's range."""
        return DIVISOR_FLOOR

    @cached_property
    def _sum_norm(self) -> tuple[Array, Array]:
        s = self.wi + self.wo
        return s, np.sqrt(np.sum(s * s, axis=-1, keepdims=True))

    @cached_property
    def h(self) -> Array:
        """Unit half vector; for upper-hemisphere pairs wi + wo never vanishes, so this is exact."""
        s, n = self._sum_norm
        return s / np.maximum(n, self.tiny)

    @cached_property
    def cos_h(self) -> Array:
        """Cosine of the half vector's zenith angle, (..., 1)."""
        # At most 1: where |wi + wo|^2 underflows (nearly opposite grazing directions in float32), h is
        # not unit and its z reached 2, which made D infinite.
        return np.minimum(self.h[..., 2:3], 1.0)

    @cached_property
    def cos_d(self) -> Array:
        """Cosine between wi (or wo) and the half vector, (..., 1).

        For unit vectors wi . h = |wi + wo| / 2 exactly; that form is symmetric in wi and wo, where
        wi . h would amplify rounding in |wi| by 1 / |wi + wo| for nearly opposite directions.
        """
        return np.clip(0.5 * self._sum_norm[1], 0.0, 1.0)

    # What the microfacet terms derive from the directions alone: a fit evaluates hundreds of models on one Pair.
    @cached_property
    def sin2_cos2_h(self) -> tuple[Array, Array]:
        """(sin^2, cos^2) of cos_h (microfacet.sin2_cos2), (..., 1) each."""
        return microfacet.sin2_cos2(self.cos_h)

    @cached_property
    def tan2(self) -> tuple[Array, Array]:
        """microfacet.ggx_tan2 of cos_i and of cos_o, (..., 1) each."""
        return microfacet.ggx_tan2(self.cos_i), microfacet.ggx_tan2(self.cos_o)

    @cached_property
    def schlick_weight(self) -> Array:
        """fresnel.schlick_weight of cos_d, (..., 1)."""
        return fresnel.schlick_weight(self.cos_d)

    @cached_property
    def four_cos(self) -> Array:
        """max(4 cos_i cos_o, tiny), the microfacet denominator, (..., 1)."""
        return np.maximum(4.0 * self.cos_i * self.cos_o, self.tiny)

    def param(self, value: Channel) -> Array:
        """A parameter as a (C,) array in the working dtype, to broadcast against (..., 1)."""
        return as_column(value, self.dtype)


class Model(abc.ABC):
    """Base of every analytic model: validation hook, channel bookkeeping and the eval scaffold.

    Subclasses are frozen dataclasses that implement ``_eval(pair) -> (..., C or 1)`` for valid
    (upper-hemisphere) pairs; the base zeroes the rest and squeezes the channel axis of scalar models.
    """

    #: f(wi, wo) == f(wo, wi) for every pair (Helmholtz reciprocity).
    reciprocal: ClassVar[bool] = True
    #: Directional albedo <= 1 for every incident direction and every valid parameter set.
    energy_conserving: ClassVar[bool] = True
    #: Why a model is exempt from one of the properties above (shown by the checks).
    exemption: ClassVar[str] = ""

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        own = cls.__dict__.get("__post_init__")
        if own is None:
            return

        def post_init(self: Model) -> None:
            own(self)
            # Per-channel parameters of different lengths are caught here, at construction,
            # rather than as a broadcasting error at the first eval.
            channels_of(*self._channel_params())

        cls.__post_init__ = post_init  # type: ignore[attr-defined]

    def _channel_params(self) -> tuple[Channel, ...]:
        return tuple(
            getattr(self, f.name)
            for f in dataclasses.fields(self)  # type: ignore[arg-type]
            if isinstance(getattr(self, f.name), float | tuple)
        )

    @property
    def channels(self) -> int | None:
        """Number of output channels, or None when every parameter is scalar."""
        return channels_of(*self._channel_params())

    def conserves_energy(self) -> bool:
        """Whether this instance promises albedo <= 1 (class default, narrowed by parameters)."""
        return self.energy_conserving

    @abc.abstractmethod
    def _eval(self, p: Pair) -> Array:
        """f_r for the pair, shape (..., C) or (..., 1); only valid pairs need be right."""

    def eval(self, wi: npt.ArrayLike, wo: npt.ArrayLike) -> Array:
        """BRDF value f_r in 1/sr (cosine excluded) for unit directions wi, wo (..., 3)."""
        p = Pair(wi, wo)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore", under="ignore"):
            f = self._eval(p)
        f = np.where(p.valid, f, 0.0).astype(p.dtype, copy=False)
        if self.channels is None:
            return f[..., 0]
        return np.broadcast_to(f, (*p.cos_i.shape[:-1], self.channels)).copy()

    def with_params(self, **changes: object) -> Model:
        """A copy with some parameters changed (validated again)."""
        return dataclasses.replace(self, **changes)  # type: ignore[type-var]

