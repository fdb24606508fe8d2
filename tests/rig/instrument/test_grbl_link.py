"""GrblLink (pyserial) against the virtual GRBL on a pty; link and controller share a ManualClock.

One file past 400 lines on purpose: it mirrors one module, ``rig.instrument.links.grbl``.
"""

from __future__ import annotations

import os
import threading
import time
import tty

import pytest

from rig.instrument.axis import Axis, AxisLimitError
from rig.instrument.clock import ManualClock
from rig.instrument.links.base import LinkError, MotionLink, MoveTimeout
from rig.instrument.links.grbl import GrblLink
from rig.instrument.links.grbl_protocol import (
    GrblAbortAlarm,
    GrblCommandError,
    GrblConnectError,
    GrblError,
    GrblHomingAlarm,
    GrblLimitAlarm,
    GrblLockedError,
    GrblResetError,
    GrblTimeoutError,
    parse_status,
)
from simulator.grbl.server import open_virtual_grbl


def make_axes(**light):
    """Light arm on X (geared 3:1, reversed, 10 steps per motor degree) and camera arm on Y (direct)."""
    options = dict(units_per_degree=10.0, gear_ratio=3.0, direction=-1, zero_offset_deg=0.0)
    options.update(light)
    return [
        Axis("light", "X", max_speed_deg_s=20.0, max_accel_deg_s2=40.0, tolerance_deg=0.05, **options),
        Axis("camera", "Y", units_per_degree=10.0, max_speed_deg_s=45.0, max_accel_deg_s2=90.0, tolerance_deg=0.05),
    ]


def connect(sim, clock, axes=None, **kwargs):
    kwargs.setdefault("poll_interval_s", 0.05)
    kwargs.setdefault("configure", True)
    return GrblLink(sim.port, axes or make_axes(), clock=clock, **kwargs)


@pytest.fixture
def clock():
    return ManualClock()


@pytest.fixture
def sim(clock):
    with open_virtual_grbl(clock) as server:
        yield server


@pytest.fixture
def link(sim, clock):
    with connect(sim, clock) as lk:
        yield lk


def test_satisfies_motion_link_and_handshakes(link, sim):
    assert isinstance(link, MotionLink)
    assert link.session.version == "1.1h"
    assert link.session.rx_buffer_bytes == 128
    # configure=True wrote steps per motor degree, motor degrees/min and motor degrees/s^2 from the axes.
    s = sim.controller.settings
    assert (s[100], s[110], s[120]) == (10.0, 20.0 * 3 * 60, 40.0 * 3)
    assert (s[101], s[111], s[121]) == (10.0, 45.0 * 60, 90.0)
    assert link.configure_axes() == {}  # nothing differs now: no EEPROM writes


def test_move_reaches_target_in_joint_degrees(link, sim, clock):
    start = clock.now()
    link.move_to({"light": 30.0, "camera": -45.0})
    positions = link.wait_in_position(timeout_s=30.0)
    assert positions == pytest.approx({"light": 30.0, "camera": -45.0}, abs=0.05)
    # G-code coordinate = direction * joint * gear: the controller's X sits at -90 motor degrees.
    assert sim.controller.mpos == {"X": -90.0, "Y": -45.0, "Z": 0.0}
    assert link.read_positions() == pytest.approx(positions)
    # The light arm paces the coordinated move: 90 motor deg at 60 deg/s with 120 deg/s^2 is a trapezoid of
    # 90/60 + 60/120 = 2.0 s; the link sees it end at the next 50 ms poll.
    assert 2.0 <= clock.now() - start <= 2.0 + 0.05 + 1e-9


def test_reset_on_connect_and_a_second_link_on_the_same_port(sim, clock):
    with connect(sim, clock, reset_on_connect=True) as first:
        first.move_to({"camera": -10.0})
        first.wait_in_position(10.0)
    with connect(sim, clock) as second:  # reopening resets GRBL like an Arduino: position report back to 0
        assert second.read_positions()["camera"] == 0.0


def test_out_of_range_target_is_refused_before_anything_is_sent(link, sim):
    sent = sim.controller.lines_received
    with pytest.raises(AxisLimitError, match="light"):
        link.move_to({"light": 500.0})
    with pytest.raises(AxisLimitError):
        link.queue_moves([{"camera": 10.0}, {"camera": float("nan")}])  # the whole sweep is checked first
    with pytest.raises(LinkError, match="unknown axis 'tilt'"):
        link.move_to({"tilt": 1.0})
    assert sim.controller.lines_received == sent
    assert sim.controller.planner_blocks == 0


def test_streams_a_long_sweep_without_overflowing_grbl_buffer(link, sim, clock):
    poses = [{"light": float(i % 9), "camera": -float(i % 13)} for i in range(80)]  # ~2.5 kB of G-code
    link.queue_moves(poses)
    positions = link.wait_in_position(timeout_s=300.0)
    assert positions == pytest.approx(poses[-1], abs=0.05)
    assert sim.controller.rx_dropped == 0
    assert sim.controller.lines_received >= 80
    assert 90 < sim.controller.rx_peak <= 127  # the link kept GRBL's buffer nearly full, never over


def test_settings_round_trip(link):
    link.session.write_settings({24: 100.0, 27: 2.5, 110: 1234.5})
    values = link.session.settings()
    assert (values[24], values[27], values[110]) == (100.0, 2.5, 1234.5)


LINK_ERRORS = [
    ("G5", 20),
    ("G1.5 X1", 23),
    ("G0 X1 X2", 25),
    ("G4", 28),
    ("G80 X1", 31),
    ("G0 X1 R2", 36),
    ("$Q", 2),
    ("$XX", 3),
    ("$100=-1", 4),
    ("$H", 5),
    ("$0=1", 6),
    ("$20=1", 10),
    ("$100=1000000", 12),
    ("$J=G91 X1", 22),
    ("$J=G1 X1 F10", 16),
]


@pytest.mark.parametrize(("line", "code"), LINK_ERRORS)
def test_every_error_code_becomes_a_specific_exception(link, line, code):
    with pytest.raises(GrblCommandError) as info:
        link.session.command(line)
    assert info.value.code == code
    assert info.value.line == line
    assert f"error:{code}" in str(info.value) and info.value.meaning.split(":")[0] in str(info.value)
    link.move_to({"camera": -1.0})  # the stream is still in step afterwards
    link.wait_in_position(5.0)


def test_undefined_feed_rate_after_a_reset(link):
    link.reset()
    with pytest.raises(GrblCommandError) as info:
        link.session.command("G1 X-1")
    assert info.value.code == 22


def test_not_idle_error_while_moving(link):
    link.move_to({"light": 40.0})
    with pytest.raises(GrblCommandError) as info:
        link.session.command("$$")
    assert info.value.code == 8


def test_homing_lock_then_home(clock):
    with open_virtual_grbl(clock, settings={22: 1, 20: 1}, start_position={"X": -60.0, "Y": -20.0}) as sim:
        # Homed frame: the switch is at 0 and the light travels on negative motor degrees.
        with connect(sim, clock, make_axes(min_deg=0.0, max_deg=60.0)) as link:
            assert link.status().state == "Alarm"
            with pytest.raises(GrblLockedError, match="G-code lock"):
                link.move_to({"light": 10.0})
            link.home(timeout_s=60.0)
            assert link.status().state == "Idle"
            assert sim.controller.mpos["X"] == -1.0  # pulled off the switch by $27
            link.move_to({"light": 20.0, "camera": -30.0})
            assert link.wait_in_position(10.0) == pytest.approx({"light": 20.0, "camera": -30.0}, abs=0.05)


def test_unlock_clears_the_homing_lock(clock):
    with open_virtual_grbl(clock, settings={22: 1}) as sim:
        with connect(sim, clock) as link:
            link.unlock()
            assert link.status().state == "Idle"
            assert "Caution: Unlocked" in link.session.messages


@pytest.mark.parametrize("code", [8, 9])
def test_homing_failure_raises_and_leaves_alarm(clock, code):
    with open_virtual_grbl(clock, settings={22: 1}) as sim:
        with connect(sim, clock) as link:
            sim.controller.fail_next_homing(code)
            with pytest.raises(GrblHomingAlarm) as info:
                link.home(timeout_s=60.0)
            assert info.value.code == code and info.value.position_lost
            assert "homing fail" in str(info.value)
            assert link.status().state == "Alarm"  # GRBL reset itself; the link expected that banner
            link.unlock()
            link.move_to({"camera": -5.0})
            link.wait_in_position(5.0)


def test_homing_disabled_is_error_5(link):
    with pytest.raises(GrblCommandError) as info:
        link.home()
    assert info.value.code == 5


def test_hard_limit_alarm_needs_reset(clock):
    with open_virtual_grbl(clock, settings={21: 1}) as sim:
        with connect(sim, clock) as link:
            link.move_to({"light": 50.0})
            sim.controller.trip_hard_limit(after_s=1.0)
            with pytest.raises(GrblLimitAlarm) as info:
                link.wait_in_position(30.0)
            assert info.value.code == 1 and info.value.needs_reset and link.position_lost
            assert info.value.line.startswith("G90 G53 G1 X-150")
            with pytest.raises(GrblError, match="halted"):
                link.move_to({"light": 0.0})
            assert link.reset().state == "Alarm"
            link.unlock()
            link.move_to({"light": 0.0})
            assert link.wait_in_position(30.0)["light"] == pytest.approx(0.0, abs=0.05)


def test_soft_limit_alarm_names_the_line(clock):
    with open_virtual_grbl(clock, settings={22: 1, 20: 1, 130: 90.0}) as sim:
        with connect(sim, clock) as link:
            link.unlock()
            # The Axis allows 40 degrees (120 motor degrees) but GRBL's X travel is only 90 motor degrees.
            with pytest.raises(GrblLimitAlarm) as info:
                link.move_to({"light": 40.0})
            assert info.value.code == 2 and not info.value.position_lost
            assert "X-120" in info.value.line and "exceeds the machine travel" in str(info.value)
            link.reset()
            link.unlock()
            link.move_to({"light": 20.0})
            link.wait_in_position(10.0)


def test_feed_hold_and_resume(link, clock):
    link.move_to({"camera": -90.0})
    clock.advance(0.5)
    link.feed_hold()
    link.session.wait_for(lambda: link.session.last_status.state == "Hold", 5.0, "hold", fresh=True)
    link.session.wait_for(lambda: not link.session.last_status.moving, 5.0, "stop", fresh=True)
    held = link.read_positions()["camera"]
    clock.advance(10.0)
    assert link.read_positions()["camera"] == held
    link.resume()
    assert link.wait_in_position(10.0)["camera"] == pytest.approx(-90.0, abs=0.05)


def test_stop_during_motion_keeps_position(link, sim, clock):
    link.queue_moves([{"light": 50.0}, {"light": 0.0}, {"light": 30.0}])
    link.session.wait_acknowledged()  # all three are in GRBL's planner before the clock moves
    clock.advance(1.0)
    link.stop()
    status = link.status()
    assert status.state == "Idle" and not link.position_lost
    assert 0.0 < link.read_positions()["light"] < 50.0
    assert sim.controller.planner_blocks == 0  # the queued moves are gone
    link.move_to({"light": 5.0})
    assert link.wait_in_position(10.0)["light"] == pytest.approx(5.0, abs=0.05)


def test_stop_that_cannot_hold_resets_in_motion_and_loses_position(sim, clock):
    with connect(sim, clock, stop_timeout_s=1.0) as link:
        link.move_to({"light": 50.0})
        clock.advance(0.5)
        sim.controller.stall()  # frozen in Run: the feed hold never completes
        link.stop()
        assert link.last_alarm == 3 and link.position_lost
        assert link.status().state == "Alarm"
        with pytest.raises(GrblLockedError):
            link.move_to({"light": 0.0})
        link.unlock()


def test_stalled_axis_times_out_with_positions(link, sim, clock):
    link.move_to({"light": 50.0, "camera": -20.0})
    clock.advance(0.5)
    sim.controller.stall()
    with pytest.raises(MoveTimeout) as info:
        link.wait_in_position(timeout_s=5.0)
    positions = info.value.positions_deg
    assert set(positions) == {"light", "camera"}
    assert 0.0 < positions["light"] < 50.0
    assert "state Run" in str(info.value) and "light" in str(info.value)
    link.stop()  # GRBL is reset in motion: ALARM:3 absorbed by stop()
    assert link.position_lost


def test_dropped_status_replies_are_retried(sim, clock):
    with connect(sim, clock, reply_timeout_s=0.05, status_retries=2) as link:
        sim.controller.drop_status_reports(2)
        assert link.read_positions() == {"light": 0.0, "camera": 0.0}
        sim.controller.drop_status_reports(3)
        with pytest.raises(GrblTimeoutError, match="no status report"):
            link.read_positions()
        assert link.read_positions() == {"light": 0.0, "camera": 0.0}


def test_unexpected_reset_is_reported(link, sim):
    sim.controller.receive(b"\x18")  # as if someone else reset the controller
    with pytest.raises(GrblResetError, match="reset unexpectedly"):
        link.read_positions()
    link.move_to({"camera": -3.0})  # the link re-reads the position and modal state afterwards
    link.wait_in_position(5.0)


def test_reset_during_motion_is_alarm_3(link, sim, clock):
    link.move_to({"light": 50.0})
    clock.advance(0.5)
    assert link.reset().state == "Alarm"
    assert link.last_alarm == 3 and link.position_lost
    with pytest.raises(GrblAbortAlarm):
        link.wait_in_position(1.0)


def test_work_position_reports_are_converted(sim, clock):
    sim.controller.settings.store(10, 0)  # WPos + WCO instead of MPos
    with connect(sim, clock) as link:
        link.move_to({"camera": -12.0})
        assert link.wait_in_position(10.0)["camera"] == pytest.approx(-12.0, abs=0.05)


def test_shutdown_stops_motion_and_is_idempotent(sim, clock):
    link = connect(sim, clock)
    link.move_to({"light": 50.0})
    clock.advance(0.5)
    link.shutdown()
    link.shutdown()
    assert sim.controller.state == "Idle"
    with pytest.raises(LinkError, match="shut down"):
        link.move_to({"light": 1.0})
    link.stop()  # harmless once closed


def test_missing_port_names_it():
    with pytest.raises(GrblConnectError, match="/dev/does-not-exist"):
        GrblLink("/dev/does-not-exist", make_axes(), clock=ManualClock())


def test_silent_pty_times_out_quickly():
    master, slave = os.openpty()
    tty.setraw(slave)
    port = os.ttyname(slave)
    try:
        started = time.monotonic()
        with pytest.raises(GrblConnectError, match=f"no GRBL banner on {port}.*nothing received"):
            GrblLink(port, make_axes(), clock=ManualClock(), banner_timeout_s=0.2)
        assert time.monotonic() - started < 2.0
    finally:
        os.close(slave)
        os.close(master)


def test_port_that_is_not_grbl():
    master, slave = os.openpty()
    tty.setraw(slave)
    port = os.ttyname(slave)
    done = threading.Event()

    def chatter():
        # Something else on the port: answers every byte with a line that is not GRBL's.
        while not done.is_set():
            try:
                if os.read(master, 64):
                    os.write(master, b"echo: Marlin 2.1 ready\r\n")
            except OSError:
                return

    os.set_blocking(master, True)
    thread = threading.Thread(target=chatter, daemon=True)
    thread.start()
    try:
        with pytest.raises(GrblConnectError, match=r"Marlin.*is this a GRBL controller"):
            GrblLink(port, make_axes(), clock=ManualClock(), banner_timeout_s=0.3)
    finally:
        done.set()
        os.close(slave)
        os.write(master, b"")
        os.close(master)
        thread.join(timeout=1.0)


def test_axis_addresses_are_checked():
    with pytest.raises(ValueError, match="not a GRBL axis letter"):
        GrblLink("/dev/null", [Axis("tilt", 3, units_per_degree=1.0)])
    with pytest.raises(ValueError, match="used twice"):
        GrblLink("/dev/null", [Axis("a", "X", units_per_degree=1.0), Axis("b", "X", units_per_degree=1.0)])


def test_status_parsing():
    st = parse_status("<Hold:0|WPos:1.000,-2.500,0.000|Bf:15,128|FS:0,0|WCO:10.000,0.000,0.000|Ov:100,100,100>")
    assert (st.state, st.substate, st.moving) == ("Hold", 0, False)
    assert st.machine_position(None) == (11.0, -2.5, 0.0)
    assert st.fields["Bf"] == "15,128"
    st = parse_status("<Run|MPos:-1.000,2.000,3.000|FS:500,0>")
    assert st.moving and st.feed == 500.0 and st.machine_position(None) == (-1.0, 2.0, 3.0)
    assert parse_status("<Door:2|MPos:0,0,0|FS:0,0>").moving
    for bad in ("Idle|MPos:0,0,0", "<Idle|FS:0,0>", "<Idle|MPos:a,b>", "<Idle|junk>"):
        with pytest.raises(ValueError):
            parse_status(bad)


def _physical(sim):
    """Where the virtual axes really stand (units): the report plus what a power-up zeroed."""
    c = sim.controller
    return {a: c.mpos[a] + c._offset[i] for i, a in enumerate(c.axes)}


def test_a_run_link_homes_so_a_reconnect_never_measures_at_the_wrong_angles(clock):
    axes = make_axes(min_deg=0.0, max_deg=60.0)
    with open_virtual_grbl(clock, settings={22: 1, 20: 1}, start_position={"X": -60.0, "Y": -20.0}) as sim:
        with connect(sim, clock, axes, require_home=True) as link:
            link.move_to({"light": 20.0, "camera": -30.0})  # homes first: the port was just opened
            link.wait_in_position(10.0)
            first = _physical(sim)
        # Reopening the port resets GRBL: it reports 0 wherever the axes stand. The next run homes again.
        with connect(sim, clock, axes, require_home=True) as link:
            link.move_to({"light": 20.0, "camera": -30.0})
            held = link.wait_in_position(10.0)
            assert held == pytest.approx({"light": 20.0, "camera": -30.0}, abs=0.05)
            assert _physical(sim) == pytest.approx(first, abs=1e-6)  # the same place, not an offset one


def test_without_homing_a_run_link_refuses_to_move_saying_why(clock):
    with open_virtual_grbl(clock) as sim:
        with connect(sim, clock, require_home=True) as link:
            with pytest.raises(GrblError, match=r"position is not known .*homing is disabled \(\$22=0\)"):
                link.move_to({"camera": -5.0})
            assert sim.controller.mpos == {"X": 0.0, "Y": 0.0, "Z": 0.0}  # nothing moved


def test_a_late_status_report_is_never_taken_for_a_later_one(sim, clock):
    # The controller answers one '?' only when asked again (a busy line): the link takes the late report, and
    # the one that answers the repeated '?' arrives after it. It must not pass for the next report, taken later.
    with connect(sim, clock, reply_timeout_s=0.2) as link:
        link.move_to({"camera": 60.0})
        sim.controller.delay_status_reports(1)
        link.status()
        clock.advance(0.5)
        moving = link.status()
        assert moving.state == "Run"
        assert moving.machine_position(None)[1] == pytest.approx(sim.controller.mpos["Y"], abs=1e-3)
        assert link.wait_in_position(30.0)["camera"] == pytest.approx(60.0, abs=0.05)


def test_a_lost_ok_of_a_move_is_recovered_by_checking_the_axes_reached_the_target(link, sim, clock):
    # A noisy line loses GRBL's 'ok' of a move it executed: the link must neither wait out command_timeout_s nor
    # count the line in flight forever (no move would ever be in position again).
    sim.controller.drop_acknowledgements(1)
    start = clock.now()
    link.move_to({"light": 10.0, "camera": -20.0})
    assert link.wait_in_position(timeout_s=30.0) == pytest.approx({"light": 10.0, "camera": -20.0}, abs=0.05)
    assert link.session.replies_lost == 1 and link.session.in_flight == 0
    assert clock.now() - start < 0.25 * link.session.command_timeout_s  # noticed within a few polls once Idle
    link.move_to({"light": 5.0})  # and the next move is counted as usual
    assert link.wait_in_position(timeout_s=30.0)["light"] == pytest.approx(5.0, abs=0.05)


def test_a_command_whose_ok_is_lost_is_sent_again_a_bounded_number_of_times(link, sim):
    sim.controller.drop_acknowledgements(2)
    assert link.session.settings()[100] == 10.0  # '$$' sent three times, answered the third
    assert link.session.replies_lost == 2
    sim.controller.drop_acknowledgements(10)
    with pytest.raises(GrblTimeoutError, match=r"no reply to '\$\$' .*4 times.*losing replies"):
        link.session.settings()
    sim.controller.drop_acknowledgements(0)


def test_homing_whose_ok_is_lost_is_done_once_grbl_is_idle(clock):
    with open_virtual_grbl(clock, settings={22: 1}, start_position={"X": -60.0, "Y": -20.0}) as sim:
        with connect(sim, clock, require_home=True) as link:
            sim.controller.drop_acknowledgements(1)
            link.home(timeout_s=60.0)  # a failed homing leaves Alarm, never Idle: Idle means it was done
            assert link.status().state == "Idle" and sim.controller.mpos["X"] == -1.0
            assert link.session.replies_lost == 1


def test_a_garbled_state_is_no_state():
    # A corrupted byte in 'Run' must not read as some other state (stop() would reset in motion, thinking it still).
    for bad in ("<R\ufffdn|MPos:0,0,0|FS:0,0>", "<Idl|MPos:0,0,0|FS:0,0>"):
        with pytest.raises(ValueError, match="state"):
            parse_status(bad)
