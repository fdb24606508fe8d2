"""A run's manifest reads back as the rig and sweep it was started with, for every camera backend.

The manifest is written the way ``start_run`` writes it (``session.manifest`` through ``RunStore.create``) and read
the way ``gonio resume``, ``gonio analyze`` and ``gonio batch analyze`` read it (``RunStore.read`` and ``configs_of``).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rig.run.calibrate import CALIBRATION_FORMAT
from rig.run.config.files import RigConfig, load_rig, load_sweep
from rig.run.measuring.runner import RunOptions
from rig.run.session import capture_settings, configs_of, make_plan, manifest
from rig.run.storage.store import RunStore

SWEEP = """
[sweep]
kind = "in_plane"
theta_i_deg = [20.0]
theta_o_deg = [-40.0, 0.0, 40.0]
"""
HARDWARE = """
[link]
kind = "dynamixel"
port = "/dev/ttyUSB0"
[axes.light]
id = 1
[axes.camera]
id = 2
[axes.tilt]
id = 3
[axes.roll]
id = 4
[reference]
kind = "manual"
"""
#: Each backend's [camera] table as a rig file would give it: its own keys and none of the others'.
CAMERAS = {
    "folder": 'backend = "folder"\nfolder = "/srv/tether"\ntrigger = ["true", "{exposure_s}"]\nroi = [10, 10, 20, 20]',
    "opencv": 'backend = "opencv"\ndevice = 0\napi = "v4l2"\ndiscard_frames = 2',
    "gphoto2": 'backend = "gphoto2"\nport = "usb:001,004"\nkeep_on_camera = false',
    "genicam": 'backend = "genicam"\ncti_file = "/opt/vendor/producer.cti"\npixel_format = "BayerRG12"',
    "simulated": 'backend = "simulated"\nresolution = [48, 40]\nspp = 2',
}


def _rig_text(backend: str) -> str:
    link = "" if backend == "simulated" else HARDWARE
    return f"{link}\n[camera]\n{CAMERAS[backend]}\n"


def _round_trip(tmp_path: Path, rig_text: str) -> tuple[RigConfig, RigConfig, dict[str, object]]:
    """(rig as loaded, rig as read back from its run's manifest, the manifest's rig table)."""
    (tmp_path / "rig.toml").write_text(rig_text)
    (tmp_path / "sweep.toml").write_text(SWEEP)
    rig, sweep = load_rig(tmp_path / "rig.toml"), load_sweep(tmp_path / "sweep.toml")
    doc = manifest(rig, sweep, make_plan(rig, sweep), RunOptions())
    RunStore.create(tmp_path / "run", doc).close()
    back, back_sweep = configs_of(RunStore.read(tmp_path / "run"))
    assert back_sweep.file == sweep.file
    assert (back_sweep.directions_deg == sweep.directions_deg).all()
    return rig, back, doc["rig"]  # type: ignore[return-value]


@pytest.mark.parametrize("backend", sorted(CAMERAS))
def test_the_manifest_reads_back_as_the_rig_it_was_written_from(tmp_path: Path, backend: str) -> None:
    rig, back, table = _round_trip(tmp_path, _rig_text(backend))
    assert back.file == rig.file
    assert back.file.camera.model_fields_set == rig.file.camera.model_fields_set
    assert back.axes == rig.axes and back.geometry == rig.geometry
    assert table["camera"]["backend"] == backend  # type: ignore[index]
    # The simulated camera's keys are written only where the simulated camera reads them.
    assert ("resolution" in table["camera"]) == (backend == "simulated")  # type: ignore[operator]


def test_a_camera_calibration_without_noise_reads_back_without_noise(tmp_path: Path) -> None:
    # [camera.noise] beside a calibration is an error: a manifest that wrote the default noise was refused on resume.
    doc = {"format": CALIBRATION_FORMAT, "noise": {"e_per_dn": 2.5, "read_noise_e": 4.0}}
    (tmp_path / "camera_calibration.json").write_text(json.dumps(doc))
    rig_text = _rig_text("folder") + 'calibration = "camera_calibration.json"\n'
    rig, back, _ = _round_trip(tmp_path, rig_text)
    sweep = load_sweep(tmp_path / "sweep.toml")
    assert capture_settings(back, sweep).noise == capture_settings(rig, sweep).noise
    assert capture_settings(back, sweep).noise.e_per_dn == 2.5


def test_a_simulated_grbl_axis_homes_the_same_after_a_resume(tmp_path: Path) -> None:
    # A simulated GRBL axis without direction or zero_offset_deg is homed to its limit: the defaults written out
    # as if given turned the resumed run's tilt zero from its homing position to -180 deg.
    text = '[simulation]\nlink = "grbl"\n[axes.tilt]\nletter = "Z"\ngear_ratio = 3.0\n'
    rig, back, _ = _round_trip(tmp_path, text)
    assert back.axes == rig.axes
    assert rig.axes[2].zero_offset_deg != -180.0


def test_a_run_written_with_every_default_still_reads(tmp_path: Path) -> None:
    # Manifests written before only the given keys were kept hold the simulated camera's defaults in a folder
    # camera's table: they are dropped on reading, so those runs analyse and resume.
    rig, _, _ = _round_trip(tmp_path, _rig_text("folder"))
    path = tmp_path / "run" / "manifest.json"
    doc = json.loads(path.read_text())
    doc["rig"] = rig.file.model_dump(mode="json", exclude_none=True)
    assert doc["rig"]["camera"]["resolution"] == [32, 32]
    path.write_text(json.dumps(doc))
    back, _ = configs_of(RunStore.read(tmp_path / "run"))
    assert back.file == rig.file and back.axes == rig.axes


def test_a_curved_sample_reads_back_and_a_rig_without_one_writes_no_sample_key(tmp_path: Path) -> None:
    for name in ("sphere", "flat"):
        (tmp_path / name).mkdir()
    rig, back, table = _round_trip(tmp_path / "sphere", '[sample]\nshape = "sphere"\nradius_mm = 12.5\n')
    assert table["sample"] == {"shape": "sphere", "radius_mm": 12.5}
    assert back.sample_shape == rig.sample_shape and rig.sample_shape.radius_m == 0.0125
    # A rig file without [sample] writes the manifest it always wrote: no key for the default flat sample.
    _, flat, table = _round_trip(tmp_path / "flat", _rig_text("simulated"))
    assert "sample" not in table and flat.sample_shape.kind == "flat"
