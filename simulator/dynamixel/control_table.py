"""The XM430-W350 control table (model number 1020) as data: addresses, sizes, access, defaults and ranges.

Source: ROBOTIS e-Manual, XM430-W350 page (firmware 42 and later: Velocity Limit 200, no Acceleration
Limit). Multi-byte items are little-endian; items that can be negative are two's complement. Addresses
below 64 are EEPROM (writable only with Torque Enable off). The indirect address/data area (168 and up)
is not modelled: the table ends after Present Temperature (146).

Ranges here are the fixed ones (a value outside gives Data Range Error). Limits that depend on other
items (Goal Position inside the position limits, Profile Velocity under the Velocity Limit ...) are the
servo's business and give Data Limit Error.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

MODEL_NUMBER = 1020
FIRMWARE_VERSION = 46
"""A firmware with Clear (v42+), time-based profiles (v42+) and Fast Sync/Bulk Read (v45+)."""

EEPROM_END = 64
"""Addresses below this are EEPROM: locked while Torque Enable is 1."""

TICKS_PER_REV = 4096
VELOCITY_UNIT_RPM = 0.229
ACCELERATION_UNIT_RPM2 = 214.577
NO_LOAD_SPEED_RPM = 46.0
"""No-load speed at 12 V; the profile never runs faster than this."""

BAUD_RATES: dict[int, int] = {
    0: 9_600,
    1: 57_600,
    2: 115_200,
    3: 1_000_000,
    4: 2_000_000,
    5: 3_000_000,
    6: 4_000_000,
    7: 4_500_000,
}
"""Baud Rate (8) register value -> bits per second."""

OPERATING_MODES = frozenset({0, 1, 3, 4, 5, 16})
"""Current, velocity, position, extended position, current-based position, PWM."""


def baud_register_for(baudrate: int) -> int:
    """Baud Rate (8) register value for ``baudrate`` in bits per second; ValueError if the servo has none."""
    for value, rate in BAUD_RATES.items():
        if rate == baudrate:
            return value
    rates = ", ".join(str(r) for r in BAUD_RATES.values())
    raise ValueError(f"baud rate {baudrate!r} bps is not one an XM430 supports ({rates})")


@dataclass(frozen=True)
class Field:
    """One control table item: where it lives, how it is encoded and which values it accepts."""

    name: str
    address: int
    size: int
    writable: bool
    default: int
    minimum: int = 0
    maximum: int = 0
    signed: bool = False
    allowed_mask: int | None = None
    """For bit fields: the bits that may be set (any other bit gives Data Range Error)."""
    allowed: frozenset[int] | None = None

    @property
    def end(self) -> int:
        """First address after this item."""
        return self.address + self.size

    @property
    def eeprom(self) -> bool:
        """True for items in the EEPROM area."""
        return self.address < EEPROM_END

    def encode(self, value: int) -> bytes:
        """Little-endian bytes of ``value`` (two's complement when signed)."""
        return (value & ((1 << (8 * self.size)) - 1)).to_bytes(self.size, "little")

    def decode(self, data: bytes) -> int:
        """Integer from this item's little-endian bytes."""
        return int.from_bytes(data, "little", signed=self.signed)

    def in_range(self, value: int) -> bool:
        """Whether ``value`` lies in the item's fixed range (not its limits)."""
        if self.allowed is not None:
            return value in self.allowed
        if self.allowed_mask is not None:
            return 0 <= value and not value & ~self.allowed_mask
        return self.minimum <= value <= self.maximum


def _rw(name: str, address: int, size: int, default: int, lo: int, hi: int, *, signed: bool = False) -> Field:
    return Field(name, address, size, True, default, lo, hi, signed)


def _ro(name: str, address: int, size: int, *, signed: bool = False, default: int = 0) -> Field:
    # Read-only items take whatever their bytes can hold (the servo, not the client, sets them).
    bits = 8 * size
    lo, hi = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
    return Field(name, address, size, False, default, lo, hi, signed)


_POSITION_RANGE = 1_048_575
_GAIN_MAX = 16_383

FIELDS: tuple[Field, ...] = (
    _ro("model_number", 0, 2, default=MODEL_NUMBER),
    _ro("model_information", 2, 4),
    _ro("firmware_version", 6, 1, default=FIRMWARE_VERSION),
    _rw("id", 7, 1, 1, 0, 252),
    _rw("baud_rate", 8, 1, 1, 0, 7),
    _rw("return_delay_time", 9, 1, 250, 0, 254),
    Field("drive_mode", 10, 1, True, 0, allowed_mask=0x0D),
    Field("operating_mode", 11, 1, True, 3, allowed=OPERATING_MODES),
    _rw("secondary_id", 12, 1, 255, 0, 255),
    Field("protocol_type", 13, 1, True, 2, allowed=frozenset({1, 2})),
    _rw("homing_offset", 20, 4, 0, -1_044_479, 1_044_479, signed=True),
    _rw("moving_threshold", 24, 4, 10, 0, 1023),
    _rw("temperature_limit", 31, 1, 80, 0, 100),
    _rw("max_voltage_limit", 32, 2, 160, 95, 160),
    _rw("min_voltage_limit", 34, 2, 95, 95, 160),
    _rw("pwm_limit", 36, 2, 885, 0, 885),
    _rw("current_limit", 38, 2, 1193, 0, 1193),
    _rw("velocity_limit", 44, 4, 200, 0, 1023),
    _rw("max_position_limit", 48, 4, 4095, 0, 4095),
    _rw("min_position_limit", 52, 4, 0, 0, 4095),
    Field("shutdown", 63, 1, True, 52, allowed_mask=0x3D),
    _rw("torque_enable", 64, 1, 0, 0, 1),
    _rw("led", 65, 1, 0, 0, 1),
    _rw("status_return_level", 68, 1, 2, 0, 2),
    _ro("registered_instruction", 69, 1),
    _ro("hardware_error_status", 70, 1),
    _rw("velocity_i_gain", 76, 2, 1920, 0, _GAIN_MAX),
    _rw("velocity_p_gain", 78, 2, 100, 0, _GAIN_MAX),
    _rw("position_d_gain", 80, 2, 0, 0, _GAIN_MAX),
    _rw("position_i_gain", 82, 2, 0, 0, _GAIN_MAX),
    _rw("position_p_gain", 84, 2, 800, 0, _GAIN_MAX),
    _rw("feedforward_2nd_gain", 88, 2, 0, 0, _GAIN_MAX),
    _rw("feedforward_1st_gain", 90, 2, 0, 0, _GAIN_MAX),
    _rw("bus_watchdog", 98, 1, 0, 0, 127),
    _rw("goal_pwm", 100, 2, 885, -885, 885, signed=True),
    _rw("goal_current", 102, 2, 1193, -1193, 1193, signed=True),
    _rw("goal_velocity", 104, 4, 0, -1023, 1023, signed=True),
    _rw("profile_acceleration", 108, 4, 0, 0, 32767),
    _rw("profile_velocity", 112, 4, 0, 0, 32767),
    _rw("goal_position", 116, 4, 0, -_POSITION_RANGE, _POSITION_RANGE, signed=True),
    _ro("realtime_tick", 120, 2),
    _ro("moving", 122, 1),
    _ro("moving_status", 123, 1),
    _ro("present_pwm", 124, 2, signed=True),
    _ro("present_current", 126, 2, signed=True),
    _ro("present_velocity", 128, 4, signed=True),
    _ro("present_position", 132, 4, signed=True),
    _ro("velocity_trajectory", 136, 4, signed=True),
    _ro("position_trajectory", 140, 4, signed=True),
    _ro("present_input_voltage", 144, 2, default=120),
    _ro("present_temperature", 146, 1, default=36),
)

TABLE_SIZE = FIELDS[-1].end
"""Bytes in the modelled table; reading or writing past it is an Access Error."""

FIELD_BY_NAME: dict[str, Field] = {f.name: f for f in FIELDS}


def field(name: str) -> Field:
    """The item called ``name``; KeyError listing the known names otherwise."""
    try:
        return FIELD_BY_NAME[name]
    except KeyError:
        raise KeyError(f"no control table item {name!r}; known: {', '.join(FIELD_BY_NAME)}") from None


def fields_touched(address: int, length: int) -> Iterator[tuple[Field, bool]]:
    """Items overlapping ``[address, address + length)`` in address order, each with "fully covered"."""
    end = address + length
    for f in FIELDS:
        if f.address < end and f.end > address:
            yield f, (f.address >= address and f.end <= end)
