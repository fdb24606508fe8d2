"""Broken frames through the run path: a camera fault that names what is wrong, never a shifted reading or numpy.

A camera that delivers a frame without pixels, or a dark frame holding NaN counts, stops the run as a camera
fault (``RunStopped.cause == "camera"``, exit 4) whose message names the frame and the defect.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from acquisition.frame import Frame
from rig.run.measuring.runner import RunStopped
from rig.run.session import make_plan, manifest, options_for
from rig.run.storage.store import RunStore
from simulator.from_config import rig_from
from tests.run_helpers import FlakyCamera, in_plane_sweep, run_outcome, sim_rig

pytestmark = pytest.mark.mitsuba


class _BrokenCamera(FlakyCamera):
    """Delivers every light frame and dark frame through ``light`` and ``dark``."""

    def __init__(self, camera: Any, light: Callable[[Frame], Frame], dark: Callable[[Frame], Frame]) -> None:
        super().__init__(camera, {})
        self._light, self._dark = light, dark

    def capture(self) -> Frame:
        """A light frame as ``light`` spoils it."""
        return self._light(super().capture())

    def capture_dark(self) -> Frame:
        """A dark frame as ``dark`` spoils it."""
        return self._dark(super().capture_dark())


def _run(tmp_path: Path, light: Callable[[Frame], Frame], dark: Callable[[Frame], Frame]) -> Any:
    rig = sim_rig()
    sweep = in_plane_sweep([30.0], [-30.0, 20.0], exposures_s=[0.02], dark_frames=1)
    plan = make_plan(rig, sweep)
    store = RunStore.create(tmp_path / "run", manifest(rig, sweep, plan, options_for(rig, sweep, False)))
    with rig_from(rig) as sim:
        assert sim.camera is not None
        return run_outcome(sim, rig, sweep, plan, store, _BrokenCamera(sim.camera, light, dark))


def _same(frame: Frame) -> Frame:
    return frame


def _nan_rows(frame: Frame) -> Frame:
    data = np.array(frame.data, dtype=np.float32)
    data[: max(1, data.shape[0] // 4)] = np.nan  # a quarter of the dark frame unread
    return dataclasses.replace(frame, data=data)


def test_a_dark_frame_with_nan_counts_is_a_camera_fault_naming_the_dark(tmp_path: Path) -> None:
    outcome = _run(tmp_path, _same, _nan_rows)
    assert isinstance(outcome, RunStopped) and outcome.cause == "camera", outcome
    assert "dark 0 for 0.02 s" in str(outcome) and "non-finite pixel values" in str(outcome), outcome


def test_a_frame_without_pixels_is_a_camera_fault_naming_it(tmp_path: Path) -> None:
    def empty(frame: Frame) -> Frame:
        return dataclasses.replace(frame, data=frame.data[:0])

    outcome = _run(tmp_path, empty, _same)
    assert isinstance(outcome, RunStopped) and outcome.cause == "camera", outcome
    assert "the frame holds no pixels" in str(outcome) and "gonio simulated camera" in str(outcome), outcome
