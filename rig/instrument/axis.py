"""One joint of the rig as a controller sees it: device units, direction, offset, limits and tolerance."""

from __future__ import annotations

import math
from dataclasses import dataclass

from model.errors import InputError


class AxisLimitError(InputError, ValueError):
    """A target lies outside an axis's soft limits."""


@dataclass(frozen=True)
class Axis:
    """A joint driven by one servo (Dynamixel id) or one controller axis (GRBL letter).

    Parameters
    ----------
    name:
        Joint name used in poses and files, e.g. ``"light"``, ``"camera"``, ``"tilt"``, ``"roll"``.
    address:
        Where the link finds it: a Dynamixel id (``int``, 0..252) or a GRBL axis letter (``"X"`` ...).
    units_per_degree:
        Device units per degree of the *motor* shaft: 4096/360 ticks for an XM430, steps per degree for
        a stepper (GRBL's ``$100`` .. are per unit; with ``unit = degree`` this is the same number).
    gear_ratio:
        Motor turns per joint turn (>= 1 for a reduction).
    direction:
        +1 or -1: sign between joint degrees and device units.
    zero_offset_deg:
        Joint angle (degrees) at device position 0.
    min_deg, max_deg:
        Soft limits on the joint angle in degrees; targets outside are refused.
    max_speed_deg_s, max_accel_deg_s2:
        Joint speed and acceleration limits (degrees/s, degrees/s^2) the link programs into the device.
    tolerance_deg:
        In-position tolerance on the joint angle in degrees.
    backlash_deg:
        Known play between the motor (what the encoder or the step count sees) and the load, in degrees of
        joint; 0 when none is known.
    """

    name: str
    address: int | str
    units_per_degree: float
    gear_ratio: float = 1.0
    direction: int = 1
    zero_offset_deg: float = 0.0
    min_deg: float = -180.0
    max_deg: float = 180.0
    max_speed_deg_s: float = 60.0
    max_accel_deg_s2: float = 120.0
    tolerance_deg: float = 0.2
    backlash_deg: float = 0.0

    def __post_init__(self) -> None:
        where = f"axis {self.name!r}"
        if not self.name:
            raise ValueError("axis name must not be empty")
        for key in ("units_per_degree", "gear_ratio", "max_speed_deg_s", "max_accel_deg_s2", "tolerance_deg"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{where}: {key} = {value!r}, expected a positive finite number")
        if self.direction not in (1, -1):
            raise ValueError(f"{where}: direction = {self.direction!r}, expected 1 or -1")
        if not (math.isfinite(self.min_deg) and math.isfinite(self.max_deg) and self.min_deg < self.max_deg):
            raise ValueError(
                f"{where}: limits [{self.min_deg!r}, {self.max_deg!r}] deg, expected finite min_deg < max_deg"
            )
        if not (math.isfinite(self.backlash_deg) and self.backlash_deg >= 0):
            raise ValueError(f"{where}: backlash_deg = {self.backlash_deg!r}, expected a finite number >= 0")
        if not math.isfinite(self.zero_offset_deg):
            raise ValueError(f"{where}: zero_offset_deg = {self.zero_offset_deg!r}, expected a finite number")
        if isinstance(self.address, int) and not 0 <= self.address <= 252:
            raise ValueError(f"{where}: Dynamixel id {self.address!r} outside 0..252")

    @property
    def units_per_joint_degree(self) -> float:
        """Device units per degree of joint motion (gear ratio included)."""
        return self.units_per_degree * self.gear_ratio

    def check(self, target_deg: float) -> None:
        """Raise ``AxisLimitError`` naming the axis, target and limit if ``target_deg`` is not allowed."""
        if not math.isfinite(target_deg):
            raise AxisLimitError(f"axis {self.name!r}: target {target_deg!r} deg is not a finite number")
        if target_deg < self.min_deg:
            raise AxisLimitError(
                f"axis {self.name!r}: target {target_deg:.6g} deg is below its lower limit {self.min_deg:g} deg"
            )
        if target_deg > self.max_deg:
            raise AxisLimitError(
                f"axis {self.name!r}: target {target_deg:.6g} deg is above its upper limit {self.max_deg:g} deg"
            )

    def to_units(self, joint_deg: float) -> float:
        """Device position (ticks or steps, unrounded) for a joint angle in degrees, after the limit check."""
        self.check(joint_deg)
        return self.direction * (joint_deg - self.zero_offset_deg) * self.units_per_joint_degree

    def to_degrees(self, units: float) -> float:
        """Joint angle in degrees for a device position in ticks or steps."""
        return self.zero_offset_deg + self.direction * units / self.units_per_joint_degree

    def in_position(self, actual_deg: float, target_deg: float) -> bool:
        """Whether ``actual_deg`` is within the in-position tolerance of ``target_deg`` (degrees)."""
        return abs(actual_deg - target_deg) <= self.tolerance_deg
