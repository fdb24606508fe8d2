"""Every example file keeps its promises: it loads, its joints read 0 deg where it says, its commands parse.

A Dynamixel joint reads ~0 deg with its servo at the centre of its turn (2048 ticks) and stays within one
servo turn when it is geared (the servo's absolute encoder then knows the joint at power-up). A GRBL rig's
comments list the $-settings to program; those must be what its axes imply, its joints' ranges must fit the
machine travel after homing, and the virtual controller programmed that way must home and reach every joint's
zero and limits. Every `gonio ...` command quoted in a comment must parse.
"""

from __future__ import annotations

import dataclasses
import json
import re
import shlex
import shutil
from pathlib import Path

import numpy as np
import pytest

from acquisition.flatfield import FlatField
from acquisition.noise import SensorNoise
from gonio.cli import build_parser
from rig.instrument.clock import ManualClock
from rig.instrument.links.dynamixel_table import X_SERIES
from rig.instrument.links.grbl import AXIS_LETTERS, GrblLink
from rig.run.calibrate import CALIBRATION_FORMAT
from rig.run.config.files import RigConfig, load_rig, load_sweep
from rig.run.session import capture_settings
from simulator.grbl.server import open_virtual_grbl

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
TOMLS = sorted(EXAMPLES.glob("*.toml"))
RIGS = [p for p in TOMLS if p.name.startswith("rig_")]
CENTRE = X_SERIES.ticks_per_turn // 2


def _comment_commands(path: Path) -> list[str]:
    comments = [line.split("#", 1)[1] for line in path.read_text().splitlines() if "#" in line]
    quoted = [c for text in comments for c in re.findall(r"`(gonio [^`]+)`", text)]
    return quoted + [text.strip() for text in comments if text.strip().startswith("gonio ")]  # a command line


def _settings(path: Path) -> dict[int, float]:
    """The GRBL $-settings a rig file's comments ask for (``$100=8.889`` ...)."""
    text = " ".join(line.split("#", 1)[1] for line in path.read_text().splitlines() if "#" in line)
    return {int(k): float(v) for k, v in re.findall(r"\$(\d+)=([-0-9.]+)", text)}


def test_there_are_examples_of_each_kind():
    names = {p.name for p in TOMLS}
    assert {"rig_simulated.toml", "rig_dynamixel.toml", "rig_grbl.toml", "sweep_grid.toml"} <= names


@pytest.mark.parametrize("path", TOMLS, ids=lambda p: p.name)
def test_every_example_loads_and_its_commands_parse(path: Path):
    if path.name.startswith("rig_"):
        load_rig(path)
    else:
        load_sweep(path)
    parser = build_parser()
    for command in _comment_commands(path):
        args = parser.parse_args(shlex.split(command)[1:])  # argparse exits (a test failure) on a bad command
        assert callable(args.func), command


def _dynamixel_axes(rig: RigConfig) -> bool:
    return all(isinstance(a.address, int) for a in rig.axes)


@pytest.mark.parametrize("path", RIGS, ids=lambda p: p.name)
def test_each_servo_joint_reads_zero_at_its_centre_and_stays_within_one_turn(path: Path):
    rig = load_rig(path)
    if not _dynamixel_axes(rig):
        pytest.skip(f"{path.name} drives its joints by GRBL letters (see the GRBL test)")
    for axis in rig.axes:
        assert abs(axis.to_degrees(CENTRE)) <= 0.5 / axis.units_per_joint_degree, (axis.name, axis.to_degrees(CENTRE))
        if axis.gear_ratio != 1.0:
            ticks = sorted((axis.to_units(axis.min_deg), axis.to_units(axis.max_deg)))
            assert 0 <= ticks[0] and ticks[1] <= X_SERIES.ticks_per_turn - 1, (axis.name, ticks)


def test_the_dynamixel_example_fixes_what_it_used_to_get_wrong():
    rig = load_rig(EXAMPLES / "rig_dynamixel.toml")
    tilt = next(a for a in rig.axes if a.name == "tilt")
    assert tilt.gear_ratio == 3.0 and tilt.to_degrees(CENTRE) == pytest.approx(0.0)  # it read -120 deg
    assert "gonio sim servos --ids 1-4" in _comment_commands(EXAMPLES / "rig_dynamixel.toml")


GRBL_RIGS = [p for p in RIGS if "$22=1" in p.read_text()]


@pytest.mark.parametrize("path", GRBL_RIGS, ids=lambda p: p.name)
def test_a_grbl_rig_lists_the_settings_its_axes_imply_and_its_joints_fit_the_travel(path: Path):
    rig, s = load_rig(path), _settings(path)
    assert s[22] == 1 and s[23] == 0, "homing on, every axis towards its switch at machine 0"
    for axis in rig.axes:
        i = AXIS_LETTERS.index(str(axis.address))
        assert s[100 + i] == pytest.approx(axis.units_per_degree, abs=1e-3), axis.name
        assert s[110 + i] == pytest.approx(axis.max_speed_deg_s * axis.gear_ratio * 60), axis.name
        assert s[120 + i] == pytest.approx(axis.max_accel_deg_s2 * axis.gear_ratio), axis.name
        ends = [axis.to_units(d) / axis.units_per_degree for d in (axis.min_deg, axis.max_deg)]
        # After homing the pulled-off position is -$27; soft limits keep the machine within [-$13x, 0].
        assert -s[130 + i] <= min(ends) and max(ends) <= -s[27] + 1e-9, (axis.name, ends)


@pytest.mark.parametrize("path", GRBL_RIGS, ids=lambda p: p.name)
def test_a_grbl_rig_homes_and_reaches_its_zeros_and_limits_on_the_controller_its_comments_program(path: Path):
    rig, settings = load_rig(path), _settings(path)
    letters = "".join(str(a.address) for a in rig.axes)
    clock = ManualClock()
    start = {letter: -50.0 for letter in letters}  # wherever the axes stood when the power came on
    with open_virtual_grbl(clock, axes=letters, settings=settings, start_position=start) as sim:
        with GrblLink(sim.port, rig.axes, clock=clock, require_home=True, poll_interval_s=0.05) as link:
            zero = {a.name: 0.0 for a in rig.axes}
            link.move_to(zero)  # homes first: a run never assumes where the axes are
            assert link.wait_in_position(120.0) == pytest.approx(zero, abs=0.05)
            for pose in ({a.name: a.min_deg for a in rig.axes}, {a.name: a.max_deg for a in rig.axes}):
                link.move_to(pose)
                assert link.wait_in_position(120.0) == pytest.approx(pose, abs=0.05)


def _without_table(text: str, name: str) -> str:
    """A TOML file's text without table ``[name]`` (its header to the next table's)."""
    lines = text.splitlines(keepends=True)
    start = next(i for i, line in enumerate(lines) if line.startswith(f"[{name}]"))
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("[")), len(lines))
    return "".join(lines[:start] + lines[end:])


def test_the_raw_rig_edited_as_its_comment_says_runs_with_its_camera_calibration(tmp_path: Path):
    # The comment said to point calibration and flat_field at the files; gonio run then refused the rig (exit 2),
    # for [camera.noise] beside a calibration. Every edit the comment asks for is made, and nothing else.
    (tmp_path / "examples").mkdir()
    rig_path = Path(shutil.copy(EXAMPLES / "rig_simulated_raw.toml", tmp_path / "examples"))
    text = rig_path.read_text()
    comment = " ".join(line.lstrip("# ").strip() for line in text.splitlines() if line.startswith("#"))
    assert "point [camera] calibration and flat_field at the files it writes" in comment
    for key in ("calibration", "flat_field"):
        text = re.sub(rf"^# ({key} = )", r"\1", text, count=1, flags=re.M)
    for table in re.findall(r"delete the \[([\w.]+)\] table", comment):
        text = _without_table(text, table)
    rig_path.write_text(text)
    calib = tmp_path / "calib"  # what `--out calib/` makes, which the lines name relative to the rig file
    calib.mkdir()
    fitted = SensorNoise(e_per_dn=3.1, read_noise_e=4.5)
    doc = {"format": CALIBRATION_FORMAT, "noise": dataclasses.asdict(fitted)}
    (calib / "camera_calibration.json").write_text(json.dumps(doc))
    ones = np.ones((48, 48), dtype=np.float32)
    FlatField(ones, 0 * ones, "raw", "RGGB", 2, 1000.0, 0.0, 0.0).save(calib / "flat_field.npz")
    rig = load_rig(rig_path)
    assert rig.file.camera.calibration is not None and rig.file.camera.flat_field is not None
    settings = capture_settings(rig, load_sweep(EXAMPLES / "sweep_in_plane.toml"))  # what gonio run reads first
    assert settings.noise == fitted and settings.flat_field is not None
