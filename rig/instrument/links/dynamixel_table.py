"""Control-table layouts, unit conversions and error decoding for the Dynamixel models the link drives.

The X series (XL430, XM430, XM540, XH430, XW ...) and the MX series on Protocol 2.0 share one layout,
so a bus of mixed X servos is read with one SYNC_READ. The P series (PH/PM, formerly PRO+) keeps its
RAM registers at other addresses and another resolution; a bus that mixes the two families is read with
BULK_READ, one block per servo.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from model.errors import HardwareFault

ALERT_BIT = 0x80

STATUS_ERRORS = {
    1: "Result Fail: the instruction could not be processed",
    2: "Instruction Error: undefined instruction, or ACTION without REG_WRITE",
    3: "CRC Error: the instruction packet's CRC did not match",
    4: "Data Range Error: the data is too long for the address",
    5: "Data Length Error: the data is shorter than the instruction needs",
    6: "Data Limit Error: the value is outside the register's limits",
    7: "Access Error: read-only or undefined address, or EEPROM written while torque is on",
}

HARDWARE_ERRORS = {
    0: "input voltage error",
    2: "overheating",
    3: "motor encoder error",
    4: "electrical shock",
    5: "overload",
}


def describe_status_error(error: int) -> str:
    """Human meaning of a status packet's error byte."""
    parts = []
    number = error & ~ALERT_BIT
    if number:
        parts.append(STATUS_ERRORS.get(number, f"unknown error number {number}"))
    if error & ALERT_BIT:
        parts.append("Alert: hardware error (read Hardware Error Status)")
    return "; ".join(parts) if parts else "no error"


def describe_hardware_error(status: int) -> str:
    """Human meaning of the Hardware Error Status register (address 70 on the X series)."""
    names = [text for bit, text in HARDWARE_ERRORS.items() if status & (1 << bit)]
    return ", ".join(names) if names else "none"


@dataclass(frozen=True)
class ControlTable:
    """Addresses (and sizes) of the registers the link uses, plus the model's resolution.

    Parameters
    ----------
    family:
        Layout name; servos of one family can share a SYNC_READ.
    ticks_per_turn:
        Encoder counts per output-shaft revolution.
    velocity_unit_rpm:
        Profile Velocity unit in rev/min (0.229 on the X series).
    accel_unit_rpm2:
        Profile Acceleration unit in rev/min^2 (214.577 on the X series).
    velocity_limit_units:
        The largest Profile Velocity the servo takes (its Velocity Limit; the XM430-W350's 200, 45.8 rev/min,
        its no-load speed); more is a Data Limit Error. None: not known here (the servo refuses what it cannot).
    accel_limit_units:
        The largest Profile Acceleration the register holds (32767 on the X series); more is a Data Range Error.
    """

    family: str
    ticks_per_turn: int
    velocity_unit_rpm: float
    accel_unit_rpm2: float
    velocity_limit_units: int | None = None
    accel_limit_units: int | None = None
    id: int = 7
    baud_rate: int = 8
    operating_mode: int = 11
    max_position_limit: int = 48
    min_position_limit: int = 52
    shutdown: int = 63
    return_delay_time: int = 9
    torque_enable: int = 64
    hardware_error_status: int = 70
    profile_acceleration: int = 108
    profile_velocity: int = 112
    goal_position: int = 116
    moving: int = 122
    moving_status: int = 123
    present_position: int = 132

    @property
    def motion_block(self) -> tuple[int, int]:
        """(address, size) of one read covering Moving, Moving Status and Present Position."""
        return self.moving, self.present_position + 4 - self.moving

    @property
    def ticks_per_degree(self) -> float:
        """Encoder counts per degree of output shaft."""
        return self.ticks_per_turn / 360.0

    def velocity_units(self, deg_per_s: float) -> int:
        """Profile Velocity register value for a speed in degrees/s (at least 1: 0 means unlimited)."""
        return max(1, round(deg_per_s / 6.0 / self.velocity_unit_rpm))

    def accel_units(self, deg_per_s2: float) -> int:
        """Profile Acceleration register value for an acceleration in degrees/s^2 (at least 1)."""
        return max(1, round(deg_per_s2 * 10.0 / self.accel_unit_rpm2))

    @property
    def max_speed_deg_s(self) -> float:
        """The fastest profile speed the servo takes, output-shaft degrees/s (the Velocity Limit's)."""
        if self.velocity_limit_units is None:
            return math.inf
        return self.velocity_limit_units * self.velocity_unit_rpm * 6.0

    @property
    def max_accel_deg_s2(self) -> float:
        """The largest profile acceleration the register holds, output-shaft degrees/s^2."""
        if self.accel_limit_units is None:
            return math.inf
        return self.accel_limit_units * self.accel_unit_rpm2 / 10.0


BAUD_RATE_VALUES = {9600: 0, 57600: 1, 115200: 2, 1_000_000: 3, 2_000_000: 4, 3_000_000: 5, 4_000_000: 6,
                    4_500_000: 7}  # fmt: skip
"""Baud rate (bps) -> Baud Rate (8) register value; the X, MX(2.0) and P series share these (e-Manual)."""


def baud_rate_value(baudrate: int) -> int:
    """The Baud Rate (8) register value for ``baudrate`` bps; ValueError listing the rates a servo can take."""
    if baudrate not in BAUD_RATE_VALUES:
        rates = ", ".join(str(b) for b in BAUD_RATE_VALUES)
        raise ValueError(f"baud rate {baudrate!r}: a Dynamixel servo takes one of {rates}")
    return BAUD_RATE_VALUES[baudrate]


X_SERIES = ControlTable(family="X", ticks_per_turn=4096, velocity_unit_rpm=0.229, accel_unit_rpm2=214.577,
                        velocity_limit_units=200, accel_limit_units=32767)  # fmt: skip
"""The X series' table, with the XM430-W350's Velocity Limit (firmware 42 and later: 200, no Acceleration Limit)."""

# P series (PH54, PH42, PM54, PM42): RAM block at 512+, resolution per model (ROBOTIS e-Manual).
_P_SERIES_RAM = dict(
    torque_enable=512,
    hardware_error_status=518,
    profile_acceleration=556,
    profile_velocity=560,
    goal_position=564,
    moving=570,
    moving_status=571,
    present_position=580,
)


def _p_series(ticks_per_turn: int) -> ControlTable:
    return ControlTable(
        family="P", ticks_per_turn=ticks_per_turn, velocity_unit_rpm=0.01, accel_unit_rpm2=1.0, **_P_SERIES_RAM
    )


MODELS: dict[int, tuple[str, ControlTable]] = {
    1020: ("XM430-W350", X_SERIES),
    1030: ("XM430-W210", X_SERIES),
    1060: ("XL430-W250", X_SERIES),
    1010: ("XH430-W350", X_SERIES),
    1000: ("XH430-W210", X_SERIES),
    1120: ("XM540-W270", X_SERIES),
    1100: ("XM540-W150", X_SERIES),
    311: ("MX-64(2.0)", X_SERIES),
    321: ("MX-106(2.0)", X_SERIES),
    30: ("MX-28(2.0)", X_SERIES),
    2020: ("PH54-200-S500-R", _p_series(1_003_846)),
    2010: ("PH54-100-S500-R", _p_series(1_003_846)),
    2000: ("PH42-020-S300-R", _p_series(607_500)),
    2120: ("PM54-060-S250-R", _p_series(502_834)),
    2110: ("PM54-040-S250-R", _p_series(502_834)),
    2100: ("PM42-010-S260-R", _p_series(526_374)),
}
"""Model number -> (name, control table). Only the XM430-W350 is exercised here (the virtual bus)."""


class UnknownModelError(HardwareFault, ValueError):
    """A servo reported a model number the link has no control table for."""


def table_for_model(model_number: int, where: str = "servo") -> ControlTable:
    """Control table for a model number; raises UnknownModelError naming the model and the servo."""
    try:
        return MODELS[model_number][1]
    except KeyError:
        known = ", ".join(f"{n} ({name})" for n, (name, _) in sorted(MODELS.items()))
        raise UnknownModelError(f"{where}: model number {model_number} is not supported; known: {known}") from None


def model_name(model_number: int) -> str:
    """Product name for a model number, or ``model <n>`` if unknown."""
    return MODELS.get(model_number, (f"model {model_number}", X_SERIES))[0]
