"""Every hardware workflow of the README and docs/hardware.md on a Dynamixel rig, through the rehearsal.

The shipped ``examples/rig_dynamixel.toml`` (port, folder and ROI changed, see ``workflows.py``) against
``gonio sim rig``: the servo commands on its bus, the camera and geometry calibrations with the operator's
light, lens cap and board, a run stopped with Ctrl-C at a mid-run reference and resumed, its analyses, and an
adaptive sweep stopped and resumed; then ``examples/rig_misaligned.toml`` served on this link, its
misalignments found by ``gonio calibrate geometry`` through the folder camera.
"""

from __future__ import annotations

import json
import sys

import pytest

from tests.rehearsal import workflows as w
from tests.rehearsal.harness import Operator

pytestmark = [pytest.mark.slow, pytest.mark.mitsuba]


class TestDynamixel(w.Workflows):
    """The shared workflows, and what only a Dynamixel rig has or this file shows once for both links."""

    link = "dynamixel"

    def test_servo_commands_find_and_move_the_rehearsed_servos(self, rehearsed: w.Rehearsed) -> None:
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

    def test_a_run_shot_by_a_trigger_command(self, rehearsed: w.Rehearsed) -> None:
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

    def test_an_image_mode_run_stopped_resumed_and_analysed(self, rehearsed: w.Rehearsed) -> None:
        # Image mode on a rig file that states no sensor size, through the folder camera's whole-sensor DNG mosaics.
        reh, rig, tmp = rehearsed
        sweep = tmp / "sweep_image.toml"
        sweep.write_text(w.IMAGE_SWEEP)
        op = Operator(reh, tmp)
        whole, _ = w.check_image_run(op, rig, sweep, tmp / "shipped_dynamixel.toml", tmp)
        report = op.run("analyze", str(whole), "--quiet", "--models", "lambert", "--out", str(tmp / "image-analysis"))
        assert report.status == 0, report.output
        fit = json.loads((tmp / "image-analysis" / "fit.json").read_text())
        assert fit["chosen"] == "lambert"
