"""Parameter validation shared by every model: one clear error that names the parameter and its range."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

from model.errors import InputError

Channel = float | tuple[float, ...]
"""A model parameter: one float for all channels, or one float per channel (e.g. RGB)."""


class ParameterError(InputError, ValueError):
    """A model parameter is outside its documented range or has the wrong shape."""


def _fmt_range(lo: float, hi: float, lo_open: bool, hi_open: bool) -> str:
    left = "(" if lo_open else "["
    right = ")" if hi_open else "]"
    return f"{left}{lo:g}, {hi:g}{right}"


def channel(
    owner: str,
    name: str,
    value: npt.ArrayLike,
    lo: float = -math.inf,
    hi: float = math.inf,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
) -> Channel:
    """Validate a scalar or per-channel parameter against [lo, hi] and return it as float or tuple."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim > 1 or arr.size == 0:
        raise ParameterError(
            f"{owner}.{name} = {value!r}: expected a number or a 1-D sequence of per-channel numbers"
        )
    flat = arr.reshape(-1)
    for v in flat:
        # +inf passes only where the range is open-ended above (e.g. a light's intensity).
        inside = lo <= v <= hi and not (lo_open and v == lo) and not (hi_open and v == hi)
        if not inside or (math.isinf(v) and not v == hi == math.inf):
            raise ParameterError(
                f"{owner}.{name} = {value!r} is outside its valid range "
                f"{_fmt_range(lo, hi, lo_open, hi_open)}"
            )
    if arr.ndim == 0:
        return float(arr)
    return tuple(float(v) for v in flat)


def channels_of(*params: Channel) -> int | None:
    """Common channel count of some parameters: None when all are scalar; error if counts differ."""
    counts = {len(p) for p in params if isinstance(p, tuple)}
    if not counts:
        return None
    counts.discard(1)
    if len(counts) > 1:
        raise ParameterError(f"per-channel parameters disagree on the number of channels: {sorted(counts)}")
    return counts.pop() if counts else 1


def as_column(value: Channel | Sequence[float], dtype: np.dtype) -> np.ndarray:
    """A parameter as an array of shape (C,) (C = 1 for a scalar) to broadcast against (..., 1)."""
    return np.atleast_1d(np.asarray(value, dtype=dtype))


def choice(owner: str, name: str, value: str, allowed: Sequence[str]) -> str:
    """Validate a string option against its allowed values."""
    if value not in allowed:
        raise ParameterError(f"{owner}.{name} = {value!r}: expected one of {', '.join(map(repr, allowed))}")
    return value


def scalar(
    owner: str,
    name: str,
    value: npt.ArrayLike,
    lo: float = -math.inf,
    hi: float = math.inf,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
) -> float:
    """Validate a parameter that is one number for all channels against [lo, hi]."""
    if np.ndim(value) != 0:
        raise ParameterError(f"{owner}.{name} = {value!r}: expected a single number, not one per channel")
    result = channel(owner, name, value, lo, hi, lo_open=lo_open, hi_open=hi_open)
    assert isinstance(result, float)
    return result


def albedo_sum(owner: str, rho_d: Channel, rho_s: Channel) -> None:
    """Require rho_d + rho_s <= 1 per channel: for these models the sum is the normal-incidence albedo."""
    total = np.asarray(rho_d) + np.asarray(rho_s)
    if np.any(total > 1.0 + 1e-12):
        raise ParameterError(
            f"{owner}: rho_d + rho_s = {total.tolist()} exceeds 1; the sum is the albedo at normal incidence"
        )
