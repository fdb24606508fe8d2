"""Every hardware workflow of the README and docs/hardware.md on a GRBL rig, through the rehearsal.

The shipped ``examples/rig_grbl.toml`` (port, folder and ROI changed, see ``workflows.py``) against ``gonio sim
rig``: the camera calibration with the operator's light and lens cap, a run stopped with Ctrl-C at a mid-run
reference and resumed (the controller homes again after the port is opened anew), its analyses, and an
adaptive sweep stopped and resumed. The geometry calibration on this link: ``test_rehearsal_grbl_geometry.py``.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.rehearsal import workflows as w
from tests.rehearsal.harness import Operator, Rehearsal

pytestmark = [pytest.mark.slow, pytest.mark.mitsuba]


@pytest.fixture(scope="module")
def rehearsed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Rehearsal, Path, Path]]:
    tmp = tmp_path_factory.mktemp("grbl")
    shipped = w.small_rig("grbl", tmp)
    with w.rehearsal_of(shipped, tmp / "frames") as reh:
        yield reh, reh.rig_file(shipped, tmp / "rig.toml"), tmp


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
