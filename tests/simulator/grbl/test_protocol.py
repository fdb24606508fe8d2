"""The virtual GRBL 1.1 on a pty, driven byte by byte through pyserial (no link code involved): banner,
settings, queries, error codes, buffers, check mode, status drops and the server.
"""

from __future__ import annotations

import threading
import time

import pytest

from rig.instrument.clock import ManualClock
from simulator.grbl import server as server_module
from simulator.grbl.controller import VirtualGrbl
from simulator.grbl.noise import LineNoise
from simulator.grbl.server import open_virtual_grbl, serve_grbl
from tests.simulator.grbl.grbl_client import BANNER, Client


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


def test_receive_buffer_holds_all_128_bytes(grbl, clock):
    # GRBL 1.1's ring buffer has a spare slot so all RX_BUFFER_SIZE = 128 bytes are usable, which is what
    # character-counting clients (the link included) rely on.
    client, sim = grbl
    assert client.send("$10=3") == ["ok"]
    client.ser.write(b"!")  # a feed hold suspends the main loop: lines wait in the receive buffer
    assert client.query().startswith("<Hold:0")
    lines = ["G21 G90"] * 12 + ["G90"] * 8  # 12 * 8 + 8 * 4 = 128 bytes
    data = "".join(line + "\n" for line in lines).encode()
    assert len(data) == 128
    client.ser.write(data)
    assert "|Bf:15,0|" in client.query()  # all 128 bytes wait in the buffer
    assert sim.controller.rx_dropped == 0
    client.ser.write(b"~")
    client.run_until(lambda r: r.startswith("<Idle") and "Bf:15,128" in r)
    assert client.other.count("ok") == len(lines)


def test_flushing_the_host_buffers_mid_move_is_not_a_reset(grbl, clock):
    # pyserial's reset_input_buffer() / reset_output_buffer() drop bytes on the host; GRBL never sees them.
    # Only opening the port (an Arduino's DTR reset) or 0x18 resets it.
    client, sim = grbl
    client.send("G1 X-10 F600")
    clock.advance(0.5)
    before = client.mpos()
    assert client.state() == "Run" and -10.0 < before[0] < 0.0
    client.ser.reset_input_buffer()
    client.ser.reset_output_buffer()
    assert client.state() == "Run" and client.mpos() == before  # no time passed: still there, still moving
    assert BANNER not in client.other and sim.opens == 1
    client.run_until(lambda r: r.startswith("<Idle"))
    assert client.mpos() == (-10.0, 0.0, 0.0)  # the move went on to its end
    client.ser.write(b"\x18")  # whereas a soft reset mid-session is one
    assert client.read_until(lambda line: line == BANNER)[-1] == BANNER


def test_without_inotify_an_open_after_a_hang_up_still_resets_and_a_flush_does_not(clock, monkeypatch):
    # Where opens cannot be watched (not Linux), the only open the server can tell is one after nobody had the port.
    monkeypatch.setattr(server_module._OpenWatch, "opened", lambda self: False)
    with open_virtual_grbl(clock) as sim:
        first = Client(sim.port, clock)
        first.ser.reset_input_buffer()
        assert first.state() == "Idle" and sim.opens == 1
        first.close()
        deadline = time.monotonic() + 30.0
        while not sim.hung_up:  # the serving thread sees the port closed within a tick
            assert time.monotonic() < deadline, "the server never saw the port closed"
            time.sleep(0.001)
        again = Client(sim.port, clock)
        assert again.greeting[-1] == BANNER and sim.opens == 2
        again.close()


def test_a_noisy_line_loses_or_garbles_replies_the_same_way_for_a_seed(grbl, clock):
    client, sim = grbl
    noise = sim.controller.noisy_line(drop=1.0)
    client.ser.write(b"?G21\n")
    assert client.readline(0.2) is None and noise.dropped == 2  # the report and the 'ok' are both lost
    noise = sim.controller.noisy_line(garble=1.0, seed=5)
    client.ser.write(b"G21\n")
    line, deadline = b"", time.monotonic() + 60.0  # the port's short read timeout can cut a line on a loaded host
    while not line.endswith(b"\n") and time.monotonic() < deadline:
        line += client.ser.read_until(b"\n")
    assert line.endswith(b"\r\n") and len(line) == 4 and sum(b >= 0x80 for b in line) == 1  # one byte is no character
    sim.controller.noisy_line()  # a quiet line again
    assert client.send("G21") == ["ok"]
    first, again = ([n.carry(b"ok\r\n") for _ in range(40)] for n in (LineNoise(0.3, 0.2, 7), LineNoise(0.3, 0.2, 7)))
    assert first == again and b"" in first and b"ok\r\n" in first and len(set(first)) > 2  # seeded: the same noise
    with pytest.raises(ValueError, match="drop \\+ garble"):
        sim.controller.noisy_line(drop=0.7, garble=0.5)


def test_lost_acknowledgements_leave_the_lines_executed(grbl, clock):
    client, sim = grbl
    sim.controller.drop_acknowledgements(1)
    client.ser.write(b"G1 X-2 F600\n")
    assert client.readline(0.2) is None
    client.run_until(lambda r: r.startswith("<Idle"))
    assert client.mpos() == (-2.0, 0.0, 0.0) and client.send("G21") == ["ok"]
