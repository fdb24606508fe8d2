"""Still cameras over USB (PTP) through libgphoto2 and its Python binding; extra ``gonio[gphoto2]``.

Tested against libgphoto2 itself (the python-gphoto2 wheel's, 2.5.34) through its "Directory Browse"
driver on a ``disk:`` port, which serves a folder as a camera: choosing a camera by port and model,
downloading a file (``file_get``), decoding and checking it, deleting it from the "card", and the errors
of a driver that has no settings or no remote capture. UNTESTED WITHOUT A CAMERA (no driver that needs no
camera captures or has settings): ``capture`` on a real camera and setting shutter speed and ISO through
``get_config``/``set_config``. The pure helpers (shutter-speed parsing, nearest choice) are tested.

The camera must be set to save RAW only (not RAW+JPEG: ``capture`` then reports only one of the two
files) and to manual exposure mode (M), so that shutter speed and ISO are settable.
"""

from __future__ import annotations

import math
import re
import tempfile
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path
from typing import Any

from acquisition.cameras import CameraError, ClockLike, RealTimeClock, import_backend
from acquisition.files.images import read_frame
from acquisition.files.metadata import DEFAULT_EXPOSURE_RTOL, ReadOptions
from acquisition.frame import ExposureSettings, Frame

_SHUTTER_RE = re.compile(r"^\s*(\d+(?:\.\d+)?)\s*(?:/\s*(\d+(?:\.\d+)?))?\s*(?:s|sec|\"|'')?\s*$", re.IGNORECASE)


def parse_shutter_speed(text: str) -> float:
    """Seconds from a gphoto2 shutter-speed choice: ``"1/250"`` -> 0.004, ``"2.5"``, ``"30s"``, ``'2"'``.

    Raises ValueError for choices that are not a time (``"bulb"``, ``"auto"``, ``"x 1/200"``...).
    """
    match = _SHUTTER_RE.match(text.replace(",", "."))
    if not match:
        raise ValueError(f"shutter speed {text!r} is not a time in seconds (like '1/250', '0.5' or '30')")
    num = float(match.group(1))
    den = float(match.group(2)) if match.group(2) else 1.0
    if num <= 0 or den <= 0:
        raise ValueError(f"shutter speed {text!r} is not a positive time")
    return num / den


def parse_iso(text: str) -> float:
    """ISO number from a gphoto2 ISO choice: ``"100"``, ``"ISO 400"``; ValueError for ``"Auto"`` and the like."""
    match = re.fullmatch(r"\s*(?:iso\s*)?(\d+(?:\.\d+)?)\s*", text, re.IGNORECASE)
    if not match or float(match.group(1)) <= 0:
        raise ValueError(f"ISO choice {text!r} is not a number")
    return float(match.group(1))


def nearest_choice(requested: float, choices: Iterable[str], parse: Any = parse_shutter_speed) -> tuple[str, float]:
    """The choice whose parsed value is nearest to ``requested`` in log scale (stops); returns (choice, value)."""
    best: tuple[float, str, float] | None = None
    for choice in choices:
        try:
            value = parse(choice)
        except ValueError:
            continue
        distance = abs(math.log2(value / requested))
        if best is None or distance < best[0]:
            best = (distance, choice, value)
    if best is None:
        raise ValueError(f"no usable choice near {requested!r} among {list(choices)!r}")
    return best[1], best[2]


def _entry(gp: Any, listing: Any, lookup: str, key: str) -> Any | None:
    """What libgphoto2's ``listing`` (loaded here) holds for ``key`` by its method ``lookup``; None if nothing."""
    listing.load()
    try:
        index = getattr(listing, lookup)(key)
    except gp.GPhoto2Error:
        return None
    return listing[index] if index >= 0 else None


class GPhoto2Camera:
    """A still camera driven through libgphoto2: set shutter speed and ISO, capture, download, decode.

    UNTESTED WITHOUT HARDWARE. Exposure in seconds is mapped to the nearest shutter speed the camera
    offers (the returned ``ExposureSettings`` says which); gain to the nearest ISO / 100. Each capture
    is downloaded into ``download_dir`` (a temporary folder by default), decoded with ``read_frame`` and
    checked against the applied exposure; ``keep_on_camera=False`` deletes it from the card.
    """

    def __init__(
        self,
        *,
        download_dir: str | Path | None = None,
        keep_on_camera: bool = False,
        clock: ClockLike | None = None,
        exposure_rtol: float = DEFAULT_EXPOSURE_RTOL,
        shutter_config: tuple[str, ...] = ("shutterspeed", "shutterspeed2", "exposuretime"),
        iso_config: tuple[str, ...] = ("iso", "isospeed"),
        port: str | None = None,
        model: str | None = None,
    ) -> None:
        gp = import_backend("gphoto2", "gphoto2", "gphoto2")
        self._gp = gp
        self.clock: ClockLike = clock if clock is not None else RealTimeClock()
        self.exposure_rtol = exposure_rtol
        self.keep_on_camera = keep_on_camera
        self._shutter_config = shutter_config
        self._iso_config = iso_config
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        if download_dir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="gonio-gphoto2-")
            download_dir = self._tmp.name
        self.download_dir = Path(download_dir)
        self._camera: Any = gp.Camera()
        if port is not None or model is not None:
            self._choose(gp, port, model)
        try:
            self._camera.init()
        except gp.GPhoto2Error as exc:
            raise CameraError(f"gphoto2: no camera found or it is busy (another program holds it?): {exc}") from exc
        try:
            self._identity = str(self._camera.get_abilities().model)
        except gp.GPhoto2Error:
            self._identity = "gphoto2 camera"
        self._applied: ExposureSettings | None = None

    def _choose(self, gp: Any, port: str | None, model: str | None) -> None:
        """Use the camera on ``port`` ("usb:001,004", "disk:/folder") of driver ``model`` instead of autodetection."""
        if port is not None:
            ports = gp.PortInfoList()
            info = _entry(gp, ports, "lookup_path", port)
            if info is None:
                raise CameraError(f"gphoto2: no port {port!r} (libgphoto2 knows "
                                  f"{', '.join(ports[i].get_path() for i in range(len(ports)))})")  # fmt: skip
            self._camera.set_port_info(info)
        if model is not None:
            abilities = _entry(gp, gp.CameraAbilitiesList(), "lookup_model", model)
            if abilities is None:
                raise CameraError(f"gphoto2: libgphoto2 has no camera model {model!r} (as `gphoto2 --list-cameras` "
                                  "names them)")  # fmt: skip
            self._camera.set_abilities(abilities)

    @property
    def identity(self) -> str:
        """Camera model as libgphoto2 names it."""
        return self._identity

    def _widget(self, config: Any, names: tuple[str, ...]) -> Any:
        for name in names:
            try:
                return config.get_child_by_name(name)
            except self._gp.GPhoto2Error:
                continue
        raise CameraError(f"gphoto2 {self.identity}: none of the settings {names} exists (is the camera in M mode?)")

    def set_exposure(self, exposure_s: float, gain: float | None = None) -> ExposureSettings:
        """Set the shutter speed nearest to ``exposure_s`` seconds (and ISO nearest to 100 x gain); return them."""
        if not (math.isfinite(exposure_s) and exposure_s > 0):
            raise ValueError(f"gphoto2 {self.identity}: exposure {exposure_s!r} s is not a positive number")
        gp = self._gp
        try:
            config = self._camera.get_config()
            shutter = self._widget(config, self._shutter_config)
            choice, applied_s = nearest_choice(exposure_s, list(shutter.get_choices()))
            shutter.set_value(choice)
            applied_gain = self._applied.gain if self._applied else 1.0
            if gain is not None:
                iso_widget = self._widget(config, self._iso_config)
                iso_choice, iso = nearest_choice(100.0 * gain, list(iso_widget.get_choices()), parse_iso)
                iso_widget.set_value(iso_choice)
                applied_gain = iso / 100.0
            self._camera.set_config(config)
        except gp.GPhoto2Error as exc:
            unsupported = exc.code == gp.GP_ERROR_NOT_SUPPORTED
            hint = " (its driver has no settings: it cannot set an exposure)" if unsupported else ""
            message = f"gphoto2 {self.identity}: cannot set exposure {exposure_s:.6g} s: {exc}{hint}"
            raise CameraError(message) from exc
        self._applied = ExposureSettings(applied_s, applied_gain)
        return self._applied

    def capture(self) -> Frame:
        """Capture to the camera's card, download the file, decode it and check its exposure."""
        gp = self._gp
        try:
            path = self._camera.capture(gp.GP_CAPTURE_IMAGE)
        except gp.GPhoto2Error as exc:
            hint = " (its driver cannot capture remotely)" if exc.code == gp.GP_ERROR_NOT_SUPPORTED else ""
            raise CameraError(f"gphoto2 {self.identity}: capture failed: {exc}{hint}") from exc
        return self.download(path.folder, path.name)

    def download(self, folder: str, name: str) -> Frame:
        """Download the file ``folder``/``name`` from the camera, decode it and check its exposure (if one was set)."""
        gp = self._gp
        try:
            target = self.download_dir / name
            camera_file = self._camera.file_get(folder, name, gp.GP_FILE_TYPE_NORMAL)
            camera_file.save(str(target))
            if not self.keep_on_camera:
                self._camera.file_delete(folder, name)
        except gp.GPhoto2Error as exc:
            raise CameraError(f"gphoto2 {self.identity}: download of {folder}/{name} failed: {exc}") from exc
        expected = self._applied.exposure_s if self._applied else None
        options = ReadOptions(expected_exposure_s=expected, rtol=self.exposure_rtol, timestamp_s=self.clock.now())
        frame = read_frame(target, options)
        if frame.camera_id == "unknown":
            frame = replace(frame, camera_id=self.identity)
        return frame

    def close(self) -> None:
        """Release the camera and remove the temporary download folder."""
        try:
            self._camera.exit()
        finally:
            if self._tmp is not None:
                self._tmp.cleanup()
