"""The virtual GRBL's ``$`` settings: defaults, validation as GRBL 1.1 does it on ``$N=value``, and ``$$`` output.

Axis settings follow GRBL's numbering for each configured axis letter (X, Y, Z, then A, B, C): ``$100+i`` steps per
unit, ``$110+i`` maximum rate in units/min, ``$120+i`` acceleration in units/s^2, ``$130+i`` maximum travel in
units. Values persist across resets and reconnections, as GRBL keeps them in EEPROM.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from simulator.grbl.gcode import Status

MAX_STEP_RATE_HZ = 30_000
AXIS_LETTERS = "XYZABC"

GLOBAL_DEFAULTS: dict[int, float] = {
    0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010, 12: 0.002, 13: 0,
    20: 0, 21: 0, 22: 0, 23: 0, 24: 25.0, 25: 500.0, 26: 250, 27: 1.0, 30: 1000, 31: 0, 32: 0,
}  # fmt: skip
AXIS_DEFAULTS = (250.0, 500.0, 10.0, 200.0)  # steps/unit, units/min, units/s^2, units
_INTEGER = {0, 1, 2, 3, 4, 5, 6, 10, 13, 20, 21, 22, 23, 26, 30, 31, 32}
_BOOLEAN = {4, 5, 6, 13, 20, 21, 22, 32}


class GrblSettings:
    """GRBL's settings table for ``n_axes`` axes, keyed by setting number."""

    def __init__(self, n_axes: int, overrides: Mapping[int, float] | None = None) -> None:
        self.n_axes = n_axes
        self.values = self.defaults()
        for key, value in (overrides or {}).items():
            if key not in self.values:
                raise ValueError(f"virtual GRBL: no setting ${key} for {n_axes} axes")
            self.values[key] = float(value)

    def defaults(self) -> dict[int, float]:
        """GRBL's generic defaults for this many axes."""
        values = {k: float(v) for k, v in GLOBAL_DEFAULTS.items()}
        for group, default in enumerate(AXIS_DEFAULTS):
            for i in range(self.n_axes):
                values[100 + 10 * group + i] = default
        return values

    def __getitem__(self, key: int) -> float:
        return self.values[key]

    def flag(self, key: int) -> bool:
        """A boolean setting such as ``$20`` (soft limits), ``$21`` (hard limits), ``$22`` (homing)."""
        return bool(self.values[key])

    def steps_per_unit(self, i: int) -> float:
        """``$100+i``: steps per unit of axis ``i``."""
        return self.values[100 + i]

    def max_rate(self, i: int) -> float:
        """``$110+i``: maximum rate of axis ``i`` in units/min."""
        return self.values[110 + i]

    def accel(self, i: int) -> float:
        """``$120+i``: acceleration of axis ``i`` in units/s^2."""
        return self.values[120 + i]

    def max_travel(self, i: int) -> float:
        """``$130+i``: maximum travel of axis ``i`` in units (machine space is [-travel, 0])."""
        return self.values[130 + i]

    def store(self, key: int, value: float) -> Status | None:
        """Apply ``$key=value`` as GRBL would; returns the error status or None when stored."""
        if math.copysign(1.0, value) < 0:
            return Status.NEGATIVE_VALUE
        if key >= 100:
            group, axis = divmod(key - 100, 10)
            if group > 3 or axis >= self.n_axes:
                return Status.INVALID_STATEMENT
            if value == 0 and group < 3:
                # GRBL accepts zero here and then divides by it; the simulator refuses (documented).
                return Status.INVALID_STATEMENT
            if group == 0 and value * self.max_rate(axis) > MAX_STEP_RATE_HZ * 60:
                return Status.MAX_STEP_RATE_EXCEEDED
            if group == 1 and value * self.steps_per_unit(axis) > MAX_STEP_RATE_HZ * 60:
                return Status.MAX_STEP_RATE_EXCEEDED
            self.values[key] = value
            return None
        if key not in GLOBAL_DEFAULTS:
            return Status.INVALID_STATEMENT
        if key in _INTEGER:
            value = float(int(value))
        if key in _BOOLEAN:
            value = 1.0 if value else 0.0
        if key == 0 and value < 3:
            return Status.SETTING_STEP_PULSE_MIN
        if key == 20 and value and not self.flag(22):
            return Status.SOFT_LIMIT_ERROR
        if key == 22 and not value:
            self.values[20] = 0.0  # GRBL forces soft limits off when homing is disabled
        self.values[key] = value
        return None

    def report_lines(self) -> list[str]:
        """The ``$$`` dump, one ``$N=value`` line per setting in GRBL's order and number format."""
        return [f"${k}={int(v)}" if k in _INTEGER else f"${k}={v:.3f}" for k, v in sorted(self.values.items())]
