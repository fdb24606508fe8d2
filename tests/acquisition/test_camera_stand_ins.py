"""Every camera backend chosen in a rig file, validated, opened and read against the most real stand-in here:

- folder: a trigger command (a real subprocess) that writes the DNG a tethering program would;
- opencv: an image sequence read by OpenCV's CAP_IMAGES (a V4L2 loopback needs a kernel module that a
  container cannot load);
- genicam: harvesters with the GenTL producer viky.cti that the genicam wheel ships (a simulated device);
- gphoto2: libgphoto2's "Directory Browse" driver on a disk: port (the one driver that needs no camera).
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from acquisition.cameras import CameraError
from acquisition.files.dng import write_dng
from acquisition.frame import Frame
from rig.instrument.clock import ManualClock, SystemClock
from rig.run.backends.hardware import open_camera
from rig.run.config.files import ConfigError, RigConfig, parse, rig_config
from rig.run.config.schema import RigFile


def _rig(camera: dict[str, Any]) -> RigConfig:
    doc = {"link": {"kind": "dynamixel", "port": "/dev/null"}, "reference": {"kind": "none"}, "camera": camera,
           "axes": {j: {"id": i} for i, j in enumerate(("light", "camera", "tilt", "roll"), 1)}}  # fmt: skip
    return rig_config(parse(doc, RigFile, "lab.toml"), "lab.toml")


def test_every_backend_is_selectable_and_its_keys_are_its_own() -> None:
    for backend, keys in (("gphoto2", {"port": "usb:"}), ("genicam", {"cti_file": "/x.cti"}),
                          ("opencv", {"device": "clip.mp4"}), ("folder", {"folder": "/tmp"})):  # fmt: skip
        assert _rig({"backend": backend, **keys}).file.camera.backend == backend
    with pytest.raises(ConfigError, match=r"lab\.toml: \[camera\] camera\.cti_file = '/x\.cti': the 'folder' camera "
                       r"backend does not read this key \(genicam reads it\); it reads folder, trigger"):  # fmt: skip
        _rig({"backend": "folder", "folder": "/tmp", "cti_file": "/x.cti"})
    with pytest.raises(ConfigError, match=r"the genicam camera backend needs cti_file: the GenTL producer"):
        _rig({"backend": "genicam"})
    with pytest.raises(ConfigError, match=r"camera\.api = 'v4l3': expected a value 'any', 'v4l2'"):
        _rig({"backend": "opencv", "api": "v4l3"})
    with pytest.raises(ConfigError, match=r"placeholder \{exposure\}; expected one of \{exposure_s\}"):
        _rig({"backend": "folder", "folder": "/tmp", "trigger": ["shoot", "{exposure}"]})
    with pytest.raises(ConfigError, match=r"camera\.spp = 8: the 'gphoto2' camera backend does not read this key"):
        _rig({"backend": "gphoto2", "spp": 8})


SHOOT = """import sys, numpy as np
from acquisition.files.dng import write_dng
folder, exposure, index = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
counts = np.full((24, 24), 64 + round(2e5 * exposure), dtype=np.uint16)
write_dng(f"{folder}/shot_{index:04d}.dng", counts, black_level=64, white_level=4095, exposure_s=exposure)
"""


def test_a_triggered_folder_camera_shoots_each_frame_at_its_exposure(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    script = tmp_path / "shoot.py"
    script.write_text(SHOOT)
    hot = tmp_path / "hot"
    hot.mkdir()
    trigger = [sys.executable, str(script), str(hot), "{exposure_s}", "{index}"]
    rig = _rig({"backend": "folder", "folder": str(hot), "trigger": trigger, "poll_interval_s": 0.01,
                "stable_polls": 1, "timeout_s": 120.0})  # fmt: skip
    # The script imports gonio like a lab's tethering helper would (installed, or from the checkout).
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(Path(__file__).resolve().parents[2]),
                                                      os.environ.get("PYTHONPATH", "")]))  # fmt: skip
    camera = open_camera(rig, SystemClock())
    frames: list[Frame] = []
    for t in (0.001, 0.004, 0.01):
        camera.set_exposure(t)
        frames.append(camera.capture())
    assert [f.exposure_s for f in frames] == pytest.approx([0.001, 0.004, 0.01])
    assert [int(f.data[0, 0]) - 64 for f in frames] == [200, 800, 2000]
    assert sorted(p.name for p in hot.iterdir()) == ["shot_0000.dng", "shot_0001.dng", "shot_0002.dng"]
    failing = _rig({"backend": "folder", "folder": str(hot), "trigger": [sys.executable, "-c", "exit(3)"]})
    camera = open_camera(failing, SystemClock())
    camera.set_exposure(0.01)
    with pytest.raises(CameraError, match=r"trigger command .* exited with status 3"):
        camera.capture()


def test_opencv_reads_an_image_sequence_chosen_in_a_rig_file(tmp_path: Path) -> None:
    for i in range(3):
        cv2.imwrite(str(tmp_path / f"frame_{i:03d}.png"), np.full((16, 20, 3), 40 * (i + 1), np.uint8))
    rig = _rig({"backend": "opencv", "device": str(tmp_path / "frame_%03d.png"), "api": "images",
                "discard_frames": 0})  # fmt: skip
    camera = open_camera(rig, ManualClock())
    camera.set_exposure(0.01)
    frames = [camera.capture() for _ in range(3)]
    assert [int(f.data[0, 0, 0]) for f in frames] == [40, 80, 120]
    assert frames[0].kind == "8bit" and frames[0].extra["exposure_confirmed"] is False
    camera.close()


def _viky() -> str:
    import genicam

    return os.path.join(os.path.dirname(genicam.__file__), "viky.cti")


def test_genicam_opens_the_viky_gentl_producer_and_fetches_frames() -> None:
    rig = _rig({"backend": "genicam", "cti_file": _viky(), "serial_number": "2", "pixel_format": "Mono8"})
    camera = open_camera(rig, ManualClock())
    try:
        assert camera.identity == "Machine Vision Games Ltd. Viky 2"
        assert camera.set_exposure(0.02).exposure_s == 0.02  # viky has no ExposureTime: recorded, unconfirmed
        frame = camera.capture()
        assert frame.kind == "linear" and frame.shape == (400, 400) and frame.white_level == 255.0
        assert frame.extra["exposure_confirmed"] is False and frame.data.dtype == np.uint8
    finally:
        camera.close()
    colour = open_camera(_rig({"backend": "genicam", "cti_file": _viky(), "index": 0, "pixel_format": "RGBa8",
                               "strict": True}), ManualClock())  # fmt: skip
    try:
        assert colour.capture().shape == (400, 400, 3)
        with pytest.raises(CameraError, match="no ExposureTime feature"):
            colour.set_exposure(0.01)
    finally:
        colour.close()
    with pytest.raises(CameraError, match=r"PixelFormat 'BayerRG12' not offered; the camera offers RGBa8, Mono8"):
        open_camera(_rig({"backend": "genicam", "cti_file": _viky(), "pixel_format": "BayerRG12"}), ManualClock())


def test_gphoto2_downloads_through_libgphoto2s_directory_driver(tmp_path: Path) -> None:
    card = tmp_path / "card"
    card.mkdir()
    mosaic = np.random.default_rng(1).integers(0, 4000, (24, 32), dtype=np.uint16)
    write_dng(card / "IMG_0001.dng", mosaic, black_level=64, white_level=4095, exposure_s=1 / 250, camera_id="Acme")
    rig = _rig({"backend": "gphoto2", "port": f"disk:{card}", "model": "Directory Browse",
                "download_dir": str(tmp_path / "got")})  # fmt: skip
    (tmp_path / "got").mkdir()
    camera = open_camera(rig, ManualClock())
    try:
        assert camera.identity == "Directory Browse"
        frame = camera.download("/", "IMG_0001.dng")  # type: ignore[attr-defined]
        assert np.array_equal(frame.data, mosaic) and frame.exposure_s == pytest.approx(1 / 250)
        assert not (card / "IMG_0001.dng").exists()  # taken off the "card" (keep_on_camera false)
        with pytest.raises(CameraError, match="cannot set an exposure"):
            camera.set_exposure(0.01)
        with pytest.raises(CameraError, match="cannot capture remotely"):
            camera.capture()
    finally:
        camera.close()
    with pytest.raises(CameraError, match=r"no camera model 'Nikon Z99'"):
        open_camera(_rig({"backend": "gphoto2", "port": f"disk:{card}", "model": "Nikon Z99"}), ManualClock())
