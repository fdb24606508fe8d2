"""Every hardware workflow of the README and docs/hardware.md on a Dynamixel rig, through the rehearsal.

The shipped ``examples/rig_dynamixel.toml`` (port, folder and ROI changed, see ``workflows.py``) against
``gonio sim rig``: the servo commands on its bus, the camera and geometry calibrations with the operator's
light, lens cap and board, a run stopped with Ctrl-C at a mid-run reference and resumed, its analyses, and an
adaptive sweep stopped and resumed; then ``examples/rig_misaligned.toml`` served on this link, its
misalignments found by ``gonio calibrate geometry`` through the folder camera.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.rehearsal import workflows as w
from tests.rehearsal.harness import Operator, Rehearsal

pytestmark = [pytest.mark.slow, pytest.mark.mitsuba]

#: ``examples/rig_misaligned.toml``'s [simulation.misalignment], which its controller is not told.
MISALIGNED = {"light_zero_deg": 0.5, "camera_zero_deg": -0.3, "tilt_zero_deg": 0.2, "roll_zero_deg": 0.4,
              "sample_tilt_deg": 0.6, "sample_tilt_azimuth_deg": 30.0, "sample_offset_mm": [1.0, -0.8, 0.5]}


@pytest.fixture(scope="module")
def rehearsed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Rehearsal, Path, Path]]:
    tmp = tmp_path_factory.mktemp("dynamixel")
    shipped = w.small_rig("dynamixel", tmp)
    with w.rehearsal_of(shipped, tmp / "frames") as reh:
        yield reh, reh.rig_file(shipped, tmp / "rig.toml"), tmp


def test_servo_commands_find_and_move_the_rehearsed_servos(rehearsed: tuple[Rehearsal, Path, Path]) -> None:
    reh, rig, tmp = rehearsed
    op = Operator(reh, tmp)
    scan = op.run("servo", "scan", "--port", reh.port, "--bauds", "1000000")
    assert scan.status == 0, scan.output
    found = [line.split()[:5] for line in scan.output.splitlines() if line.startswith("id")]
    assert found == [["id", str(i), "1000000", "baud", "XM430-W350"] for i in (1, 2, 3, 4)], scan.output
    check = op.run("servo", "check", "--port", reh.port, "--latency-ms", "1", "1", "2", "3", "4")
    assert check.status == 0, check.output
    status = op.run("servo", "status", "--port", reh.port, "1", "2")
    assert status.status == 0, status.output
    move = op.run("servo", "move", "--rig", str(rig), "light", "20")
    assert move.status == 0, move.output
    assert "light" in move.output


def test_a_run_stopped_and_resumed_is_analysed(rehearsed: tuple[Rehearsal, Path, Path]) -> None:
    reh, rig, tmp = rehearsed
    sweep = tmp / "sweep.toml"
    sweep.write_text(w.SWEEP)
    op = Operator(reh, tmp)
    whole, cut = w.check_run_interrupt_resume(op, rig, sweep, tmp)
    w.check_analyze(op, whole, cut, tmp)


def test_an_adaptive_sweep_stopped_and_resumed(rehearsed: tuple[Rehearsal, Path, Path]) -> None:
    reh, rig, tmp = rehearsed
    w.check_adaptive(Operator(reh, tmp), rig, tmp)


def test_the_camera_calibration_finds_the_sensor(rehearsed: tuple[Rehearsal, Path, Path]) -> None:
    reh, rig, tmp = rehearsed
    calibration = w.check_camera_calibration(Operator(reh, tmp), rig, tmp)
    found = calibration["parameters"]
    assert isinstance(found, dict)
    # The rehearsal's sensor is [camera.noise]'s defaults: 4 e-/DN, 3 e- read noise, black at 512 DN.
    for key, truth in (("e_per_dn", 4.0), ("read_noise_e", 3.0), ("black_level_dn", 512.0)):
        assert abs(found[key]["value"] - truth) <= 3 * found[key]["std_error"], (key, found[key])


def test_the_geometry_calibration_of_the_misaligned_rig(tmp_path: Path) -> None:
    written = tmp_path / "rig.toml"
    with w.rehearsal_of(w.ROOT / "examples" / "rig_misaligned.toml", tmp_path / "frames", "--link", "dynamixel",
                        "--write-rig", str(written)) as reh:  # fmt: skip
        w.check_geometry_calibration(Operator(reh, tmp_path), written, tmp_path / "calib", 30, MISALIGNED)


def test_a_run_shot_by_a_trigger_command(rehearsed: tuple[Rehearsal, Path, Path]) -> None:
    # A rig file whose camera is fired by a trigger, as a gphoto2 command would fire a real one: the folder
    # camera runs `gonio sim shoot` per frame with the frame's settings filled in, and leaves no request itself.
    reh, rig, tmp = rehearsed
    python = sys.executable
    trigger = (f'["{python}", "-m", "gonio.cli", "sim", "shoot", "--folder", "{reh.frames}", "--exposure-s", '
               '"{exposure_s}", "--gain", "{gain}", "--index", "{index}"]')
    triggered = tmp / "triggered.toml"
    triggered.write_text(rig.read_text().replace('[camera]\n', f'[camera]\ntrigger = {trigger}\n', 1))
    sweep = tmp / "sweep.toml"
    sweep.write_text(w.SWEEP)
    op = Operator(reh, tmp)
    done = op.run("run", str(sweep), "--rig", str(triggered), "--out", str(tmp / "triggered"), "--quiet")
    assert done.status == 0, done.output
    assert len(w.table(tmp / "triggered")) == 8
    assert not list(reh.frames.glob(".gonio-shot-*")), "a request was left behind"
