"""A real camera's frame size for the geometry calibration is the size of the frames it delivers, not a rig file key."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from acquisition.board import ChArUcoBoard
from acquisition.frame import Frame
from rig.alignment import procedure
from rig.alignment.fit import CalibrationError
from rig.alignment.procedure import calibrate_geometry
from rig.run.config.files import load_rig

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"


class _Camera:
    """A camera that delivers flat grey frames of one size: the board is nowhere in them."""

    def __init__(self, width: int, height: int) -> None:
        self.shape = (height, width)
        self.exposure_s = 0.01
        self.frames = 0

    def set_exposure(self, seconds: float) -> None:
        self.exposure_s = seconds

    def capture(self) -> Frame:
        self.frames += 1
        data = np.full(self.shape, 512 + 2000, dtype=np.uint16)
        return Frame(data, "linear", self.exposure_s, black_level=512.0, white_level=16383.0)


class _Link:
    def __init__(self) -> None:
        self.at: dict[str, float] = {}
        self.stopped = False

    def move_to(self, joints: dict[str, float]) -> None:
        self.at = dict(joints)

    def wait_in_position(self, timeout_s: float) -> dict[str, float]:
        return self.at

    def shutdown(self, keep_torque: bool = False) -> None:
        self.stopped = True


class _Board:
    description = "mounted by the test"

    def __init__(self) -> None:
        self.mounted = False

    def present_board(self, board: ChArUcoBoard, alpha: float) -> None:
        self.mounted = True

    def withdraw_board(self) -> None:
        self.mounted = False


def _hardware(monkeypatch: pytest.MonkeyPatch, width: int, height: int) -> SimpleNamespace:
    inst = SimpleNamespace(camera=_Camera(width, height), link=_Link(), board=_Board())

    @contextlib.contextmanager
    def opened(rig: Any, start: Any = None) -> Iterator[SimpleNamespace]:
        yield inst

    monkeypatch.setattr(procedure, "instruments", opened)
    return inst


@pytest.mark.parametrize("example", ["rig_dynamixel.toml", "rig_grbl.toml"])
def test_a_folder_cameras_frames_too_small_for_the_board_are_refused_naming_their_size(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, example: str
) -> None:
    rig = load_rig(EXAMPLES / example)
    assert rig.file.camera.backend == "folder"
    inst = _hardware(monkeypatch, 160, 120)
    with pytest.raises(CalibrationError) as caught:
        calibrate_geometry(rig, tmp_path, captures=8, log=lambda _: None)
    message = str(caught.value)
    assert "camera delivered a frame of 160 x 120 px" in message and "resolution" not in message
    assert f"{example}" in message and "needs at least 20 px" in message
    need = int(message.split("whole frames of at least ")[1].split(" px")[0].split(" x ")[1])
    assert procedure.square_px(rig, ChArUcoBoard(), (need, need)) >= procedure.MIN_SQUARE_PX
    # Refused at its first frame, and the board is withdrawn and the axes stopped all the same.
    assert inst.link.stopped and not inst.board.mounted
    assert not (tmp_path / "geometry_calibration.json").exists()


def test_a_folder_camera_delivering_large_enough_frames_is_not_refused_for_their_size(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    rig = load_rig(EXAMPLES / "rig_dynamixel.toml")
    inst = _hardware(monkeypatch, 640, 480)
    # Past the size check, the calibration goes on through every board pose (and finds no board in grey frames).
    with pytest.raises(CalibrationError, match="the board was found in no capture"):
        calibrate_geometry(rig, tmp_path, captures=8, log=lambda _: None)
    assert inst.camera.frames >= 4 and inst.link.stopped and not inst.board.mounted
