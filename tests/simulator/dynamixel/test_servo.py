"""One virtual XM430-W350 without a wire: control table layout and access rules, profiles and faults.

Time comes from a ``ManualClock``; nothing here waits.

One file past 400 lines on purpose: it mirrors one module, ``simulator.dynamixel.servo``.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from rig.instrument.clock import ManualClock
from simulator.dynamixel import control_table as ct
from simulator.dynamixel.faults import HardwareError
from simulator.dynamixel.motion import TICKS_PER_S2_PER_ACCELERATION_UNIT, TICKS_PER_S_PER_VELOCITY_UNIT
from simulator.dynamixel.profile import ProfileType, plan
from simulator.dynamixel.protocol import ErrorNumber
from simulator.dynamixel.servo import VirtualServo

V_UNIT = TICKS_PER_S_PER_VELOCITY_UNIT
A_UNIT = TICKS_PER_S2_PER_ACCELERATION_UNIT


def u32(value: int) -> bytes:
    return (value & 0xFFFFFFFF).to_bytes(4, "little")


@pytest.fixture
def clock() -> ManualClock:
    return ManualClock()


@pytest.fixture
def servo(clock: ManualClock) -> VirtualServo:
    return VirtualServo(1, clock=clock, position_ticks=2048)


# (name, address, size, writable, default) for the items the brief names, from the XM430-W350 e-Manual.
LAYOUT = [
    ("model_number", 0, 2, False, 1020),
    ("id", 7, 1, True, 1),
    ("baud_rate", 8, 1, True, 1),
    ("return_delay_time", 9, 1, True, 250),
    ("drive_mode", 10, 1, True, 0),
    ("operating_mode", 11, 1, True, 3),
    ("velocity_limit", 44, 4, True, 200),
    ("max_position_limit", 48, 4, True, 4095),
    ("min_position_limit", 52, 4, True, 0),
    ("shutdown", 63, 1, True, 52),
    ("torque_enable", 64, 1, True, 0),
    ("led", 65, 1, True, 0),
    ("status_return_level", 68, 1, True, 2),
    ("hardware_error_status", 70, 1, False, 0),
    ("profile_acceleration", 108, 4, True, 0),
    ("profile_velocity", 112, 4, True, 0),
    ("goal_position", 116, 4, True, 0),
    ("realtime_tick", 120, 2, False, 0),
    ("moving", 122, 1, False, 0),
    ("moving_status", 123, 1, False, 0),
    ("present_pwm", 124, 2, False, 0),
    ("present_current", 126, 2, False, 0),
    ("present_velocity", 128, 4, False, 0),
    ("present_position", 132, 4, False, 0),
    ("velocity_trajectory", 136, 4, False, 0),
    ("position_trajectory", 140, 4, False, 0),
    ("present_input_voltage", 144, 2, False, 120),
    ("present_temperature", 146, 1, False, 36),
]


@pytest.mark.parametrize(("name", "address", "size", "writable", "default"), LAYOUT)
def test_control_table_layout(name: str, address: int, size: int, writable: bool, default: int) -> None:
    f = ct.field(name)
    assert (f.address, f.size, f.writable, f.default) == (address, size, writable, default)
    assert f.eeprom == (address < 64)


def test_items_do_not_overlap_and_unknown_names_are_named() -> None:
    taken: set[int] = set()
    for f in ct.FIELDS:
        span = set(range(f.address, f.end))
        assert not span & taken, f.name
        taken |= span
    with pytest.raises(KeyError, match="no control table item 'goal_speed'"):
        ct.field("goal_speed")


def test_signed_items_round_trip(servo: VirtualServo) -> None:
    assert servo.write(20, u32(-1000)) == ErrorNumber.NONE  # Homing Offset, torque off
    assert servo.read(20, 4) == (ErrorNumber.NONE, u32(-1000))
    assert servo.value("homing_offset") == -1000
    assert servo.value("present_position") == 2048 - 1000


def test_eeprom_locked_while_torque_on(servo: VirtualServo) -> None:
    assert servo.write(64, b"\x01") == ErrorNumber.NONE
    assert servo.write(11, b"\x04") == ErrorNumber.ACCESS
    assert servo.write(9, b"\x00") == ErrorNumber.ACCESS
    assert servo.value("operating_mode") == 3
    assert servo.write(64, b"\x00") == ErrorNumber.NONE
    assert servo.write(11, b"\x04") == ErrorNumber.NONE
    assert servo.value("operating_mode") == 4


@pytest.mark.parametrize(
    ("address", "data", "error"),
    [
        (132, u32(0), ErrorNumber.ACCESS),  # read-only item
        (0, b"\x00\x00", ErrorNumber.ACCESS),  # model number
        (147, b"\x00", ErrorNumber.ACCESS),  # past the modelled table
        (14, b"\x00", ErrorNumber.ACCESS),  # unused address only
        (116, b"\x00\x08", ErrorNumber.DATA_LENGTH),  # half of Goal Position
        (118, b"\x00\x00", ErrorNumber.DATA_LENGTH),  # upper half of Goal Position
        (11, b"\x02", ErrorNumber.DATA_RANGE),  # no operating mode 2
        (9, b"\xff", ErrorNumber.DATA_RANGE),  # Return Delay Time tops out at 254
        (68, b"\x03", ErrorNumber.DATA_RANGE),  # Status Return Level 0..2
        (116, u32(4096), ErrorNumber.DATA_LIMIT),  # above Max Position Limit in position mode
        (116, u32(-1), ErrorNumber.DATA_LIMIT),
        (112, u32(201), ErrorNumber.DATA_LIMIT),  # Profile Velocity above Velocity Limit (200)
        (104, u32(-300), ErrorNumber.DATA_LIMIT),  # Goal Velocity beyond Velocity Limit
    ],
)
def test_write_errors(servo: VirtualServo, address: int, data: bytes, error: ErrorNumber) -> None:
    before = {f.name: servo.value(f.name) for f in ct.FIELDS}
    assert servo.write(address, data) == error
    assert {f.name: servo.value(f.name) for f in ct.FIELDS} == before


def test_write_spanning_several_items_is_all_or_nothing(servo: VirtualServo) -> None:
    # Profile Acceleration + Profile Velocity in one 8-byte write.
    assert servo.write(108, u32(20) + u32(100)) == ErrorNumber.NONE
    assert (servo.value("profile_acceleration"), servo.value("profile_velocity")) == (20, 100)
    # The second item is out of its limit: neither changes.
    assert servo.write(108, u32(30) + u32(500)) == ErrorNumber.DATA_LIMIT
    assert (servo.value("profile_acceleration"), servo.value("profile_velocity")) == (20, 100)
    # Torque Enable and LED with the two unused bytes after them: the gap is ignored.
    assert servo.write(64, b"\x01\x01\x07\x07") == ErrorNumber.NONE
    assert (servo.value("torque_enable"), servo.value("led")) == (1, 1)


def test_limits_checked_against_values_written_in_the_same_packet(servo: VirtualServo) -> None:
    # Max (48) and Min (52) Position Limit together, torque off.
    assert servo.write(48, u32(3000) + u32(1000)) == ErrorNumber.NONE
    assert servo.write(64, b"\x01") == ErrorNumber.NONE
    assert servo.write(116, u32(3500)) == ErrorNumber.DATA_LIMIT
    assert servo.write(116, u32(2900)) == ErrorNumber.NONE


def test_reads_past_the_table_are_access_errors(servo: VirtualServo) -> None:
    assert servo.read(146, 1) == (ErrorNumber.NONE, b"\x24")
    assert servo.read(146, 2) == (ErrorNumber.ACCESS, b"")
    assert servo.read(14, 6) == (ErrorNumber.NONE, bytes(6))  # unused bytes read as zero


def test_reg_write_waits_for_action(servo: VirtualServo, clock: ManualClock) -> None:
    servo.write(64, b"\x01")
    assert servo.action() == ErrorNumber.INSTRUCTION  # nothing registered
    assert servo.reg_write(116, u32(5000)) == ErrorNumber.DATA_LIMIT
    assert servo.reg_write(116, u32(3000)) == ErrorNumber.NONE
    assert servo.value("registered_instruction") == 1
    clock.advance(5.0)
    assert servo.value("present_position") == 2048
    assert servo.action() == ErrorNumber.NONE
    assert servo.value("registered_instruction") == 0
    clock.advance(5.0)
    assert servo.value("present_position") == 3000


def profile_numbers(pv: int, pa: int, distance: float) -> tuple[float, float, float]:
    """(cruise speed ticks/s, acceleration ticks/s^2, arrival time s) of a trapezoid from rest."""
    v, a = pv * V_UNIT, pa * A_UNIT
    ramp = v / a
    return v, a, 2 * ramp + (distance - v * v / a) / v


def test_trapezoid_in_closed_form(servo: VirtualServo, clock: ManualClock) -> None:
    servo.write(108, u32(20) + u32(100))
    servo.write(64, b"\x01")
    servo.write(116, u32(3072))
    v, a, arrival = profile_numbers(100, 20, 1024.0)
    for t in (0.05, 0.2, 0.3):  # accelerating
        clock.advance(t - clock.now())
        s = servo.state()
        assert s.position == pytest.approx(2048 + 0.5 * a * t * t)
        assert s.velocity == pytest.approx(a * t)
        assert s.profile_type == ProfileType.TRAPEZOIDAL and s.profile_ongoing and s.moving
    clock.advance(0.5 - clock.now())
    assert servo.state().velocity == pytest.approx(v)
    assert servo.value("present_velocity") == 100
    assert servo.value("moving_status") == 0x30 | 0x02
    t = arrival - 0.1  # decelerating
    clock.advance(t - clock.now())
    assert servo.state().position == pytest.approx(3072 - 0.5 * a * 0.1**2)
    clock.advance(arrival - 1e-6 - clock.now())
    assert servo.value("moving") == 1
    clock.advance(2e-6)
    assert (servo.value("moving"), servo.value("moving_status")) == (0, 0x30 | 0x01)
    assert (servo.value("present_position"), servo.value("present_velocity")) == (3072, 0)


@pytest.mark.parametrize(
    ("pv", "pa", "goal", "kind"),
    [
        (100, 20, 2248, ProfileType.TRIANGULAR),  # 200 ticks: never reaches 100 units
        (100, 0, 3072, ProfileType.RECTANGULAR),  # infinite acceleration
        (0, 0, 3072, ProfileType.NONE),  # no profile: runs at the Velocity Limit
    ],
)
def test_profile_types(servo: VirtualServo, clock: ManualClock, pv: int, pa: int, goal: int, kind: int) -> None:
    servo.write(108, u32(pa) + u32(pv))
    servo.write(64, b"\x01")
    servo.write(116, u32(goal))
    clock.advance(0.01)
    assert servo.value("moving_status") & 0x30 == kind
    assert servo.value("moving") == 1
    clock.advance(3.0)
    assert (servo.value("present_position"), servo.value("moving")) == (goal, 0)


def test_step_moves_at_the_velocity_limit(servo: VirtualServo, clock: ManualClock) -> None:
    servo.write(64, b"\x01")
    servo.write(116, u32(3072))
    clock.advance(0.1)
    assert servo.value("present_velocity") == 200  # Velocity Limit default, just under the 46 rpm no-load speed
    clock.advance(1024 / (200 * V_UNIT) - 0.1 + 1e-6)
    assert servo.value("present_position") == 3072


def test_time_based_profile_arrives_at_the_set_time(servo: VirtualServo, clock: ManualClock) -> None:
    servo.write(10, b"\x04")  # Drive Mode: time-based profile
    servo.write(108, u32(200) + u32(1000))  # 200 ms ramps, 1000 ms move
    servo.write(64, b"\x01")
    servo.write(116, u32(1000))
    clock.advance(0.999)
    assert servo.value("moving") == 1
    clock.advance(0.002)
    assert (servo.value("present_position"), servo.value("moving")) == (1000, 0)


def test_new_goal_mid_move_keeps_position_and_velocity_continuous(servo: VirtualServo, clock: ManualClock) -> None:
    servo.write(108, u32(20) + u32(100))
    servo.write(64, b"\x01")
    servo.write(116, u32(3072))
    clock.advance(0.5)
    before = servo.state()
    servo.write(116, u32(2048))  # reverse while cruising at 100 units
    after = servo.state()
    assert after.position == pytest.approx(before.position)
    assert after.velocity == pytest.approx(before.velocity)
    # It brakes first, so it overshoots the switch point by v^2 / 2a before coming back.
    v, a = 100 * V_UNIT, 20 * A_UNIT
    clock.advance(v / a)
    assert servo.state().position == pytest.approx(before.position + v * v / (2 * a))
    assert servo.state().velocity == pytest.approx(0.0, abs=1e-6)
    clock.advance(3.0)
    assert (servo.value("present_position"), servo.value("moving")) == (2048, 0)


def test_torque_off_stops_and_torque_on_holds_where_it_is(servo: VirtualServo, clock: ManualClock) -> None:
    servo.write(64, b"\x01")
    servo.write(116, u32(3072))
    clock.advance(0.1)
    servo.write(64, b"\x00")
    stopped = servo.value("present_position")
    assert 2048 < stopped < 3072
    clock.advance(5.0)
    assert servo.value("present_position") == stopped
    servo.write(64, b"\x01")
    assert servo.value("goal_position") == stopped
    clock.advance(5.0)
    assert servo.value("present_position") == stopped


def test_steady_state_error_and_backlash(servo: VirtualServo, clock: ManualClock) -> None:
    servo.mechanics.steady_state_error_ticks = 6
    servo.mechanics.backlash_ticks = 10
    servo.write(64, b"\x01")
    servo.write(116, u32(3000))
    clock.advance(5.0)
    assert servo.value("present_position") == 2994
    assert servo.value("moving_status") & 0x01  # settled: in position as far as the servo can tell
    assert servo.physical_position_ticks() == pytest.approx(2994 - 5)
    servo.write(116, u32(1000))
    clock.advance(5.0)
    assert servo.value("present_position") == 1006
    assert servo.physical_position_ticks() == pytest.approx(1006 + 5)


def test_a_load_settles_within_its_encoder_count_the_same_way_for_the_same_goal(
    servo: VirtualServo, clock: ManualClock
) -> None:
    servo.mechanics.settle_ticks = 1.0
    servo.write(64, b"\x01")
    offsets = {}
    for goal in (3000, 1000, 2500, 1800, 3000, 1000):
        servo.write(116, u32(goal))
        clock.advance(5.0)
        assert servo.value("present_position") == goal  # the encoder cannot see where in the count it is
        off = servo.physical_position_ticks() - goal
        assert -0.5 <= off < 0.5
        assert offsets.setdefault(goal, off) == off  # the same goal, the same rest
    assert len(set(offsets.values())) == 4  # different goals, different rests
    servo.mechanics.settle_ticks = 0.0
    assert servo.physical_position_ticks() == 1000


def test_stalled_servo_never_arrives(servo: VirtualServo, clock: ManualClock) -> None:
    servo.faults.stall_short_ticks = 40
    servo.write(64, b"\x01")
    servo.write(116, u32(3072))
    clock.advance(60.0)
    assert servo.value("present_position") == 3072 - 40
    assert servo.value("present_velocity") == 0
    assert servo.value("moving") == 1
    status = servo.value("moving_status")
    assert status & 0x08 and not status & 0x01 and not status & 0x02


def test_overload_shuts_down_until_reboot(servo: VirtualServo, clock: ManualClock) -> None:
    servo.write(64, b"\x01")
    servo.write(116, u32(3072))
    clock.advance(0.2)
    assert servo.inject_hardware_error(HardwareError.OVERLOAD) == HardwareError.OVERLOAD
    stopped = servo.value("present_position")
    assert servo.value("hardware_error_status") == 0x20
    assert servo.value("torque_enable") == 0
    assert servo.status_error(ErrorNumber.NONE) == 0x80
    assert servo.write(64, b"\x01") == ErrorNumber.RESULT_FAIL
    clock.advance(5.0)
    assert servo.value("present_position") == stopped
    servo.reboot()
    assert (servo.value("hardware_error_status"), servo.status_error(ErrorNumber.NONE)) == (0, 0)
    assert servo.write(64, b"\x01") == ErrorNumber.NONE


def test_errors_outside_the_shutdown_mask_are_not_detected(servo: VirtualServo) -> None:
    assert servo.value("shutdown") == 52  # overheating, electrical shock, overload
    assert servo.inject_hardware_error(HardwareError.INPUT_VOLTAGE) == HardwareError(0)
    assert servo.value("hardware_error_status") == 0
    assert servo.inject_hardware_error(HardwareError.OVERHEATING | HardwareError.INPUT_VOLTAGE) == (
        HardwareError.OVERHEATING
    )
    assert servo.value("present_temperature") > servo.value("temperature_limit")


def test_reboot_resets_ram_keeps_eeprom_and_forgets_turns(servo: VirtualServo, clock: ManualClock) -> None:
    servo.write(11, b"\x04")  # extended position mode
    servo.write(9, b"\x00")  # Return Delay Time (EEPROM)
    servo.write(64, b"\x01\x01")  # torque + LED
    servo.write(68, b"\x01")
    servo.write(116, u32(4096 * 3 + 100))
    clock.advance(30.0)
    assert servo.value("present_position") == 4096 * 3 + 100
    servo.reboot()
    assert [servo.value(n) for n in ("torque_enable", "led", "status_return_level")] == [0, 0, 2]
    assert [servo.value(n) for n in ("operating_mode", "return_delay_time")] == [4, 0]
    assert servo.value("present_position") == 100


def test_factory_reset_options(clock: ManualClock) -> None:
    servo = VirtualServo(5, clock=clock, baudrate=1_000_000)
    servo.write(9, b"\x00")
    assert servo.factory_reset(0x02) == ErrorNumber.NONE
    assert (servo.id, servo.baudrate, servo.value("return_delay_time")) == (5, 1_000_000, 250)
    assert servo.factory_reset(0x01) == ErrorNumber.NONE
    assert (servo.id, servo.baudrate) == (5, 57_600)
    assert servo.factory_reset(0xFF) == ErrorNumber.NONE
    assert servo.id == 1
    assert servo.factory_reset(0x03) == ErrorNumber.DATA_RANGE


def test_clear_needs_magic_bytes_and_a_still_servo(servo: VirtualServo, clock: ManualClock) -> None:
    magic = bytes([0x01, 0x44, 0x58, 0x4C, 0x22])
    servo.write(11, b"\x04")
    servo.write(64, b"\x01")
    servo.write(116, u32(4096 * 2 + 7))
    clock.advance(0.1)
    assert servo.clear(magic) == ErrorNumber.RESULT_FAIL
    clock.advance(30.0)
    assert servo.clear(magic[:4] + b"\x00") == ErrorNumber.DATA_RANGE
    assert servo.clear(magic) == ErrorNumber.NONE
    assert servo.value("present_position") == 7


def test_python_side_errors_name_the_problem(servo: VirtualServo) -> None:
    with pytest.raises(ValueError, match="present_position"):
        servo.poke("present_position", 5)
    with pytest.raises(ValueError, match="return_delay_time = 300"):
        servo.poke("return_delay_time", 300)
    servo.poke("torque_enable", 1)
    with pytest.raises(RuntimeError, match="torque is on"):
        servo.place(100)


# --- the planner on its own -------------------------------------------------------------------------------

positions = st.floats(-1e5, 1e5, allow_nan=False)
speeds = st.floats(1.0, 5000.0)


@given(positions, st.floats(-5000.0, 5000.0), positions, speeds, st.floats(10.0, 1e5))
def test_plan_reaches_target_at_rest_within_limits(x0: float, v0: float, target: float, vmax: float, a: float) -> None:
    p = plan(x0, v0, target, vmax, a)
    assert p.at(p.duration + 1e-9)[:2] == (target, 0.0)
    prev_x, prev_v = x0, v0
    for seg in p.segments:
        x, v = seg.x0, seg.v0
        assert x == pytest.approx(prev_x, abs=1e-6 * (1 + abs(x)))  # continuous position
        assert v == pytest.approx(prev_v, abs=1e-6 * (1 + abs(v)))  # continuous velocity
        assert abs(seg.a) <= a * (1 + 1e-12)
        prev_x, prev_v = seg.end
        assert abs(prev_v) <= max(vmax, abs(v0)) * (1 + 1e-9)
    assert prev_x == pytest.approx(target, abs=1e-6 * (1 + abs(target)))
    # Segment durations are differences of absolute times, rounded to ~eps * t; times a, that is velocity.
    rounding = a * 1e-14 * (1.0 + p.duration)
    assert prev_v == pytest.approx(0.0, abs=1e-6 * max(1.0, vmax) + rounding)


@given(st.floats(1.0, 1e5), speeds, st.floats(10.0, 1e5))
def test_plan_from_rest_takes_the_minimum_time(distance: float, vmax: float, a: float) -> None:
    p = plan(0.0, 0.0, distance, vmax, a)
    if distance >= vmax * vmax / a:
        expected = vmax / a + distance / vmax
    else:
        expected = 2 * math.sqrt(distance / a)
    assert p.duration == pytest.approx(expected, rel=1e-9)


def test_plan_refuses_nonsense_limits() -> None:
    with pytest.raises(ValueError, match="v_max"):
        plan(0, 0, 10, 0.0, 1.0)
    with pytest.raises(ValueError, match="a_max"):
        plan(0, 0, 10, 1.0, -1.0)
