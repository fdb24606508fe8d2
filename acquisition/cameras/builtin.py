"""gonio's own camera backends as registered in ``gonio.cameras``: tethered folder, OpenCV, gphoto2, GenICam.

Each imports its library when a camera is opened, not when the registry is read. ``keys`` (and ``required``)
are the one list of the ``[camera]`` keys each reads: config validation derives from them which backend may
set which key (the keys' types and bounds are ``rig.run.config.camera.Camera``'s); a key left out of a rig file
arrives as None and the backend's own default applies.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from acquisition.cameras import ClockLike
from acquisition.cameras.registry import CameraBackend
from acquisition.frame import Camera


def _given(settings: Mapping[str, Any], *keys: str) -> dict[str, Any]:
    """The keys a rig file set (not None), for a constructor whose own defaults stand for the rest."""
    return {k: settings[k] for k in keys if settings.get(k) is not None}


def _folder(settings: Mapping[str, Any], clock: ClockLike) -> Camera:
    from acquisition.cameras.tethered import TetheredFolderCamera
    from acquisition.cameras.trigger import CommandTrigger, load_callable

    trigger = settings.get("trigger")
    if isinstance(trigger, str):
        trigger = load_callable(trigger)
    elif trigger is not None:
        timeout = settings.get("trigger_timeout_s")
        trigger = CommandTrigger(trigger) if timeout is None else CommandTrigger(trigger, timeout_s=timeout)
    options = _given(settings, "timeout_s", "poll_interval_s", "stable_polls", "settle_s",
                     "accept_unconfirmed_exposure")  # fmt: skip
    if settings.get("pattern") is not None:
        options["pattern"] = tuple(settings["pattern"])
    return TetheredFolderCamera(Path(settings["folder"]), clock=clock, trigger=trigger, **options)


#: ``[camera] api`` names of OpenCV's capture backends.
OPENCV_APIS = ("any", "v4l2", "images", "ffmpeg", "gstreamer")


def _opencv(settings: Mapping[str, Any], clock: ClockLike) -> Camera:
    import cv2

    from acquisition.cameras.opencv import OpenCVCamera

    api = settings.get("api") or "any"
    backend = {"any": None, "v4l2": cv2.CAP_V4L2, "images": cv2.CAP_IMAGES, "ffmpeg": cv2.CAP_FFMPEG,
               "gstreamer": cv2.CAP_GSTREAMER}[api]  # fmt: skip
    device = settings.get("device")
    return OpenCVCamera(0 if device is None else device, backend, clock=clock,
                        **_given(settings, "discard_frames", "strict"))  # fmt: skip


def _gphoto2(settings: Mapping[str, Any], clock: ClockLike) -> Camera:
    from acquisition.cameras.gphoto2 import GPhoto2Camera

    return GPhoto2Camera(clock=clock, **_given(settings, "port", "model", "download_dir", "keep_on_camera"))


def _genicam(settings: Mapping[str, Any], clock: ClockLike) -> Camera:
    from acquisition.cameras.genicam import GenICamCamera

    options = _given(settings, "serial_number", "index", "discard_frames", "timeout_s", "pixel_format", "strict")
    return GenICamCamera(settings["cti_file"], clock=clock, **options)


FOLDER = CameraBackend(
    _folder, "frames a tethering program writes into [camera] folder, shot by an optional trigger",
    keys=("folder", "trigger", "trigger_timeout_s", "pattern", "timeout_s", "poll_interval_s", "stable_polls",
          "settle_s", "accept_unconfirmed_exposure"),
    required=("folder",),
)  # fmt: skip
OPENCV = CameraBackend(_opencv, "a UVC camera, video file or image sequence through OpenCV, [camera] device",
                       keys=("device", "api", "discard_frames", "strict"))  # fmt: skip
GPHOTO2 = CameraBackend(_gphoto2, "a still camera through libgphoto2 (pip install 'gonio[gphoto2]')",
                        keys=("port", "model", "download_dir", "keep_on_camera"))  # fmt: skip
GENICAM = CameraBackend(_genicam, "a GenICam camera through a GenTL producer (pip install 'gonio[genicam]')",
                        keys=("cti_file", "serial_number", "index", "discard_frames", "timeout_s", "pixel_format",
                              "strict"),
                        required=("cti_file",))  # fmt: skip
