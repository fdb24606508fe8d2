"""The virtual GRBL 1.1 on a pty, driven byte by byte through pyserial (no link code involved)."""

from __future__ import annotations

import threading
import time

import pytest
import serial

from rig.instrument.clock import ManualClock
from simulator.grbl.controller import VirtualGrbl
from simulator.grbl.server import open_virtual_grbl, serve_grbl

BANNER = "Grbl 1.1h ['$' for help]"


class Client:
    """A bare pyserial client; every read is bounded by a wall-clock timeout so a test can never hang."""

    def __init__(self, port: str, clock: ManualClock) -> None:
        self.clock = clock
        self.ser = serial.Serial(port, 115200, timeout=0.01)
        self.buf = b""
        self.other: list[str] = []  # lines that arrived while waiting for status reports
        self.greeting = self.read_until(lambda line: line == BANNER)

    def close(self) -> None:
        self.ser.close()

    def readline(self, timeout_s: float = 2.0) -> str | None:
        deadline = time.monotonic() + timeout_s
        while b"\n" not in self.buf:
            if time.monotonic() > deadline:
                return None
            self.buf += self.ser.read(self.ser.in_waiting or 1)
        line, _, self.buf = self.buf.partition(b"\n")
        return line.decode().strip()

    def read_until(self, pred, timeout_s: float = 2.0) -> list[str]:
        lines = []
        while True:
            line = self.readline(timeout_s)
            assert line is not None, f"timed out; got {lines!r}"
            lines.append(line)
            if pred(line):
                return lines

    def send(self, line: str) -> list[str]:
        """One line, and everything GRBL prints up to its ok / error:N."""
        self.ser.write(line.encode() + b"\n")
        return self.read_until(lambda s: s == "ok" or s.startswith("error:"))

    def query(self) -> str:
        self.ser.write(b"?")
        lines = self.read_until(lambda s: s.startswith("<"))
        self.other += lines[:-1]
        return lines[-1]

    def state(self) -> str:
        return self.query()[1:-1].split("|")[0]

    def mpos(self) -> tuple[float, ...]:
        fields = dict(f.split(":", 1) for f in self.query()[1:-1].split("|")[1:])
        return tuple(float(v) for v in fields["MPos"].split(","))

    def run_until(self, pred, step_s: float = 0.05, limit_s: float = 120.0) -> str:
        """Advance simulated time in steps, polling '?', until ``pred(report)``; bounded by ``limit_s``."""
        start = self.clock.now()
        while True:
            report = self.query()
            if pred(report):
                return report
            assert self.clock.now() - start < limit_s, f"still {report} after {limit_s} s"
            self.clock.advance(step_s)


@pytest.fixture
def clock():
    return ManualClock()


@pytest.fixture
def grbl(clock, request):
    settings = getattr(request, "param", None)
    with open_virtual_grbl(clock, settings=settings) as sim:
        client = Client(sim.port, clock)
        yield client, sim
        client.close()


def test_banner_on_open_and_on_every_reopen(clock):
    with open_virtual_grbl(clock) as sim:
        first = Client(sim.port, clock)
        assert first.greeting == ["", BANNER]
        assert first.query() == "<Idle|MPos:0.000,0.000,0.000|FS:0,0|WCO:0.000,0.000,0.000>"
        assert first.query() == "<Idle|MPos:0.000,0.000,0.000|FS:0,0|Ov:100,100,100>"
        assert first.query() == "<Idle|MPos:0.000,0.000,0.000|FS:0,0>"
        first.close()
        again = Client(sim.port, clock)  # like an Arduino, opening the port resets the controller
        assert again.greeting[-1] == BANNER
        assert sim.opens == 2
        again.close()


def test_stop_is_prompt_even_with_a_client_attached(clock):
    with open_virtual_grbl(clock) as sim:
        client = Client(sim.port, clock)
        started = time.monotonic()
    assert time.monotonic() - started < 1.0
    client.close()


def test_settings_dump_set_and_read_back(grbl):
    client, sim = grbl
    dump = client.send("$$")
    assert dump[-1] == "ok"
    assert "$0=10" in dump and "$11=0.010" in dump and "$100=250.000" in dump and "$132=200.000" in dump
    assert client.send("$100=80.5") == ["ok"]
    assert client.send("$22=1") == ["ok"]
    assert client.send("$20=1") == ["ok"]
    dump = client.send("$$")
    assert "$100=80.500" in dump and "$20=1" in dump and "$22=1" in dump
    assert client.send("$22=0") == ["ok"]
    assert "$20=0" in client.send("$$")  # GRBL drops soft limits with homing
    assert sim.controller.settings[100] == 80.5


def test_info_parser_state_parameters_and_help(grbl):
    client, _ = grbl
    assert client.send("$I") == ["[VER:1.1h.20190830:]", "[OPT:V,15,128]", "ok"]
    assert client.send("$G") == ["[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]", "ok"]
    assert client.send("G20 G91 G1 F10") == ["ok"]
    assert client.send("$G") == ["[GC:G1 G54 G17 G20 G91 G94 M5 M9 T0 F10.0 S0]", "ok"]
    params = client.send("$#")
    assert params[0] == "[G54:0.000,0.000,0.000]" and params[-2] == "[PRB:0.000,0.000,0.000:0]"
    assert client.send("$")[0].startswith("[HLP:$$ $# $G $I")


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


ERROR_CASES = [
    ("1", 1),
    ("G1 Xa", 2),
    ("$Q", 2),
    ("$XX", 3),
    ("$100", 3),
    ("$999=1", 3),
    ("$100=-1", 4),
    ("G1 F-5", 4),
    ("$H", 5),
    ("$0=2", 6),
    ("$20=1", 10),
    ("G1 X" + "1" * 80, 11),
    ("$100=5000", 12),
    ("$J=G91 X10", 22),
    ("$J=G1 X1 F100", 16),
    ("$J=G91 X1 F100 M3", 16),
    ("G2 X1 Y1 I1", 20),
    ("G1 A5 F100", 20),
    ("G1 X1 G0", 21),
    ("G1 X1", 22),
    ("G1.5", 23),
    ("G0 X1 X2", 25),
    ("N10000001 G0 X1", 27),
    ("G4", 28),
    ("G80 G53 X1", 30),
    ("G80 X1", 31),
    ("G0 X1 R2", 36),
    ("T300", 38),
]


@pytest.mark.parametrize(("line", "code"), ERROR_CASES, ids=[f"error{c}-{line[:12]}" for line, c in ERROR_CASES])
def test_error_codes(grbl, line, code):
    client, _ = grbl
    assert client.send(line)[-1] == f"error:{code}"
    assert client.state() == "Idle"  # an error never moves anything


def test_not_idle_error_while_moving(grbl):
    client, _ = grbl
    client.send("G1 X5 F100")
    assert client.send("$$") == ["error:8"]
    assert client.send("$H") == ["error:8"]
    assert client.send("$C") == ["error:8"]


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


def test_buffer_overflow_loses_characters_of_a_client_that_does_not_count(grbl, clock):
    client, sim = grbl
    client.send("$120=1000")
    lines = [f"G1 X{-(i + 1)}.25 Y{-(i % 7)}.5 F9000" for i in range(40)]
    client.ser.write("".join(line + "\n" for line in lines).encode())  # ~1000 bytes at once, no counting
    client.query()
    assert sim.controller.rx_dropped > 0  # the planner filled, then the 128-byte buffer did
    client.run_until(lambda r: r.startswith("<Idle"), step_s=0.05)
    assert client.other.count("ok") < len(lines)
    assert client.mpos()[0] != -40.25  # the last lines never arrived
    # The partial line left in the buffer garbles whatever comes next.
    assert client.send("G0 X-1")[-1].startswith("error:")


def test_line_longer_than_80_characters_overflows(grbl):
    client, _ = grbl
    assert client.send("G0 X-1 " + "(" + "c" * 100 + ")") == ["ok"]  # comments are stripped before counting
    assert client.send("G0" + " X-1" * 30)[-1] == "error:11"


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


def test_check_mode_parses_without_moving(grbl):
    client, _ = grbl
    assert client.send("$C") == ["[MSG:Enabled]", "ok"]
    assert client.state() == "Check"
    assert client.send("G1 X-5 F100") == ["ok"]
    assert client.state() == "Check" and client.mpos() == (0.0, 0.0, 0.0)
    assert client.send("G1 X1 X2")[-1] == "error:25"
    client.ser.write(b"$C\n")
    assert client.read_until(lambda s: s == BANNER)[:2] == ["[MSG:Disabled]", "ok"]
    assert client.state() == "Idle"


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


def test_dropped_status_reports_and_stall(grbl, clock):
    client, sim = grbl
    sim.controller.drop_status_reports(2)
    client.ser.write(b"???")
    assert len(client.read_until(lambda s: s.startswith("<"))) == 1
    assert client.readline(0.05) is None
    client.send("G1 X-10 F600")
    clock.advance(0.5)
    sim.controller.stall()
    stuck = client.mpos()
    clock.advance(30.0)
    assert client.state() == "Run" and client.mpos() == stuck


def test_program_end_resets_modal_state(grbl, clock):
    client, _ = grbl
    client.send("G91 G0 X-1")
    client.ser.write(b"M30\n")
    while "ok" not in client.other:
        clock.advance(0.1)
        client.query()
    assert client.other == ["[MSG:Pgm End]", "ok"]
    assert client.send("$G")[0].startswith("[GC:G1 G54 G17 G21 G90")


def test_controller_argument_checks():
    with pytest.raises(ValueError, match="prefix"):
        VirtualGrbl(ManualClock(), axes="XZ")
    with pytest.raises(ValueError, match=r"\$140"):
        VirtualGrbl(ManualClock(), settings={140: 1.0})
    with pytest.raises(ValueError, match="8 or 9"):
        VirtualGrbl(ManualClock()).fail_next_homing(3)
    four = VirtualGrbl(ManualClock(), axes="XYZA")
    four.power_on()
    four.receive(b"G0 A-5\n?")
    assert b"MPos:0.000,0.000,0.000,0.000" in four.read_output()


def test_serve_grbl_blocks_until_stopped(clock):
    ready: list[str] = []
    stop = threading.Event()
    thread = threading.Thread(target=serve_grbl, kwargs={"clock": clock, "stop": stop, "on_ready": ready.append})
    thread.start()
    try:
        deadline = time.monotonic() + 2.0
        while not ready and time.monotonic() < deadline:
            stop.wait(0.01)
        client = Client(ready[0], clock)
        assert client.send("G0 X-1") == ["ok"]
        client.close()
    finally:
        stop.set()
        thread.join(timeout=2.0)
    assert not thread.is_alive()
