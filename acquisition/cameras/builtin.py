"""gonio's own camera backends as registered in ``gonio.cameras``: the tethered folder and OpenCV.

Each imports its library when a camera is opened, not when the registry is read.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from acquisition.cameras import ClockLike
from acquisition.cameras.registry import CameraBackend
from acquisition.frame import Camera


def _folder(settings: Mapping[str, Any], clock: ClockLike) -> Camera:
    from acquisition.cameras.tethered import TetheredFolderCamera

    return TetheredFolderCamera(Path(settings["folder"]), clock=clock)


def _opencv(settings: Mapping[str, Any], clock: ClockLike) -> Camera:
    from acquisition.cameras.opencv import OpenCVCamera

    return OpenCVCamera(settings["device"])


FOLDER = CameraBackend(_folder, "frames a tethering program writes into [camera] folder")
OPENCV = CameraBackend(_opencv, "a UVC camera (or video file) through OpenCV, [camera] device")
