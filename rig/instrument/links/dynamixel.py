"""The Dynamixel link: a pose is one SYNC_WRITE of goal positions, arrival is polled with one SYNC_READ.

Each servo is configured once (torque off, operating mode, position limits, return delay, profile
velocity and acceleration, torque on). A move checks every target against its axis's soft limits before
anything is sent, so a refused pose moves nothing. While waiting, every poll reads Moving, Moving Status
and Present Position of all axes in one packet and inspects each status packet's Alert bit, so a servo
that shut itself down (overload, overheating) is noticed on the next poll rather than at the timeout.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from rig.instrument.axis import Axis
from rig.instrument.clock import Clock, SystemClock, poll_until
from rig.instrument.links.base import LinkError, MoveTimeout, Pose
from rig.instrument.links.dynamixel_bus import CommunicationError, DynamixelBus, Reading
from rig.instrument.links.dynamixel_table import ControlTable, describe_hardware_error, model_name, table_for_model

POSITION_MODE = 3
EXTENDED_POSITION_MODE = 4
_MOVING_STATUS_IN_POSITION = 0x01


class ServoFault(LinkError):
    """A servo shut down on a hardware error (overload, overheating, ...) and was not recovered."""

    def __init__(self, message: str, axis: str, hardware_error: int) -> None:
        super().__init__(message)
        self.axis = axis
        self.hardware_error = hardware_error


@dataclass(frozen=True)
class DynamixelOptions:
    """How the link configures and polls the servos.

    Parameters
    ----------
    poll_interval_s:
        Time between in-position polls, seconds of the link's clock.
    return_delay_us:
        Return Delay Time to program (microseconds, 2 us steps); 0 is fastest (the factory 500 us
        dominates read latency on a real bus).
    allow_reboot:
        Recover a servo that shut down on a hardware error by REBOOT, reconfigure it and resend its goal.
        Off by default: an overload usually means the arm hit something.
    max_reboots:
        Reboots allowed within one wait before giving up.
    read_mode:
        ``"auto"`` uses SYNC_READ when all servos share a control table and BULK_READ otherwise;
        ``"sync"`` or ``"bulk"`` force one.
    """

    poll_interval_s: float = 0.01
    return_delay_us: int = 0
    allow_reboot: bool = False
    max_reboots: int = 2
    read_mode: str = "auto"

    def __post_init__(self) -> None:
        if not self.poll_interval_s > 0:
            raise ValueError(f"poll_interval_s = {self.poll_interval_s!r}: expected a positive number of seconds")
        if not 0 <= self.return_delay_us <= 508:
            raise ValueError(f"return_delay_us = {self.return_delay_us!r}: expected 0..508 microseconds")
        if self.read_mode not in ("auto", "sync", "bulk"):
            raise ValueError(f"read_mode = {self.read_mode!r}: expected 'auto', 'sync' or 'bulk'")
        if self.max_reboots < 0:
            raise ValueError(f"max_reboots = {self.max_reboots!r}: expected a count >= 0")


@dataclass(frozen=True)
class AxisState:
    """One poll of one axis: joint angle (degrees), Moving flag, Moving Status and the Alert bit."""

    position_deg: float
    moving: bool
    moving_status: int
    alert: bool


class DynamixelLink:
    """Drives a set of axes whose addresses are Dynamixel ids on one bus (Protocol 2.0)."""

    def __init__(
        self,
        bus: DynamixelBus,
        axes: Sequence[Axis],
        *,
        clock: Clock | None = None,
        options: DynamixelOptions | None = None,
        configure: bool = True,
    ) -> None:
        if not axes:
            raise ValueError("DynamixelLink needs at least one axis")
        names = [a.name for a in axes]
        ids = [a.address for a in axes]
        if len(set(names)) != len(names):
            raise ValueError(f"DynamixelLink: axis names repeat: {names}")
        for axis in axes:
            if not isinstance(axis.address, int):
                raise ValueError(f"axis {axis.name!r}: address {axis.address!r} is not a Dynamixel id (0..252)")
        if len(set(ids)) != len(ids):
            raise ValueError(f"DynamixelLink: servo ids repeat: {ids}")
        self.bus = bus
        self.axes = {a.name: a for a in axes}
        self.clock = clock or SystemClock()
        self.options = options or DynamixelOptions()
        self.targets_deg: dict[str, float] = {}
        self.reboots = 0
        self._tables: dict[str, ControlTable] = {}
        self._models: dict[str, int] = {}
        self._closed = False
        if configure:
            self.configure()

    @classmethod
    def open(
        cls,
        port: str,
        axes: Sequence[Axis],
        *,
        baudrate: int = 1_000_000,
        retries: int = 3,
        latency_timer_ms: float = 16.0,
        clock: Clock | None = None,
        options: DynamixelOptions | None = None,
    ) -> DynamixelLink:
        """Open ``port`` at ``baudrate`` and configure every axis's servo."""
        # The bus shares the link's clock: on simulated time a reply the virtual bus dropped costs no wall time.
        bus = DynamixelBus(port, baudrate, retries=retries, latency_timer_ms=latency_timer_ms, clock=clock)
        try:
            return cls(bus, axes, clock=clock, options=options)
        except BaseException:
            bus.close()
            raise

    def __enter__(self) -> DynamixelLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()

    def _id(self, name: str) -> int:
        address = self.axes[name].address
        assert isinstance(address, int)
        return address

    # -- configuration ------------------------------------------------------------------------------

    def configure(self) -> None:
        """Find every servo, check its model against its axis, program mode, limits and profile; torque on."""
        for name, axis in self.axes.items():
            sid = self._id(name)
            try:
                model = self.bus.ping(sid)
            except CommunicationError as exc:
                where = f"axis {name!r}: no servo with id {sid} answers on {self.bus.port_name}"
                raise LinkError(f"{where}: {exc}") from exc
            table = table_for_model(model, where=f"axis {name!r} (servo {sid})")
            if abs(axis.units_per_degree - table.ticks_per_degree) > 1e-9 * table.ticks_per_degree:
                raise ValueError(
                    f"axis {name!r}: units_per_degree = {axis.units_per_degree!r}, but servo {sid} is a "
                    f"{model_name(model)} with {table.ticks_per_degree!r} ticks per degree"
                )
            self._tables[name] = table
            self._models[name] = model
            self._configure_servo(name)

    def _configure_servo(self, name: str) -> None:
        axis, table, sid = self.axes[name], self._tables[name], self._id(name)
        lo, hi = sorted((axis.to_units(axis.min_deg), axis.to_units(axis.max_deg)))
        # Position mode lets the servo enforce the soft limits itself; outside one turn only extended
        # mode reaches the targets, and the limits are then ours alone.
        mode = POSITION_MODE if 0 <= lo and hi <= table.ticks_per_turn - 1 else EXTENDED_POSITION_MODE
        motor_speed = axis.max_speed_deg_s * axis.gear_ratio
        motor_accel = axis.max_accel_deg_s2 * axis.gear_ratio
        self.bus.write(sid, table.torque_enable, 1, 0)
        self.bus.write(sid, table.operating_mode, 1, mode)
        if mode == POSITION_MODE:
            self.bus.write(sid, table.max_position_limit, 4, math.floor(hi))
            self.bus.write(sid, table.min_position_limit, 4, math.ceil(lo))
        self.bus.write(sid, table.return_delay_time, 1, self.options.return_delay_us // 2)
        self.bus.write(sid, table.profile_velocity, 4, table.velocity_units(motor_speed))
        self.bus.write(sid, table.profile_acceleration, 4, table.accel_units(motor_accel))
        self.bus.write(sid, table.torque_enable, 1, 1)

    def set_speed(self, speeds_deg_s: Mapping[str, float] | None) -> dict[str, float]:
        """Profile Velocity of the named axes (deg/s of joint; None: every axis's top speed); the speeds set.

        The register counts in steps of the table's velocity unit (0.229 rpm, 1.374 deg/s of motor on an XM430), so
        the speed a servo runs at is the nearest step, never below one: it is returned, in deg/s of joint.
        """
        self._require_open()
        wanted = speeds_deg_s if speeds_deg_s is not None else {n: a.max_speed_deg_s for n, a in self.axes.items()}
        out = {}
        for name, speed in wanted.items():
            axis, table = self.axes[name], self._tables[name]
            units = table.velocity_units(min(float(speed), axis.max_speed_deg_s) * axis.gear_ratio)
            self.bus.write(self._id(name), table.profile_velocity, 4, units)
            out[name] = units * table.velocity_unit_rpm * 6.0 / axis.gear_ratio
        return out

    def stops_at(self, pose: Pose) -> dict[str, float]:
        """The joint angles (deg) the servos settle at for ``pose`` (deg): each Goal Position a whole count."""
        return {n: self.axes[n].to_degrees(round(self.axes[n].to_units(float(deg)))) for n, deg in pose.items()}

    # -- motion -------------------------------------------------------------------------------------

    def move_to(self, pose: Pose) -> None:
        """Send every target (degrees) in one SYNC_WRITE, after checking all of them against the limits."""
        self._require_open()
        unknown = sorted(set(pose) - set(self.axes))
        if unknown:
            raise KeyError(f"pose names unknown axes {unknown}; this link drives {sorted(self.axes)}")
        ticks = {name: round(self.axes[name].to_units(float(deg))) for name, deg in pose.items()}
        by_address: dict[int, dict[int, int]] = {}
        for name, value in ticks.items():
            by_address.setdefault(self._tables[name].goal_position, {})[self._id(name)] = value
        for address, values in by_address.items():
            self.bus.sync_write(address, 4, values)
        self.targets_deg.update({name: float(deg) for name, deg in pose.items()})

    def poll(self) -> dict[str, AxisState]:
        """Moving, Moving Status, position (degrees) and Alert of every axis, read in one packet."""
        self._require_open()
        families = {t.family for t in self._tables.values()}
        mode = self.options.read_mode
        names = list(self.axes)
        if mode == "sync" or (mode == "auto" and len(families) == 1):
            address, size = self._tables[names[0]].motion_block
            readings = self.bus.sync_read(address, size, [self._id(n) for n in names])
        else:
            readings = self.bus.bulk_read({self._id(n): self._tables[n].motion_block for n in names})
        return {name: self._decode(name, readings[self._id(name)]) for name in names}

    def _decode(self, name: str, reading: Reading) -> AxisState:
        table = self._tables[name]
        ticks = reading.value(table.present_position - table.moving, 4, signed=True)
        return AxisState(
            position_deg=self.axes[name].to_degrees(ticks),
            moving=bool(reading.value(0, 1)),
            moving_status=reading.value(table.moving_status - table.moving, 1),
            alert=reading.alert,
        )

    def read_positions(self) -> dict[str, float]:
        """Present joint angle of every axis in degrees."""
        return {name: state.position_deg for name, state in self.poll().items()}

    def wait_in_position(self, timeout_s: float) -> dict[str, float]:
        """Poll until every axis with a target has stopped within tolerance; return positions in degrees."""
        self._require_open()
        if not timeout_s > 0:
            raise ValueError(f"timeout_s = {timeout_s!r}: expected a positive number of seconds")
        deadline = self.clock.now() + timeout_s
        reboots_left = self.options.max_reboots
        while True:
            states = self.poll()
            faulted = [name for name, s in states.items() if s.alert]
            if faulted:
                if not self.options.allow_reboot or reboots_left < len(faulted):
                    self._raise_fault(faulted[0])
                for name in faulted:
                    self._recover(name)
                    reboots_left -= 1
                continue
            positions = {name: s.position_deg for name, s in states.items()}
            if all(
                not states[name].moving and self.axes[name].in_position(positions[name], target)
                for name, target in self.targets_deg.items()
            ):
                return positions
            if self.clock.now() >= deadline:
                raise MoveTimeout(self._timeout_message(timeout_s, states), positions)
            self.clock.sleep(self.options.poll_interval_s)

    def _timeout_message(self, timeout_s: float, states: dict[str, AxisState]) -> str:
        late = []
        for name, target in self.targets_deg.items():
            s = states[name]
            if s.moving or not self.axes[name].in_position(s.position_deg, target):
                hint = "still moving" if s.moving else "stopped outside tolerance"
                late.append(
                    f"{name!r} at {s.position_deg:.3f} deg, target {target:.3f} deg "
                    f"(tolerance {self.axes[name].tolerance_deg:g}), {hint}"
                )
        return f"{self.bus.port_name}: axes not in position after {timeout_s:g} s: " + "; ".join(late)

    def _raise_fault(self, name: str) -> None:
        sid = self._id(name)
        status = self.bus.read(sid, self._tables[name].hardware_error_status, 1)
        raise ServoFault(
            f"axis {name!r} (servo {sid}) shut down: {describe_hardware_error(status)} "
            f"(Hardware Error Status = {status:#04x}); torque is off until REBOOT"
            + ("" if self.options.allow_reboot else "; pass allow_reboot=True to recover automatically"),
            name,
            status,
        )

    def _recover(self, name: str) -> None:
        sid = self._id(name)
        self.bus.reboot(sid)
        # A real servo takes a moment to boot; poll its ping instead of guessing how long.
        try:
            poll_until(lambda: self.bus.try_ping(sid) is not None, 2.0, self.options.poll_interval_s, self.clock,
                       f"axis {name!r} (servo {sid}) answering after REBOOT")  # fmt: skip
        except TimeoutError as exc:
            raise LinkError(f"axis {name!r} (servo {sid}) did not come back within 2 s of REBOOT") from exc
        self._configure_servo(name)
        self.reboots += 1
        if name in self.targets_deg:
            self.move_to({name: self.targets_deg[name]})

    # -- stopping -----------------------------------------------------------------------------------

    def stop(self) -> None:
        """Halt every axis where it is now (goal := present position), torque stays on."""
        self._require_open()
        here = self.read_positions()
        clamped = {n: min(max(p, self.axes[n].min_deg), self.axes[n].max_deg) for n, p in here.items()}
        self.move_to(clamped)

    def shutdown(self, keep_torque: bool = False) -> None:
        """Stop, switch torque off on every servo (each write confirmed) and close the port; idempotent.

        ``keep_torque=True`` leaves the servos holding their position (arms that would fall or swing
        unpowered); the port is closed all the same.
        """
        if self._closed:
            return
        failures: list[str] = []
        try:
            if len(self._tables) == len(self.axes):
                self.stop()
        except LinkError as exc:
            failures.append(f"stop: {exc}")
        # Torque off one servo at a time with a status reply, so "safe" is confirmed rather than assumed.
        for name, table in self._tables.items() if not keep_torque else ():
            try:
                self.bus.write(self._id(name), table.torque_enable, 1, 0)
            except LinkError as exc:
                failures.append(f"torque off {name!r}: {exc}")
        self._closed = True
        self.bus.close()
        if failures:
            raise LinkError(f"{self.bus.port_name}: shutdown incomplete: " + "; ".join(failures))

    def _require_open(self) -> None:
        if self._closed:
            raise LinkError(f"{self.bus.port_name}: the link has been shut down")
