"""One virtual XM430-W350: control table access rules, lazily evaluated motion, shutdown and reboot.

Motion is never integrated: a goal write plans a closed-form profile (``profile.plan``) from the state at
that instant of the injected clock, and every read evaluates it at ``clock.now()``. A servo therefore
costs nothing while nobody looks, and a ``ManualClock`` makes a two-second move take no real time.

Only the position modes move (3 position, 4 extended position, and 5 current-based position treated as
4). The other operating modes are accepted values, but the servo just holds still in them.

Every public method takes the lock handed in by the bus, so tests may poke servos while the bus thread
serves the client.
"""

from __future__ import annotations

import threading

from rig.instrument.clock import Clock, SystemClock
from simulator.dynamixel import control_table as ct
from simulator.dynamixel.faults import HardwareError, ServoFaults, ServoMechanics
from simulator.dynamixel.motion import (
    NO_LOAD_SPEED_TICKS_PER_S,
    TICKS_PER_S2_PER_ACCELERATION_UNIT,
    TICKS_PER_S_PER_VELOCITY_UNIT,
    Move,
    ServoState,
    profile_limits,
)
from simulator.dynamixel.protocol import ALERT_BIT, ErrorNumber

_POSITION_MODES = (3, 4, 5)
_STALL_CURRENT = 600  # Present Current units (~1.6 A): a motor straining against an obstruction.
_CLEAR_MAGIC = bytes([0x01, 0x44, 0x58, 0x4C, 0x22])
_LIVE = frozenset(
    {
        "realtime_tick", "moving", "moving_status", "present_pwm", "present_current", "present_velocity",
        "present_position", "velocity_trajectory", "position_trajectory",
    }
)  # fmt: skip


class VirtualServo:
    """A virtual XM430-W350 with its own control table, clock-driven motion and switchable faults."""

    def __init__(
        self,
        dxl_id: int,
        *,
        clock: Clock | None = None,
        lock: threading.RLock | None = None,
        baudrate: int = 57_600,
        position_ticks: int = 2048,
        seed: int = 0,
    ) -> None:
        self._clock: Clock = clock if clock is not None else SystemClock()
        self._lock = lock if lock is not None else threading.RLock()
        self.faults = ServoFaults(seed=seed)
        self.mechanics = ServoMechanics()
        self._values: dict[str, int] = {f.name: f.default for f in ct.FIELDS}
        self._set_checked("id", dxl_id)
        self._values["baud_rate"] = ct.baud_register_for(baudrate)
        self._registered: tuple[int, bytes] | None = None
        self._motion: Move | None = None
        self._rest_raw = float(position_ticks)
        self._last_direction = 0
        self._boot_s = self._clock.now()
        self._values["goal_position"] = int(position_ticks)

    def __repr__(self) -> str:
        torque, error = self._values["torque_enable"], self.hardware_error_status
        return f"VirtualServo(id={self.id}, torque={torque}, hardware_error_status={error:#04x})"

    # --- identity and wire settings -------------------------------------------------------------------

    @property
    def id(self) -> int:
        """Present ID (7)."""
        return self._values["id"]

    @property
    def secondary_id(self) -> int | None:
        """Secondary (shadow) ID (12), or None when disabled (values above 252)."""
        value = self._values["secondary_id"]
        return value if value <= 252 else None

    @property
    def baudrate(self) -> int:
        """Line speed in bits per second selected by Baud Rate (8)."""
        return ct.BAUD_RATES[self._values["baud_rate"]]

    @property
    def return_delay_s(self) -> float:
        """Return Delay Time (9) in seconds (2 us units)."""
        return self._values["return_delay_time"] * 2e-6

    @property
    def status_return_level(self) -> int:
        """Status Return Level (68): 0 PING only, 1 PING and READ, 2 all instructions."""
        return self._values["status_return_level"]

    @property
    def speaks_protocol_2(self) -> bool:
        """False after Protocol Type (13) was set to 1: the servo then ignores Protocol 2.0 packets."""
        return self._values["protocol_type"] == 2

    @property
    def hardware_error_status(self) -> int:
        """Hardware Error Status (70) bits; nonzero means the Alert bit is set in every status packet."""
        return self._values["hardware_error_status"]

    @property
    def torque_enabled(self) -> bool:
        """Torque Enable (64)."""
        return bool(self._values["torque_enable"])

    def status_error(self, number: int) -> int:
        """Status packet error byte for error ``number``, with the Alert bit while a hardware error stands."""
        with self._lock:
            return (number & 0x7F) | (ALERT_BIT if self._values["hardware_error_status"] else 0)

    # --- Python-side access ---------------------------------------------------------------------------

    def value(self, name: str) -> int:
        """Current value of control table item ``name`` (live items evaluated at ``clock.now()``)."""
        with self._lock:
            f = ct.field(name)
            if f.name in _LIVE:
                return self._live_values(self._clock.now())[f.name]
            return self._values[f.name]

    def poke(self, name: str, value: int) -> None:
        """Set a stored item directly (no torque or access rules, range still checked), e.g. for test setup."""
        with self._lock:
            if name in _LIVE:
                raise ValueError(f"servo {self.id}: {name!r} is computed from the motion and cannot be set")
            self._set_checked(name, value)

    def state(self) -> ServoState:
        """Kinematic state at ``clock.now()``."""
        with self._lock:
            return self._state(self._clock.now())

    def present_position_ticks(self) -> int:
        """Present Position (132) as the bus would report it now (ticks)."""
        return self.value("present_position")

    def physical_position_ticks(self) -> float:
        """Where the load really is now (ticks): Present Position, off by its settle, less half the backlash."""
        with self._lock:
            pos = self._state(self._clock.now()).position
            settled = self.mechanics.settle_offset(self.id, self._values["goal_position"])
            return pos + settled - self._last_direction * 0.5 * self.mechanics.backlash_ticks

    def place(self, position_ticks: float) -> None:
        """Turn the horn by hand to ``position_ticks`` (Present Position units); only with torque off."""
        with self._lock:
            if self._values["torque_enable"]:
                raise RuntimeError(f"servo {self.id}: torque is on, the horn cannot be turned by hand")
            self._motion = None
            self._rest_raw = float(position_ticks) - self._values["homing_offset"]

    def inject_hardware_error(self, errors: int) -> HardwareError:
        """Raise hardware errors now; those enabled in Shutdown (63) latch, cut the torque and set Alert.

        Returns the errors that took effect (errors masked out of Shutdown are not detected, per the
        e-Manual). Only REBOOT clears them.
        """
        with self._lock:
            effective = HardwareError(int(errors) & self._values["shutdown"])
            if not effective:
                return effective
            self._freeze(self._clock.now())
            self._values["hardware_error_status"] |= int(effective)
            self._values["torque_enable"] = 0
            if effective & HardwareError.OVERHEATING:
                self._values["present_temperature"] = self._values["temperature_limit"] + 1
            if effective & HardwareError.INPUT_VOLTAGE:
                self._values["present_input_voltage"] = self._values["max_voltage_limit"] + 5
            return effective

    # --- instructions (called by the bus with a parsed packet) -----------------------------------------

    def read(self, address: int, length: int) -> tuple[ErrorNumber, bytes]:
        """READ: ``length`` bytes from ``address``; Access Error (no data) past the end of the table."""
        with self._lock:
            if address + length > ct.TABLE_SIZE:
                return ErrorNumber.ACCESS, b""
            if length == 0:
                return ErrorNumber.NONE, b""
            live = self._live_values(self._clock.now())
            out = bytearray(length)
            for f, _ in ct.fields_touched(address, length):
                raw = f.encode(live[f.name] if f.name in live else self._values[f.name])
                for i, byte in enumerate(raw):
                    pos = f.address + i - address
                    if 0 <= pos < length:
                        out[pos] = byte
            return ErrorNumber.NONE, bytes(out)

    def write(self, address: int, data: bytes) -> ErrorNumber:
        """WRITE: all or nothing; the first rule broken decides the error number."""
        with self._lock:
            error, updates = self._check_write(address, data)
            if error == ErrorNumber.NONE:
                self._apply(updates)
            return error

    def reg_write(self, address: int, data: bytes) -> ErrorNumber:
        """REG_WRITE: check now, store, and execute on ACTION (Registered Instruction (69) becomes 1)."""
        with self._lock:
            error, _ = self._check_write(address, data)
            if error == ErrorNumber.NONE:
                self._registered = (address, bytes(data))
                self._values["registered_instruction"] = 1
            return error

    def action(self) -> ErrorNumber:
        """ACTION: run the registered write; Instruction Error if nothing is registered."""
        with self._lock:
            if self._registered is None:
                return ErrorNumber.INSTRUCTION
            address, data = self._registered
            self._registered = None
            self._values["registered_instruction"] = 0
            return self.write(address, data)

    def reboot(self) -> None:
        """REBOOT (or a power cycle): RAM back to defaults, errors cleared, torque off, position kept."""
        with self._lock:
            now = self._clock.now()
            self._freeze(now)
            for f in ct.FIELDS:
                if not f.eeprom and f.name not in _LIVE:
                    self._values[f.name] = f.default
            self._values["goal_pwm"] = self._values["pwm_limit"]
            self._values["goal_current"] = self._values["current_limit"]
            self._registered = None
            # The absolute encoder knows the angle within one turn; the turn count is lost at boot.
            self._rest_raw %= ct.TICKS_PER_REV
            self._values["goal_position"] = round(self._rest_raw) + self._values["homing_offset"]
            self._boot_s = now

    def factory_reset(self, option: int) -> ErrorNumber:
        """FACTORY_RESET: 0xFF everything, 0x01 all but ID, 0x02 all but ID and Baud Rate; then reboot."""
        with self._lock:
            if option not in (0xFF, 0x01, 0x02):
                return ErrorNumber.DATA_RANGE
            keep = {"id"} if option == 0x01 else {"id", "baud_rate"} if option == 0x02 else set()
            for f in ct.FIELDS:
                if f.writable and f.name not in keep:
                    self._values[f.name] = f.default
            self.reboot()
            return ErrorNumber.NONE

    def clear(self, params: bytes) -> ErrorNumber:
        """CLEAR 0x01: forget the turn count (position back within one turn); Result Fail while moving."""
        with self._lock:
            if len(params) != len(_CLEAR_MAGIC):
                return ErrorNumber.DATA_LENGTH
            if params != _CLEAR_MAGIC:
                return ErrorNumber.DATA_RANGE
            now = self._clock.now()
            if self._state(now).moving:
                return ErrorNumber.RESULT_FAIL
            self._freeze(now)
            self._rest_raw %= ct.TICKS_PER_REV
            return ErrorNumber.NONE

    # --- internals ------------------------------------------------------------------------------------

    def _set_checked(self, name: str, value: int) -> None:
        f = ct.field(name)
        if not f.in_range(int(value)):
            raise ValueError(f"{name} = {value!r} is outside its range for an XM430-W350")
        self._values[name] = int(value)

    def _check_write(self, address: int, data: bytes) -> tuple[ErrorNumber, list[tuple[ct.Field, int]]]:
        if not data:
            return ErrorNumber.DATA_LENGTH, []
        if address + len(data) > ct.TABLE_SIZE:
            return ErrorNumber.ACCESS, []
        touched = list(ct.fields_touched(address, len(data)))
        if not touched or any(not f.writable for f, _ in touched):
            return ErrorNumber.ACCESS, []
        if self._values["torque_enable"] and any(f.eeprom for f, _ in touched):
            return ErrorNumber.ACCESS, []
        if not all(full for _, full in touched):
            return ErrorNumber.DATA_LENGTH, []
        updates = [(f, f.decode(data[f.address - address : f.end - address])) for f, _ in touched]
        if any(not f.in_range(v) for f, v in updates):
            return ErrorNumber.DATA_RANGE, []
        proposed = dict(self._values)
        proposed.update({f.name: v for f, v in updates})
        for f, v in updates:
            if not self._within_limits(f.name, v, proposed):
                return ErrorNumber.DATA_LIMIT, []
            if f.name == "torque_enable" and v and self._values["hardware_error_status"]:
                return ErrorNumber.RESULT_FAIL, []  # only REBOOT re-arms a servo that shut down
        return ErrorNumber.NONE, updates

    @staticmethod
    def _within_limits(name: str, value: int, p: dict[str, int]) -> bool:
        if name == "goal_position" and p["operating_mode"] == 3:
            return p["min_position_limit"] <= value <= p["max_position_limit"]
        if name == "profile_velocity" and not p["drive_mode"] & 0x04:
            return value <= p["velocity_limit"]
        if name == "goal_velocity":
            return abs(value) <= p["velocity_limit"]
        if name == "goal_current":
            return abs(value) <= p["current_limit"]
        if name == "goal_pwm":
            return abs(value) <= p["pwm_limit"]
        return True

    def _apply(self, updates: list[tuple[ct.Field, int]]) -> None:
        now = self._clock.now()
        new_goal = False
        for f, v in updates:
            old = self._values[f.name]
            if f.name == "torque_enable" and v != old:
                # Either way the servo stops where it is; switching on it holds there, not at a stale goal.
                self._freeze(now)
                if v:
                    self._values["goal_position"] = round(self._rest_raw) + self._values["homing_offset"]
            self._values[f.name] = v
            new_goal = new_goal or f.name == "goal_position"
        if new_goal and self._values["torque_enable"] and self._values["operating_mode"] in _POSITION_MODES:
            self._start_move(now)

    def _freeze(self, now: float) -> None:
        self._rest_raw = self._state(now).position - self._values["homing_offset"]
        self._motion = None

    def _start_move(self, now: float) -> None:
        offset = self._values["homing_offset"]
        present = self._state(now)
        x0 = present.position - offset
        goal = float(self._values["goal_position"] - offset)
        v = self._values
        limits = profile_limits(
            abs(goal - x0), v["profile_velocity"], v["profile_acceleration"], v["velocity_limit"],
            bool(v["drive_mode"] & 0x04),
        )  # fmt: skip
        stall = self.faults.stall_short_ticks
        shortfall = float(stall) if stall is not None else float(self.mechanics.steady_state_error_ticks)
        self._motion = Move.start(
            now, x0, present.velocity, goal, limits, shortfall=shortfall, stalls=stall is not None
        )
        if self._motion.direction:
            self._last_direction = self._motion.direction

    def _state(self, now: float) -> ServoState:
        offset = self._values["homing_offset"]
        if self._motion is None:
            return ServoState.at_rest(now, self._rest_raw + offset, holding=bool(self._values["torque_enable"]))
        threshold = self._values["moving_threshold"] * TICKS_PER_S_PER_VELOCITY_UNIT
        return self._motion.state(now, offset, threshold)

    def _live_values(self, now: float) -> dict[str, int]:
        s = self._state(now)
        torque = self._values["torque_enable"]
        current = round(s.acceleration / TICKS_PER_S2_PER_ACCELERATION_UNIT * 2.0) if torque else 0
        if s.following_error and torque:
            current = _STALL_CURRENT
        limit_i, limit_pwm = self._values["current_limit"], self._values["pwm_limit"]
        pwm = round(885.0 * s.velocity / NO_LOAD_SPEED_TICKS_PER_S) if torque else 0
        status = int(s.in_position) | (0x02 if s.profile_ongoing else 0) | (0x08 if s.following_error else 0)
        return {
            "realtime_tick": int((now - self._boot_s) * 1000.0) % 32768,
            "moving": int(s.moving),
            "moving_status": status | int(s.profile_type),
            "present_pwm": max(-limit_pwm, min(limit_pwm, pwm)),
            "present_current": max(-limit_i, min(limit_i, current)),
            "present_velocity": round(s.velocity / TICKS_PER_S_PER_VELOCITY_UNIT),
            "present_position": round(s.position),
            "velocity_trajectory": round(s.trajectory_velocity / TICKS_PER_S_PER_VELOCITY_UNIT),
            "position_trajectory": round(s.trajectory_position),
        }
