"""What every table of a rig or sweep file shares: strict validation and the bounded number types.

Unknown keys are errors (``extra="forbid"``), types are not coerced (a string is never a number), and
numbers carry their bounds in their type, so an absurd value is a named error where the key is defined.
"""

from __future__ import annotations

from typing import Annotated, Any

from pydantic import BaseModel, ConfigDict, Field, model_validator
from pydantic_core import PydanticCustomError

from rig.run import registry

# Upper bounds far beyond any instrument (a kilometre, a day, a billion electrons): they keep the arithmetic
# that follows finite, so an absurd value is a named error here instead of an overflow somewhere later.
Pos = Annotated[float, Field(gt=0, le=1e9, allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0, le=1e9, allow_inf_nan=False)]
Finite = Annotated[float, Field(ge=-1e6, le=1e6, allow_inf_nan=False)]
Metres = Annotated[float, Field(gt=0, le=1000, allow_inf_nan=False)]
Seconds = Annotated[float, Field(gt=0, le=86400, allow_inf_nan=False)]
Levels = Annotated[float, Field(ge=0, le=2**32, allow_inf_nan=False)]
#: A seed numpy, the simulated sensor and Mitsuba's sampler (a uint32) all take.
Seed = Annotated[int, Field(ge=0, le=2**32 - 1)]
Deg90 = Annotated[float, Field(ge=0, le=90, allow_inf_nan=False)]
Pair = tuple[Finite, Finite]
Channels = (
    Annotated[float, Field(gt=0, le=1)]
    | tuple[
        Annotated[float, Field(gt=0, le=1)], Annotated[float, Field(gt=0, le=1)], Annotated[float, Field(gt=0, le=1)]
    ]
)


def _tuples(value: Any) -> Any:
    return tuple(_tuples(v) for v in value) if isinstance(value, list) else value


class Strict(BaseModel):
    """Base of every table: unknown keys are errors, values are not coerced, models are frozen."""

    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)

    @model_validator(mode="before")
    @classmethod
    def _arrays_as_tuples(cls, data: Any) -> Any:
        # TOML arrays arrive as lists; strict mode takes only tuples for the fixed-length and frozen fields.
        return {k: _tuples(v) for k, v in data.items()} if isinstance(data, dict) else data


def one_of(value: str, known: tuple[str, ...]) -> str:
    """``value`` if it is among ``known`` (registered names), else the error a Literal key would give."""
    # Worded as pydantic words a Literal, so the message reads like every other key's.
    if value not in known:
        raise PydanticCustomError("literal_error", "Input should be {expected}", {"expected": registry.listing(known)})
    return value
