"""The virtual GRBL 1.1's motion, driven byte by byte through pyserial (no link code involved): trapezoids,
coordinated moves, the planner, homing, hard and soft limits, holds, resets, jogs and the safety door.
"""

from __future__ import annotations

import numpy as np
import pytest

from rig.instrument.clock import ManualClock
from simulator.grbl.server import GrblPtyServer, open_virtual_grbl
from tests.simulator.grbl.grbl_client import BANNER, Client


def test_move_is_trapezoidal_and_ends_idle_at_target(grbl, clock):
    client, _ = grbl
    # 10 units at 300 units/min (5/s) with 10 units/s^2: 0.5 s ramps of 1.25 units and a 1.5 s cruise.
    assert client.send("G1 X10 F300") == ["ok"]
    start = clock.now()
    clock.advance(0.5)
    assert client.mpos()[0] == pytest.approx(1.25, abs=0.004)  # 250 steps/unit
    clock.advance(0.5)
    assert client.mpos()[0] == pytest.approx(3.75, abs=0.004)
    clock.advance(1.48)
    assert client.state() == "Run"
    clock.advance(0.03)
    assert client.state() == "Idle"
    assert clock.now() - start == pytest.approx(2.51)
    assert client.mpos() == (10.0, 0.0, 0.0)


def test_feed_is_capped_by_the_max_rate(grbl, clock):
    client, _ = grbl
    client.send("G1 X100 F6000")  # asks 100/s; $110 = 500 units/min
    clock.advance(1.5)
    assert client.query().split("|")[2] == "FS:500,0"


def test_multi_axis_move_is_coordinated(grbl, clock):
    client, _ = grbl
    client.send("$111=60")  # Y is the slow axis: 1 unit/s
    assert client.send("G0 X-10 Y-5") == ["ok"]
    for _ in range(5):
        clock.advance(1.0)
        x, y, _ = client.mpos()
        assert x == pytest.approx(2 * y, abs=0.01)  # on the straight line, so both arrive together
    client.run_until(lambda r: r.startswith("<Idle"), step_s=0.5)
    assert clock.now() == pytest.approx(6.0, abs=0.6)  # Y at 1 unit/s (plus ramps) sets the pace
    assert client.mpos() == (-10.0, -5.0, 0.0)


def test_rapid_uses_max_rate_and_relative_inch_moves(grbl, clock):
    client, _ = grbl
    client.send("$110=6000")
    client.send("$120=1000")
    assert client.send("G0 X-50") == ["ok"]
    client.run_until(lambda r: r.startswith("<Idle"), step_s=0.05)
    assert client.mpos()[0] == -50.0
    assert client.send("G20 G91 G0 X1") == ["ok"]  # one inch further, relative
    client.run_until(lambda r: r.startswith("<Idle"))
    assert client.mpos()[0] == pytest.approx(-24.6)


def test_positions_are_quantised_to_steps(grbl, clock):
    client, _ = grbl
    client.send("$100=3")  # 3 steps per unit: a target of 1.2 lands on step 4
    client.send("G0 X1.2")
    client.run_until(lambda r: r.startswith("<Idle"))
    assert client.mpos()[0] == 1.333


def test_the_load_glides_between_the_whole_steps_the_report_counts(grbl: tuple[Client, GrblPtyServer],
                                                                   clock: ManualClock) -> None:
    """During a G1 the axis moves at the commanded feed between polls of the clock, though the report jumps by steps."""
    client, sim = grbl
    client.send("$100=3")  # a third of a unit per step: a short look sees no step go by
    client.send("G1 X4 F60")  # 1 unit/s, cruising after a 0.1 s ramp (10 units/s^2) that falls 0.05 units behind
    clock.advance(1.0)
    x = client.mpos()[0]
    assert client.state() == "Run" and x * 3 == pytest.approx(round(x * 3))  # whole steps in the report
    glide = []
    for _ in range(5):
        glide.append(sim.controller.physical_position["X"])
        clock.advance(0.002)
    assert client.mpos()[0] == x  # no step reported within the look
    assert glide[0] == pytest.approx(0.95, abs=1e-9)  # 1 s at 1 unit/s less the ramp
    assert list(np.diff(glide)) == pytest.approx([0.002] * 4)  # the feed, 60 units/min, at every instant
    client.run_until(lambda r: r.startswith("<Idle"))
    assert client.mpos()[0] == sim.controller.physical_position["X"] == 4.0  # at rest on its whole step


def test_status_fields_buffer_work_position_and_inches(grbl):
    client, _ = grbl
    client.query(), client.query()  # the first reports after a reset carry WCO, then Ov
    client.send("$10=3")
    assert client.query() == "<Idle|MPos:0.000,0.000,0.000|Bf:15,128|FS:0,0>"
    client.send("$10=0")
    reports = [client.query() for _ in range(10)]
    assert all("WPos:0.000,0.000,0.000" in r for r in reports)
    assert sum("WCO:0.000,0.000,0.000" in r for r in reports) == 1
    client.send("$10=1")
    client.send("$13=1")
    client.send("G1 X25.4 F100000")
    client.run_until(lambda r: r.startswith("<Idle"))
    assert "MPos:1.0000,0.0000,0.0000" in client.query()


def test_dwell_answers_after_its_time(grbl, clock):
    client, _ = grbl
    client.ser.write(b"G4 P1.5\n")
    client.query()  # the line is in before the clock moves
    clock.advance(1.4)
    assert client.query().startswith("<Idle")
    assert client.other == []  # no ok yet
    clock.advance(0.2)
    client.query()
    assert client.other == ["ok"]


def test_planner_holds_15_blocks_and_delays_the_16th_ok(grbl, clock):
    client, sim = grbl
    client.send("$120=1000")
    for i in range(15):
        assert client.send(f"G1 X{-i - 1} F60000") == ["ok"]
    client.ser.write(b"G1 X-20 F60000\n?")
    assert client.read_until(lambda s: s.startswith("<"))[0].startswith("<Run")  # no ok: planner full
    assert sim.controller.planner_blocks == 15
    while "ok" not in client.other:
        clock.advance(0.01)
        client.query()
    client.run_until(lambda r: r.startswith("<Idle"), step_s=0.01)
    assert client.mpos()[0] == -20.0


def test_homing_enabled_starts_locked_and_unlocks(clock):
    with open_virtual_grbl(clock, settings={22: 1}) as sim:
        client = Client(sim.port, clock)
        assert client.readline() == "[MSG:'$H'|'$X' to unlock]"
        assert client.state() == "Alarm"
        assert client.send("G0 X-1") == ["error:9"]
        assert client.send("$X") == ["[MSG:Caution: Unlocked]", "ok"]
        assert client.state() == "Idle"
        assert client.send("$X") == ["ok"]  # no effect out of Alarm
        client.close()


def test_homing_cycle_travels_to_the_switch_and_pulls_off(clock):
    with open_virtual_grbl(clock, settings={22: 1, 20: 1}, start_position={"X": -40.0, "Z": -5.0}) as sim:
        client = Client(sim.port, clock)
        client.readline()
        client.ser.write(b"$H\n")
        assert client.state() == "Home"
        clock.advance(1.0)
        x = client.mpos()[0]
        assert 0 < x < 40  # reported position started at 0 (power-up) and moves toward the switch
        report = client.run_until(lambda r: not r.startswith("<Home"))
        assert report.startswith("<Idle|MPos:-1.000,-1.000,-1.000")
        assert client.other == ["ok"]
        assert client.send("G0 X-100") == ["ok"]  # inside [-200, 0]
        client.close()


@pytest.mark.parametrize("alarm", [8, 9])
def test_homing_failure_alarms_then_resets_into_alarm(clock, alarm):
    with open_virtual_grbl(clock, settings={22: 1}) as sim:
        client = Client(sim.port, clock)
        client.readline()
        sim.controller.fail_next_homing(alarm)
        client.ser.write(b"$H\n")
        lines = []
        while BANNER not in lines:
            clock.advance(0.1)
            client.ser.write(b"?")
            lines += client.read_until(lambda s: s.startswith("<") or s == BANNER)
        tail = [s for s in lines if not s.startswith("<")]
        assert tail == [f"ALARM:{alarm}", "ok", "", BANNER]
        assert client.readline() == "[MSG:'$H'|'$X' to unlock]"
        assert client.state() == "Alarm"
        client.close()


def test_hard_limit_is_critical_until_reset(clock):
    with open_virtual_grbl(clock, settings={21: 1}) as sim:
        client = Client(sim.port, clock)
        client.send("G1 X-30 F600")
        sim.controller.trip_hard_limit(after_s=0.5)
        clock.advance(0.6)
        assert client.query().startswith("<Alarm")
        assert client.other == ["ALARM:1", "[MSG:Reset to continue]"]
        stopped = client.mpos()
        clock.advance(1.0)
        assert client.mpos() == stopped  # killed on the spot
        client.ser.write(b"$X\n")  # ignored: only reset works now
        assert client.state() == "Alarm"
        client.ser.write(b"\x18")
        assert client.read_until(lambda s: s == BANNER)[-2:] == ["", BANNER]
        assert client.readline() == "[MSG:'$H'|'$X' to unlock]"
        assert client.send("$X")[-1] == "ok"
        client.close()


def test_hard_limit_ignored_when_disabled(grbl, clock):
    client, sim = grbl
    client.send("G1 X-3 F600")
    sim.controller.trip_hard_limit(after_s=0.1)
    client.run_until(lambda r: r.startswith("<Idle"))
    assert client.mpos()[0] == -3.0


def test_soft_limit_decelerates_then_alarms(clock):
    with open_virtual_grbl(clock, settings={22: 1, 20: 1}) as sim:
        client = Client(sim.port, clock)
        client.readline()
        client.send("$X")
        client.send("G1 X-20 F600")
        clock.advance(1.0)
        client.ser.write(b"G1 X10\n?")  # beyond 0: out of [-200, 0]
        assert client.read_until(lambda s: s.startswith("<"))[-1].startswith("<Hold:1")
        report = client.run_until(lambda r: "Alarm" in r, step_s=0.1)
        assert report.startswith("<Alarm")
        x = client.mpos()[0]
        assert -20 < x < -5  # stopped under control, well short of the first target
        assert client.other[-2:] == ["ALARM:2", "[MSG:Reset to continue]"]
        client.ser.write(b"\x18")
        assert client.read_until(lambda s: s == BANNER) == ["ok", "", BANNER]  # the refused line returns first
        client.close()


def test_soft_limit_when_idle_alarms_at_once_and_jog_is_refused(clock):
    with open_virtual_grbl(clock, settings={22: 1, 20: 1}) as sim:
        client = Client(sim.port, clock)
        client.readline()
        client.send("$X")
        assert client.send("$J=G91 X1 F100") == ["error:15"]
        client.ser.write(b"G0 Y-250\n")
        assert client.read_until(lambda s: s.startswith("[MSG"))[-2:] == ["ALARM:2", "[MSG:Reset to continue]"]
        assert sim.controller.last_alarm == 2
        client.close()


def test_feed_hold_and_cycle_start(grbl, clock):
    client, sim = grbl
    client.send("G1 X-10 F600")
    clock.advance(0.5)
    client.ser.write(b"!")
    assert client.state() == "Hold:1"
    client.ser.write(b"G0 Y-1\n")  # the main loop is suspended: this line waits in the buffer
    report = client.run_until(lambda r: r.startswith("<Hold:0"), step_s=0.05)
    held = client.mpos()
    clock.advance(5.0)
    assert client.mpos() == held and client.other == []
    assert sim.controller.lines_received == 1
    client.ser.write(b"~")
    client.run_until(lambda r: r.startswith("<Idle"))
    assert client.mpos() == (-10.0, -1.0, 0.0)
    assert report.startswith("<Hold:0")


def test_reset_during_motion_raises_alarm_3_and_keeps_position(grbl, clock):
    client, _ = grbl
    client.send("G1 X-10 F600")
    clock.advance(1.0)
    before = client.mpos()
    client.ser.write(b"\x18")
    lines = client.read_until(lambda s: s == BANNER)
    assert lines == ["ALARM:3", "", BANNER]
    assert client.readline() == "[MSG:'$H'|'$X' to unlock]"
    assert client.state() == "Alarm"
    assert client.mpos() == before  # GRBL keeps its step count; it just no longer trusts it


def test_reset_after_a_completed_hold_keeps_position_without_alarm(grbl, clock):
    client, _ = grbl
    client.send("G1 X-10 F600")
    clock.advance(1.0)
    client.ser.write(b"!")
    client.run_until(lambda r: r.startswith("<Hold:0"))
    client.ser.write(b"\x18")
    assert client.read_until(lambda s: s == BANNER) == ["", BANNER]
    assert client.state() == "Idle"
    assert -10 < client.mpos()[0] < 0


def test_reset_during_homing_is_alarm_6(clock):
    with open_virtual_grbl(clock, settings={22: 1}, start_position={"X": -50}) as sim:
        client = Client(sim.port, clock)
        client.readline()
        client.ser.write(b"$H\n")
        assert client.state() == "Home"
        clock.advance(1.0)
        client.ser.write(b"\x18")
        assert client.read_until(lambda s: s == BANNER) == ["ALARM:6", "ok", "", BANNER]
        client.close()


def test_jog_and_jog_cancel(grbl, clock):
    client, _ = grbl
    assert client.send("$J=G91 X-20 F600") == ["ok"]
    assert client.state() == "Jog"
    assert client.send("G0 X1") == ["error:9"]
    clock.advance(1.0)
    client.ser.write(b"\x85")
    client.run_until(lambda r: r.startswith("<Idle"))
    x = client.mpos()[0]
    assert -20 < x < 0
    assert client.send("$G")[0].startswith("[GC:G0 G54 G17 G21 G90")  # jog never changes modal state


def test_safety_door_holds_and_resumes(grbl, clock):
    client, sim = grbl
    client.send("G1 X-10 F600")
    clock.advance(0.5)
    sim.controller.open_door()
    assert client.readline() == "[MSG:Check Door]"
    assert client.state() == "Door:2"
    client.run_until(lambda r: r.startswith("<Door:0"))
    client.ser.write(b"~")
    client.run_until(lambda r: r.startswith("<Idle"))
    assert client.mpos()[0] == -10.0


def test_safety_door_during_a_jog_cancels_it(grbl, clock):
    client, sim = grbl
    client.send("$J=G91 X-20 F600")
    clock.advance(0.5)
    sim.controller.open_door()
    client.run_until(lambda r: r.startswith("<Door:0"))
    client.ser.write(b"~")
    assert client.state() == "Idle"
    assert -20 < client.mpos()[0] < 0
