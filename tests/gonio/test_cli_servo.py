"""``gonio servo scan|ping|status|move`` against virtual servos on a pty (the SDK as the client)."""

from __future__ import annotations

from pathlib import Path

import pytest

from gonio import cli
from rig.instrument.clock import ScaledClock
from simulator.dynamixel import open_virtual_bus


def test_scan_ping_and_status_report_what_the_bus_holds(capsys: pytest.CaptureFixture[str]) -> None:
    with open_virtual_bus(ids=(2, 5), baudrate=57_600) as bus:
        common = ["--port", bus.port, "--baud", "57600", "--latency-ms", "60"]
        assert cli.main(["servo", "scan", *common, "--bauds", "57600"]) == 0
        out = capsys.readouterr().out
        assert "id   2     57600 baud  XM430-W350" in out and "id   5" in out
        assert cli.main(["servo", "ping", *common, "2", "5"]) == 0
        assert capsys.readouterr().out.count("XM430-W350") == 2
        bus.servo(5).inject_hardware_error(0x20)
        assert cli.main(["servo", "status", *common, "5"]) == 0
        status = capsys.readouterr().out
        assert "torque off" in status and "overload" in status.lower()
        assert cli.main(["servo", "ping", *common, "7"]) == 3  # nobody answers at id 7: a hardware fault
        assert "servo" in capsys.readouterr().err.lower()


def test_scan_of_an_empty_bus_says_what_to_check(capsys: pytest.CaptureFixture[str]) -> None:
    with open_virtual_bus(ids=(1,), baudrate=1_000_000) as bus:
        assert cli.main(["servo", "scan", "--port", bus.port, "--bauds", "57600", "--latency-ms", "60"]) == 3
    assert "no servo answered" in capsys.readouterr().out


def test_move_drives_one_joint_of_a_rig_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with open_virtual_bus(ids=(1, 2, 3, 4), clock=ScaledClock(50.0)) as bus:
        rig = tmp_path / "rig.toml"
        rig.write_text(
            f'[link]\nkind = "dynamixel"\nport = "{bus.port}"\nlatency_timer_ms = 60.0\n[reference]\nkind = "none"\n'
            + "".join(f"[axes.{name}]\nid = {i}\n" for i, name in enumerate(("light", "camera", "tilt", "roll"), 1))
            + '[camera]\nbackend = "folder"\nfolder = "/tmp"\n'
        )
        assert cli.main(["servo", "move", "--rig", str(rig), "light", "30"]) == 0
        assert "light 29.97 deg" in capsys.readouterr().out  # 30 deg is between ticks: the read-back
        assert not bus.servo(1).torque_enabled  # left safe: torque off unless --keep-torque
        assert cli.main(["servo", "move", "--rig", str(rig), "tilt", "120"]) == 2  # beyond the tilt limit
        assert "tilt" in capsys.readouterr().err


# --- commissioning: ids, baud rates, the port and its adapter ----------------------------------------------------

SDK_LATENCY = ["--latency-ms", "60"]  # a loaded host schedules the bus thread late; a real adapter would be 1 ms


def _sdk_ping(port: str, baud: int, sid: int, tries: int = 20) -> int | None:
    """Model number of ``sid`` by dynamixel_sdk alone (not gonio's bus), or None if it never answers."""
    import dynamixel_sdk as sdk

    handler, packets = sdk.PortHandler(port), sdk.PacketHandler(2.0)
    assert handler.openPort() and handler.setBaudRate(baud)
    try:
        for _ in range(tries):
            model, result, _error = packets.ping(handler, sid)
            if result == sdk.COMM_SUCCESS:
                return int(model)
        return None
    finally:
        handler.closePort()


def test_set_id_writes_the_control_table_and_the_servo_answers_at_its_new_id(capsys):
    with open_virtual_bus(ids=(1, 2)) as bus:
        args = ["servo", "set-id", "--port", bus.port, *SDK_LATENCY, "1", "5", "--yes"]
        assert cli.main(args) == 0
        assert "servo 1 is now id 5" in capsys.readouterr().out
        assert bus.servo(5).value("id") == 5
        assert _sdk_ping(bus.port, 1_000_000, 5) == 1020  # an XM430-W350, asked by the SDK itself
        assert _sdk_ping(bus.port, 1_000_000, 1, tries=3) is None
        assert _sdk_ping(bus.port, 1_000_000, 2) == 1020  # the other servo is untouched


def test_set_id_refuses_an_id_in_use_and_asks_before_it_writes(capsys, monkeypatch):
    import io

    with open_virtual_bus(ids=(1, 2)) as bus:
        base = ["servo", "set-id", "--port", bus.port, *SDK_LATENCY]
        assert cli.main([*base, "1", "2", "--yes"]) == 2
        assert "id 2 is taken" in capsys.readouterr().err
        bus.servo(1).poke("torque_enable", 1)
        monkeypatch.setattr("sys.stdin", io.StringIO("n\n"))
        assert cli.main([*base, "1", "7"]) == 1  # declined: nothing changed
        err = capsys.readouterr().err
        assert "to id 7? Torque goes off first" in err and "nothing changed" in err
        assert bus.servo(1).value("id") == 1 and bus.servo(1).torque_enabled
        monkeypatch.setattr("sys.stdin", io.StringIO(""))  # no answer at all (a closed stdin) is no
        assert cli.main([*base, "1", "7"]) == 1
        monkeypatch.setattr("sys.stdin", io.StringIO("y\n"))
        assert cli.main([*base, "1", "7"]) == 0
        assert bus.servo(7).value("id") == 7 and not bus.servo(7).torque_enabled
        assert cli.main([*base, "9", "8", "--yes"]) == 3  # nobody at id 9
        assert "no servo answers at id 9" in capsys.readouterr().err


def test_set_baud_moves_every_listed_servo_to_the_new_rate(capsys):
    with open_virtual_bus(ids=(1, 2, 3), baudrate=1_000_000) as bus:
        args = ["servo", "set-baud", "--port", bus.port, *SDK_LATENCY, "1", "2", "57600", "--yes"]
        assert cli.main(args) == 0
        assert "1, 2 now answer at 57600 baud" in capsys.readouterr().out
        assert [bus.servo(i).value("baud_rate") for i in (1, 2, 3)] == [1, 1, 3]  # 1 = 57600, 3 = 1 Mbps
        assert _sdk_ping(bus.port, 57_600, 1) == 1020 and _sdk_ping(bus.port, 57_600, 2) == 1020
        assert _sdk_ping(bus.port, 1_000_000, 1, tries=3) is None
        assert _sdk_ping(bus.port, 1_000_000, 3) == 1020
        assert cli.main(["servo", "ping", "--port", bus.port, "--baud", "57600", *SDK_LATENCY, "1", "2"]) == 0


def test_set_baud_refuses_a_rate_the_sdk_or_the_servo_cannot_take(capsys):
    with open_virtual_bus(ids=(1,)) as bus:
        base = ["servo", "set-baud", "--port", bus.port, *SDK_LATENCY, "1"]
        assert cli.main([*base, "4500000", "--yes"]) == 2  # the servo has it, dynamixel_sdk does not
        assert "expected one of 9600, 57600, 115200, 1000000" in capsys.readouterr().err
        assert cli.main([*base, "1000000", "--yes"]) == 2
        assert bus.servo(1).value("baud_rate") == 3


def test_ping_lists_every_id_found_or_missing(capsys):
    with open_virtual_bus(ids=(1, 2, 4)) as bus:
        assert cli.main(["servo", "ping", "--port", bus.port, *SDK_LATENCY, "1", "2", "3", "4", "5"]) == 3
    out, err = capsys.readouterr()
    lines = out.splitlines()
    assert [line.split(":")[1].split()[0].strip(",") for line in lines] == ["found", "found", "missing", "found",
                                                                             "missing"]  # fmt: skip
    assert "3 of 5 servos answered" in err and "missing: 3, 5" in err


def test_move_of_an_unknown_joint_lists_the_axes(tmp_path, capsys):
    rig = tmp_path / "rig.toml"
    rig.write_text('[link]\nkind = "dynamixel"\nport = "/dev/null"\n[reference]\nkind = "none"\n'
                   + "".join(f"[axes.{n}]\nid = {i}\n" for i, n in enumerate(("light", "camera", "tilt", "roll"), 1))
                   + '[camera]\nbackend = "folder"\nfolder = "/tmp"\n')  # fmt: skip
    assert cli.main(["servo", "move", "--rig", str(rig), "lamp", "20"]) == 2
    err = capsys.readouterr().err
    assert "joint 'lamp'" in err and "light, camera, tilt, roll" in err and "Traceback" not in err
    assert cli.main(["servo", "move", "--rig", str(rig), "camrea", "20"]) == 2
    assert "did you mean 'camera'?" in capsys.readouterr().err


def _fake_sysfs(root: Path, tty: str, value: str) -> Path:
    device = root / "bus" / "usb-serial" / "devices" / tty
    device.mkdir(parents=True)
    (device / "latency_timer").write_text(value + "\n")
    return root


def test_the_latency_timer_is_read_from_sysfs_through_udev_symlinks(tmp_path):
    from rig.instrument.links.usb_serial import latency_advice, read_latency_timer

    sysfs = _fake_sysfs(tmp_path / "sys", "ttyUSB0", "16")
    dev = tmp_path / "dev"
    (dev / "serial" / "by-id").mkdir(parents=True)
    (dev / "ttyUSB0").touch()
    link = dev / "serial" / "by-id" / "usb-FTDI_USB__-__Serial_Converter_FT1234-if00-port0"
    link.symlink_to("../../ttyUSB0")
    timer = read_latency_timer(link, sysfs)
    assert timer is not None and (timer.tty, timer.value_ms) == ("ttyUSB0", 16)
    assert "above the 1 ms gonio was told" in str(latency_advice(timer, 1.0))
    assert "every servo reply waits for it" in str(latency_advice(timer, 16.0))
    (sysfs / "bus/usb-serial/devices/ttyUSB0/latency_timer").write_text("1\n")
    assert latency_advice(read_latency_timer(dev / "ttyUSB0", sysfs), 1.0) is None
    assert read_latency_timer(dev / "ttyACM0", sysfs) is None  # a CDC-ACM board has no latency timer
    (sysfs / "bus/usb-serial/devices/ttyUSB0/latency_timer").write_text("fast\n")
    with pytest.raises(ValueError, match="latency_timer: 'fast' is not a latency timer"):
        read_latency_timer(dev / "ttyUSB0", sysfs)


def test_scan_ping_and_check_say_when_the_latency_timer_is_too_high(tmp_path, capsys, monkeypatch):
    import os

    with open_virtual_bus(ids=(1,)) as bus:
        tty = os.path.basename(os.path.realpath(bus.port))  # the pty stands in for a ttyUSB behind an FTDI chip
        monkeypatch.setenv("GONIO_SYSFS", str(_fake_sysfs(tmp_path, tty, "16")))
        assert cli.main(["servo", "ping", "--port", bus.port, *SDK_LATENCY, "1"]) == 0
        assert "latency timer is 16 ms" in capsys.readouterr().err
        assert cli.main(["servo", "check", "--port", bus.port, "--latency-ms", "1", "1"]) == 3
        out = capsys.readouterr().out
        assert "readable and writable by you" in out and "above the 1 ms" in out
        (tmp_path / "bus/usb-serial/devices" / tty / "latency_timer").write_text("1\n")
        assert cli.main(["servo", "check", "--port", bus.port, *SDK_LATENCY, "1"]) == 0
        out = capsys.readouterr().out
        assert "USB latency timer 1 ms" in out and "id   1: found, XM430-W350" in out
    assert cli.main(["servo", "check", "--port", str(tmp_path / "ttyUSB9")]) == 3
    assert "no such device" in capsys.readouterr().out


@pytest.mark.parametrize(
    ("where", "what"),
    [("/dev/null", "is a character device but not a terminal (termios refuses it"),
     ("dir", "is a directory"), ("file", "is a regular file")],
)  # fmt: skip
def test_check_says_what_a_port_that_is_no_serial_port_is(tmp_path, capsys, where, what):
    port = {"dir": tmp_path, "file": tmp_path / "ttyUSB0"}.get(where, Path(where))
    if where == "file":
        port.write_text("")
    assert cli.main(["servo", "check", "--port", str(port)]) == 3
    out = capsys.readouterr().out
    assert f"{port}: {what}" in out and "expected a serial port" in out
    assert "present" not in out
