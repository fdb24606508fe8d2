"""Backends found by registration (rig/run/registry.py and base.py, acquisition/cameras/registry.py).

gonio's own backends are entry points of the installed distribution; a lab's would be entry points of its
own package. Here a stage and a camera are registered from this test module, exactly as a separate
package would register them, and a rig file that names them is validated, opened and run.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator, Mapping
from importlib.metadata import EntryPoint
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from acquisition.cameras import ClockLike
from acquisition.cameras import registry as camera_registry
from acquisition.cameras.registry import CameraBackend
from acquisition.frame import ExposureSettings, Frame
from rig.instrument.clock import ManualClock
from rig.run import registry
from rig.run.backends.base import Instruments, RigBackend, StartPose, backend
from rig.run.backends.hardware import open_camera
from rig.run.config.files import ConfigError, RigConfig, parse, rig_config
from rig.run.config.schema import RigFile
from rig.run.session import start_run
from tests.run_helpers import in_plane_sweep, read_rows, sim_rig

HERE = __name__


@contextlib.contextmanager
def _open_lab_stage(rig: RigConfig, start: StartPose | None = None) -> Iterator[Instruments]:
    """A lab's stage: here the simulated rig under another name, opened through gonio's public pieces."""
    from simulator.backend import open_simulated

    link = rig.file.link.model_copy(update={"kind": "simulated"})
    as_simulated = dataclasses.replace(rig, file=rig.file.model_copy(update={"link": link}))
    with open_simulated(as_simulated, start) as inst:
        opened.append(rig.file.link.kind)
        yield inst


opened: list[str] = []
LAB_STAGE = RigBackend(open=_open_lab_stage, needs_port=False, default_axes=True, cameras=("simulated",),
                       references=("simulated",))  # fmt: skip


class LabCamera:
    """A camera of a lab's own: a constant grey frame, exposure as requested."""

    identity = "lab camera"

    def __init__(self, clock: ClockLike) -> None:
        self.clock, self.exposure_s = clock, 0.01

    def set_exposure(self, exposure_s: float, gain: float | None = None) -> ExposureSettings:
        self.exposure_s = exposure_s
        return ExposureSettings(exposure_s, 1.0 if gain is None else gain)

    def capture(self) -> Frame:
        return Frame(np.full((4, 4), 100.0), exposure_s=self.exposure_s, kind="linear", black_level=0.0,
                     white_level=4095.0, timestamp_s=self.clock.now(), camera_id=self.identity)  # fmt: skip

    def close(self) -> None:
        pass


def _open_lab_camera(settings: Mapping[str, Any], clock: ClockLike) -> LabCamera:
    return LabCamera(clock)


LAB_CAMERA = CameraBackend(_open_lab_camera, "a lab's own camera")


@pytest.fixture
def lab_plugins(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Register LAB_STAGE under gonio.backends and LAB_CAMERA under gonio.cameras beside gonio's own."""
    rigs, cams = registry.BACKENDS.entry_points(), camera_registry.CAMERAS.entry_points()
    rigs["lab_stage"] = EntryPoint("lab_stage", f"{HERE}:LAB_STAGE", registry.GROUP)
    cams["lab_cam"] = EntryPoint("lab_cam", f"{HERE}:LAB_CAMERA", camera_registry.GROUP)
    monkeypatch.setattr(registry.BACKENDS, "entry_points", lambda: rigs)
    monkeypatch.setattr(camera_registry.CAMERAS, "entry_points", lambda: cams)
    registry.reload()
    camera_registry.reload()
    yield
    monkeypatch.undo()
    registry.reload()
    camera_registry.reload()


def test_gonio_registers_its_own_backends_through_its_entry_points() -> None:
    assert registry.names()[:3] == ("simulated", "dynamixel", "grbl")
    assert backend("grbl").coordinated and backend("grbl").addressing == "letter"
    assert not backend("simulated").needs_port and backend("simulated").cameras == ("simulated",)
    assert {"folder", "opencv"} <= set(camera_registry.names())


def test_an_unregistered_kind_is_an_error_naming_the_registered_ones() -> None:
    with pytest.raises(ConfigError, match=r"link\.kind = 'grlb': expected a value 'simulated', 'dynamixel' or 'grbl'"):
        rig_config(parse({"link": {"kind": "grlb"}}, RigFile, "lab.toml"), "lab.toml")
    with pytest.raises(registry.BackendError, match=r"no rig backend 'grlb' .*did you mean 'grbl'"):
        backend("grlb")


def test_a_lab_stage_registered_elsewhere_runs_a_sweep(lab_plugins: None, tmp_path: Path) -> None:
    rig = sim_rig(link={"kind": "lab_stage"})
    assert rig.file.link.kind == "lab_stage"
    summary = start_run(rig, in_plane_sweep([30.0], [0.0, 20.0]), tmp_path / "run", progress=False)
    assert opened == ["lab_stage"]
    rows = read_rows(summary.table)
    assert len(rows) == 2 and all(float(r["brdf_g"]) > 0 for r in rows)


def test_a_lab_camera_registered_elsewhere_is_selectable_and_opened(lab_plugins: None) -> None:
    doc = {"link": {"kind": "dynamixel", "port": "/dev/null"}, "reference": {"kind": "none"},
           "camera": {"backend": "lab_cam"},
           "axes": {j: {"id": i} for i, j in enumerate(("light", "camera", "tilt", "roll"), 1)}}  # fmt: skip
    rig = rig_config(parse(doc, RigFile, "lab.toml"), "lab.toml")
    camera = open_camera(rig, ManualClock())
    assert isinstance(camera, LabCamera)
    with pytest.raises(ConfigError, match=r"camera\.backend = 'lab_cma': expected a value .*'lab_cam'"):
        parse({**doc, "camera": {"backend": "lab_cma"}}, RigFile, "lab.toml")


def test_a_broken_plugin_names_itself(monkeypatch: pytest.MonkeyPatch) -> None:
    rigs = {**registry.BACKENDS.entry_points(), "broken": EntryPoint("broken", "no_such_module_here:X", registry.GROUP)}
    monkeypatch.setattr(registry.BACKENDS, "entry_points", lambda: rigs)
    registry.reload()
    try:
        with pytest.raises(registry.BackendError, match=r"rig backend 'broken' \(no_such_module_here:X\) cannot be"):
            backend("broken")
    finally:
        monkeypatch.undo()
        registry.reload()
