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
