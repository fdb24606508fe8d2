"""The Dynamixel link against the virtual bus, with the real dynamixel_sdk underneath and a shared clock."""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator

import pytest

from rig.instrument.axis import Axis, AxisLimitError
from rig.instrument.clock import ManualClock
from rig.instrument.links import dynamixel_bus
from rig.instrument.links.base import LinkError, MotionLink, MoveTimeout
from rig.instrument.links.dynamixel import DynamixelLink, DynamixelOptions, ServoFault
from rig.instrument.links.dynamixel_bus import CommunicationError, DynamixelBus
from rig.instrument.links.dynamixel_table import X_SERIES, describe_hardware_error, table_for_model
from simulator.dynamixel import HardwareError, open_virtual_bus
from simulator.dynamixel.bus import VirtualDynamixelBus

TICKS = 4096 / 360
# A loaded 2-core CI machine can miss the SDK's 34 ms default reply window; a real adapter would not.
LATENCY_MS = 60.0
NAMES = ("light", "camera", "tilt", "roll")


def make_axes(**overrides: float) -> list[Axis]:
    """Four XM430 joints: 0 deg at tick 2048, limits +-150 deg, 60 deg/s, 120 deg/s^2."""
    base = dict(units_per_degree=TICKS, zero_offset_deg=-180.0, min_deg=-150.0, max_deg=150.0, tolerance_deg=0.2)
    base.update(overrides)
    return [Axis(name=n, address=i + 1, **base) for i, n in enumerate(NAMES)]  # type: ignore[arg-type]


@pytest.fixture
def clock() -> ManualClock:
    return ManualClock()


@pytest.fixture
def bus(clock: ManualClock) -> Iterator[VirtualDynamixelBus]:
    with open_virtual_bus(ids=(1, 2, 3, 4), baudrate=1_000_000, clock=clock) as b:
        yield b


def open_link(bus: VirtualDynamixelBus, clock: ManualClock, axes: list[Axis] | None = None, **options: object):
    return DynamixelLink.open(
        bus.port,
        axes or make_axes(),
        clock=clock,
        latency_timer_ms=LATENCY_MS,
        options=DynamixelOptions(**options),  # type: ignore[arg-type]
    )


def trapezoid_s(distance: float, speed: float, accel: float) -> float:
    """Duration of a rest-to-rest trapezoidal move (any consistent units)."""
    if distance * accel <= speed**2:
        return 2 * (distance / accel) ** 0.5
    return distance / speed + speed / accel


def test_link_satisfies_the_motion_interface(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    with open_link(bus, clock) as link:
        assert isinstance(link, MotionLink)


def test_configure_programs_mode_limits_profile_and_torque(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    with open_link(bus, clock):
        s = bus.servo(2)
        assert s.value("operating_mode") == 3
        # The hardware limits are the soft limits rounded inwards: -150 deg is tick 341.3, +150 deg 3754.7.
        assert s.value("min_position_limit") == 342
        assert s.value("max_position_limit") == 3754
        assert s.value("return_delay_time") == 0
        assert s.value("profile_velocity") == X_SERIES.velocity_units(60.0) == 44
        assert s.value("profile_acceleration") == X_SERIES.accel_units(120.0) == 6
        assert s.torque_enabled


def test_geared_axis_uses_extended_position_mode(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    axes = make_axes(gear_ratio=3.0)
    with open_link(bus, clock, axes) as link:
        assert bus.servo(1).value("operating_mode") == 4
        link.move_to({"light": 120.0})
        positions = link.wait_in_position(timeout_s=30.0)
        assert positions["light"] == pytest.approx(120.0, abs=0.2)
        # Joint 120 deg is 300 deg from the axis zero (-180), 900 motor degrees: 2.5 encoder turns.
        assert bus.servo(1).value("present_position") == pytest.approx(900 * TICKS, abs=3)


def test_pose_reaches_targets_in_the_time_the_profile_needs(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    pose = {"light": 30.0, "camera": -45.0, "tilt": 10.0, "roll": 90.0}
    with open_link(bus, clock, poll_interval_s=0.005) as link:
        start = clock.now()
        link.move_to(pose)
        positions = link.wait_in_position(timeout_s=30.0)
        elapsed = clock.now() - start
    for name, target in pose.items():
        assert positions[name] == pytest.approx(target, abs=0.2)
    # The programmed profile, in the servo's own units (0.229 rpm, 214.577 rev/min^2), for the 90 deg roll.
    speed = 44 * 0.229 * 6.0  # deg/s
    accel = 6 * 214.577 / 10.0  # deg/s^2
    expected = trapezoid_s(90.0, speed, accel)
    assert expected <= elapsed <= expected + 0.05


def test_targets_outside_limits_are_refused_before_anything_moves(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    with open_link(bus, clock) as link:
        goals = [s.value("goal_position") for s in bus.servos]
        with pytest.raises(AxisLimitError, match=r"axis 'tilt': target 170 deg is above its upper limit 150 deg"):
            link.move_to({"light": 10.0, "tilt": 170.0})
        assert [s.value("goal_position") for s in bus.servos] == goals
        with pytest.raises(KeyError, match="unknown axes"):
            link.move_to({"elbow": 1.0})


def test_dropped_and_corrupt_replies_are_retried(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    with open_link(bus, clock) as link:
        link.move_to({"light": 20.0})
        bus.servo(3).faults.drop_replies = 2
        bus.servo(1).faults.corrupt_replies = 1
        positions = link.wait_in_position(timeout_s=30.0)
        assert positions["light"] == pytest.approx(20.0, abs=0.2)
        assert bus.servo(3).faults.drop_replies == bus.servo(1).faults.corrupt_replies == 0
        # Servo 1's corrupt reply and servo 3's first drop spoil the same sync read; the second drop another.
        assert link.bus.comm_retries_used == 2


def test_a_servo_that_stops_answering_gives_a_clear_error(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    with open_link(bus, clock) as link:
        bus.servo(4).faults.drop_replies = 10
        # 3 retries, then one more while the window can still widen (1, 2, 4, 8, then the 16x cap).
        with pytest.raises(CommunicationError, match=r"no status packet.*after 5 attempts.*lost.*check baud rate"):
            link.read_positions()
        bus.servo(4).faults.clear()


def test_overload_shutdown_is_reported_with_its_cause(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    with open_link(bus, clock) as link:
        link.move_to({"camera": -60.0})
        clock.advance(0.2)
        bus.servo(2).inject_hardware_error(HardwareError.OVERLOAD)
        with pytest.raises(ServoFault, match=r"axis 'camera' \(servo 2\) shut down: overload") as info:
            link.wait_in_position(timeout_s=30.0)
        assert info.value.hardware_error == 0x20
        assert not bus.servo(2).torque_enabled


def test_overload_is_recovered_by_reboot_when_allowed(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    with open_link(bus, clock, allow_reboot=True) as link:
        link.move_to({"camera": -60.0, "light": 40.0})
        clock.advance(0.2)
        bus.servo(2).inject_hardware_error(HardwareError.OVERHEATING)
        positions = link.wait_in_position(timeout_s=30.0)
        assert positions["camera"] == pytest.approx(-60.0, abs=0.2)
        assert link.reboots == 1
        assert bus.servo(2).hardware_error_status == 0


def test_stalled_servo_times_out_with_positions(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    with open_link(bus, clock) as link:
        bus.servo(3).faults.stall_short_ticks = 100
        link.move_to({"tilt": 45.0})
        with pytest.raises(MoveTimeout, match=r"'tilt' at .* target 45\.000 deg .* still moving") as info:
            link.wait_in_position(timeout_s=5.0)
        assert info.value.positions_deg["tilt"] == pytest.approx(45.0 - 100 / TICKS, abs=0.1)
        assert clock.now() == pytest.approx(5.0, abs=0.02)


def test_steady_state_error_against_tolerance(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    with open_link(bus, clock) as link:
        bus.servo(1).mechanics.steady_state_error_ticks = 1.0  # 0.088 deg: inside 0.2 deg
        link.move_to({"light": 30.0})
        assert link.wait_in_position(timeout_s=10.0)["light"] == pytest.approx(30.0, abs=0.2)
        bus.servo(1).mechanics.steady_state_error_ticks = 5.0  # 0.44 deg: outside
        link.move_to({"light": -30.0})
        with pytest.raises(MoveTimeout, match="stopped outside tolerance"):
            link.wait_in_position(timeout_s=10.0)


def test_stop_holds_where_the_axes_are(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    with open_link(bus, clock) as link:
        link.move_to({"roll": 140.0})
        link.read_positions()  # a round trip: the bus has taken the (unanswered) sync write before time moves
        clock.advance(0.5)
        link.stop()
        held = link.wait_in_position(timeout_s=10.0)["roll"]
        assert 0.0 < held < 140.0
        clock.advance(5.0)
        assert link.read_positions()["roll"] == pytest.approx(held, abs=0.2)


def test_shutdown_switches_torque_off_closes_and_is_idempotent(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    link = open_link(bus, clock)
    link.shutdown()
    link.shutdown()
    assert not any(s.torque_enabled for s in bus.servos)
    with pytest.raises(LinkError, match="shut down"):
        link.move_to({"light": 0.0})


def test_shutdown_runs_even_when_the_block_fails(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    with pytest.raises(RuntimeError, match="operator abort"), open_link(bus, clock) as link:
        link.move_to({"light": 10.0})
        raise RuntimeError("operator abort")
    assert not any(s.torque_enabled for s in bus.servos)


def test_bulk_read_gives_the_same_positions_as_sync_read(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    with open_link(bus, clock) as link:
        link.move_to({"light": 12.5, "camera": -33.0})
        link.wait_in_position(timeout_s=10.0)
        sync = link.read_positions()
    with open_link(bus, clock, read_mode="bulk") as link:
        assert link.read_positions() == sync


def test_concurrent_users_are_serialised_by_the_bus_owner(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    with open_link(bus, clock) as link:
        errors: list[BaseException] = []

        def hammer() -> None:
            try:
                for _ in range(25):
                    assert set(link.read_positions()) == set(NAMES)
            except BaseException as exc:
                errors.append(exc)

        threads = [threading.Thread(target=hammer) for _ in range(3)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=60)
        assert not errors
        assert link.bus.comm_retries_used == 0


def test_scan_finds_servos_at_their_own_baud_rates(clock: ManualClock) -> None:
    with open_virtual_bus(ids=(1, 2), baudrate=57_600, clock=clock) as b:
        b.servo(2).poke("baud_rate", 3)  # 1 Mbps
        with DynamixelBus(b.port, 57_600, latency_timer_ms=LATENCY_MS) as dxl:
            found = dxl.scan(baudrates=(57_600, 1_000_000))
            seen = [(f.baudrate, f.servo_id, f.model_number) for f in found]
            assert seen == [(57_600, 1, 1020), (1_000_000, 2, 1020)]
            assert dxl.baudrate == 57_600
            by_id = dxl.scan(baudrates=(1_000_000,), ids=range(1, 4))
            assert [(f.servo_id, f.firmware) for f in by_id] == [(2, b.servo(2).value("firmware_version"))]


def test_unknown_id_names_the_axis(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    axes = [*make_axes()[:3], Axis(name="roll", address=9, units_per_degree=TICKS, zero_offset_deg=-180.0)]
    with pytest.raises(LinkError, match=r"axis 'roll': no servo with id 9 answers"):
        open_link(bus, clock, axes)


def test_wrong_resolution_for_the_model_is_refused(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    with pytest.raises(ValueError, match=r"axis 'light': units_per_degree = 10.0, but servo 1 is a XM430-W350"):
        open_link(bus, clock, make_axes(units_per_degree=10.0))


def test_baud_rate_the_sdk_refuses() -> None:
    with pytest.raises(ValueError, match=r"baud rate 1500000 is not one dynamixel_sdk accepts.*57600"):
        DynamixelBus("/dev/null", 1_500_000)


def test_port_that_does_not_exist() -> None:
    with pytest.raises(LinkError, match=r"cannot open Dynamixel port '/dev/does-not-exist'"):
        DynamixelBus("/dev/does-not-exist")


def test_port_that_is_not_a_servo_bus() -> None:
    master, slave = os.openpty()
    try:
        with pytest.raises(LinkError, match=r"axis 'light': no servo with id 1 answers.*no status packet"):
            DynamixelLink.open(os.ttyname(slave), make_axes(), retries=1, latency_timer_ms=5.0)
    finally:
        os.close(master)
        os.close(slave)


def test_model_tables_and_error_texts() -> None:
    assert table_for_model(1020) is X_SERIES
    with pytest.raises(ValueError, match=r"servo 3: model number 4242 is not supported"):
        table_for_model(4242, where="servo 3")
    assert describe_hardware_error(0x24) == "overheating, overload"
    assert X_SERIES.motion_block == (122, 14)


def test_delayed_replies_within_the_timeout_are_waited_for(bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    with open_link(bus, clock) as link:
        bus.servo(2).faults.reply_delay_s = 0.03  # under the 122 ms reply window (2 x 60 ms + 2 ms)
        assert set(link.read_positions()) == set(NAMES)
        assert link.bus.comm_retries_used == 0
        bus.servo(2).faults.clear()


def test_late_replies_fail_after_bounded_retries(
    bus: VirtualDynamixelBus, clock: ManualClock, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Replies later than the widest window the bus may open: with the window free to widen (16x, ~2 s here)
    # a 0.3 s reply is late or on time depending on whether the drain saw it late, which a loaded host decides.
    monkeypatch.setattr(dynamixel_bus, "MAX_TIMEOUT_SCALE", 1.0)
    with open_link(bus, clock) as link:
        bus.servo(2).faults.reply_delay_s = 0.3
        link.bus.retries = 1
        link.bus.reply_patience_s = 0.0  # no patience for a slow host: the retry count alone bounds the wait
        try:
            # A late reply the drain catches counts as late, one it misses as lost, which the host's timing
            # decides: either way the read gives up after its retry and at most one more on a silent servo.
            with pytest.raises(CommunicationError, match=r"after [23] attempts"):
                link.read_positions()
        finally:
            bus.servo(2).faults.clear()
