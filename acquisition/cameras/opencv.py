"""UVC webcams (and video files or image sequences, for tests) through ``cv2.VideoCapture``; 8-bit frames.

Exposure control through OpenCV is backend specific, and this module only knows the backends below.
Values are what the OpenCV documentation and driver sources say; only the file backends are tested
here (no camera on the development machine):

=========  =================================  ================================================
backend    CAP_PROP_AUTO_EXPOSURE "manual"    CAP_PROP_EXPOSURE units
=========  =================================  ================================================
V4L2       1 (V4L2_EXPOSURE_MANUAL; 3 = auto)  V4L2 ``exposure_absolute``: 100 us steps
DSHOW      0.25 (0.75 = auto)                 log2 seconds, integer steps (-6 = 1/64 s)
MSMF       0.25 (0.75 = auto)                 log2 seconds, as DirectShow
=========  =================================  ================================================

V4L2 values assume OpenCV's default of unnormalised property ranges (the environment variable
``OPENCV_VIDEOIO_V4L_RANGE_NORMALIZED`` must not be set). After setting, the camera reads back
``CAP_PROP_EXPOSURE`` and reports what the driver says it applied, which is often a rounded value.

Gain: UVC defines no unit for gain, so ``gain`` is passed to ``CAP_PROP_GAIN`` in driver units and the
read-back value is kept in ``Frame.extra["driver_gain"]``; ``Frame.gain`` stays 1.

Stale frames: drivers queue several frames (V4L2 uses 4 buffers by default), so after any setting
change the next ``discard_frames`` frames were exposed with the old settings and are dropped.

Files and image sequences (``cv2.CAP_IMAGES`` with a ``frame_%03d.png`` pattern, or a video file) have
no exposure control: ``set_exposure`` records the request and frames carry
``extra["exposure_confirmed"] = False``; with ``strict=True`` it raises ExposureUnconfirmedError.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from acquisition.cameras import CameraError, ClockLike, ExposureUnconfirmedError, RealTimeClock
from acquisition.frame import ExposureSettings, Frame, FrameError


@dataclass(frozen=True)
class ExposureMapping:
    """How one OpenCV backend expresses manual exposure: the auto-exposure value for manual, and units."""

    manual_value: float
    to_driver: Callable[[float], float]
    from_driver: Callable[[float], float | None]
    description: str


def _log2_from_driver(v: float) -> float | None:
    return 2.0**v if math.isfinite(v) else None


def _v4l2_from_driver(v: float) -> float | None:
    return v * 1e-4 if math.isfinite(v) and v > 0 else None


EXPOSURE_MAPPINGS: dict[str, ExposureMapping] = {
    "V4L2": ExposureMapping(1.0, lambda s: round(s / 1e-4), _v4l2_from_driver, "exposure_absolute, 100 us units"),
    "DSHOW": ExposureMapping(0.25, lambda s: round(math.log2(s)), _log2_from_driver, "log2 seconds"),
    "MSMF": ExposureMapping(0.25, lambda s: round(math.log2(s)), _log2_from_driver, "log2 seconds"),
}
"""Known backends by ``VideoCapture.getBackendName()``; anything else cannot set exposure."""


class OpenCVCamera:
    """A camera or file read through ``cv2.VideoCapture``, delivering ``8bit`` RGB frames; exposures in seconds.

    Parameters
    ----------
    index_or_path:
        Device index (``0`` for the first camera), device path, video file, or image sequence pattern.
    backend:
        An OpenCV ``CAP_*`` backend constant (``cv2.CAP_V4L2``, ``cv2.CAP_DSHOW``, ``cv2.CAP_IMAGES``...);
        None lets OpenCV choose.
    discard_frames:
        Frames dropped after each setting change, because they were exposed before it.
    strict:
        Raise ExposureUnconfirmedError when the exposure cannot be set and read back, instead of
        delivering frames marked ``exposure_confirmed = False``.
    clock:
        Time source for frame timestamps (``rig.instrument.clock`` clocks fit); real time by default.
    camera_id:
        Identity to report; by default built from the backend and the source.
    """

    def __init__(
        self,
        index_or_path: int | str | os.PathLike[str],
        backend: int | None = None,
        *,
        discard_frames: int = 4,
        strict: bool = False,
        clock: ClockLike | None = None,
        camera_id: str | None = None,
    ) -> None:
        if discard_frames < 0:
            raise ValueError(f"OpenCVCamera: discard_frames = {discard_frames!r}, expected >= 0")
        self.source: int | str = index_or_path if isinstance(index_or_path, int) else os.fspath(index_or_path)
        self.discard_frames = int(discard_frames)
        self.strict = strict
        self.clock: ClockLike = clock if clock is not None else RealTimeClock()
        self.frames_read = 0
        """Frames taken from the device so far, discarded ones included."""
        requested_backend = cv2.CAP_ANY if backend is None else backend
        self._cap: Any = cv2.VideoCapture(self.source, requested_backend)
        if not self._cap.isOpened():
            self._cap.release()
            hint = ""
            if isinstance(self.source, str) and "%" not in self.source and not os.path.exists(self.source):
                hint = " (no such file)"
            raise CameraError(
                f"OpenCV cannot open camera {self.source!r}{hint} with backend "
                f"{_backend_label(requested_backend)}: no such device or file, device busy, or no permission"
            )
        self.backend_name: str = self._cap.getBackendName()
        self._mapping = EXPOSURE_MAPPINGS.get(self.backend_name)
        self._camera_id = camera_id or f"OpenCV {self.backend_name} camera {self.source}"
        self._exposure_s: float | None = None
        self._confirmed = False
        self._driver_exposure: float | None = None
        self._driver_gain: float | None = None
        self._pending_discard = 0

    @property
    def identity(self) -> str:
        """Backend and device or file, unless a ``camera_id`` was given."""
        return self._camera_id

    @property
    def exposure_confirmed(self) -> bool:
        """Whether the driver accepted the last exposure and reported it back."""
        return self._confirmed

    def set_exposure(self, exposure_s: float, gain: float | None = None) -> ExposureSettings:
        """Switch to manual exposure and request ``exposure_s`` seconds (and driver-unit ``gain``).

        Returns the exposure the driver reports back; when it cannot be set or read back (file
        backends, unknown backends) the request itself, unless ``strict`` makes that an error.
        """
        if not (math.isfinite(exposure_s) and exposure_s > 0):
            raise ValueError(f"{self.identity}: exposure {exposure_s!r} s is not a positive number of seconds")
        self._pending_discard = self.discard_frames
        mapping = self._mapping
        if mapping is None:
            if self.strict:
                raise ExposureUnconfirmedError(
                    f"{self.identity}: OpenCV backend {self.backend_name} has no known exposure control "
                    f"(known: {', '.join(EXPOSURE_MAPPINGS)}); cannot confirm {exposure_s:.6g} s"
                )
            self._set_unconfirmed(exposure_s, gain)
            return ExposureSettings(exposure_s, 1.0)
        cap = self._cap
        ok = bool(cap.set(cv2.CAP_PROP_AUTO_EXPOSURE, mapping.manual_value))
        ok = bool(cap.set(cv2.CAP_PROP_EXPOSURE, mapping.to_driver(exposure_s))) and ok
        if gain is not None:
            ok = bool(cap.set(cv2.CAP_PROP_GAIN, gain)) and ok
            self._driver_gain = float(cap.get(cv2.CAP_PROP_GAIN))
        self._driver_exposure = float(cap.get(cv2.CAP_PROP_EXPOSURE))
        actual = mapping.from_driver(self._driver_exposure)
        if not ok or actual is None:
            if self.strict:
                raise ExposureUnconfirmedError(
                    f"{self.identity}: the driver did not accept or report exposure {exposure_s:.6g} s "
                    f"(set returned {ok}, CAP_PROP_EXPOSURE reads {self._driver_exposure!r} in "
                    f"{mapping.description})"
                )
            self._set_unconfirmed(exposure_s, gain)
            return ExposureSettings(exposure_s, 1.0)
        self._exposure_s, self._confirmed = actual, True
        return ExposureSettings(actual, 1.0)

    def _set_unconfirmed(self, exposure_s: float, gain: float | None) -> None:
        self._exposure_s, self._confirmed = float(exposure_s), False
        if gain is not None:
            self._driver_gain = float(gain)

    def capture(self) -> Frame:
        """Drop stale frames after a setting change, then read one frame as an ``8bit`` RGB Frame."""
        if self._exposure_s is None:
            raise CameraError(f"{self.identity}: call set_exposure() first; the exposure of its frames is unknown")
        while self._pending_discard > 0:
            if not self._cap.grab():
                raise CameraError(
                    f"{self.identity}: no frame while discarding stale frames (camera unplugged or end of input)"
                )
            self.frames_read += 1
            self._pending_discard -= 1
        ok, image = self._cap.read()
        if not ok or image is None:
            raise CameraError(f"{self.identity}: no frame (camera unplugged or stopped, or end of the file/sequence)")
        self.frames_read += 1
        timestamp = self.clock.now()
        if image.dtype != np.uint8:
            raise FrameError(f"{self.identity}: frame of type {image.dtype}; only 8-bit frames are supported")
        if image.ndim == 3 and image.shape[-1] == 1:
            image = image[..., 0]
        elif image.ndim == 3:
            image = cv2.cvtColor(image, cv2.COLOR_BGRA2RGB if image.shape[-1] == 4 else cv2.COLOR_BGR2RGB)
        return Frame(
            data=image,
            kind="8bit",
            exposure_s=self._exposure_s,
            gain=1.0,
            black_level=0.0,
            white_level=255.0,
            timestamp_s=timestamp,
            camera_id=self.identity,
            source=self.source if isinstance(self.source, str) else None,
            extra={
                "exposure_confirmed": self._confirmed,
                "backend": self.backend_name,
                "driver_exposure": self._driver_exposure,
                "driver_gain": self._driver_gain,
                "frame_index": self.frames_read - 1,
            },
        )

    def close(self) -> None:
        """Release the device."""
        self._cap.release()

    def __enter__(self) -> OpenCVCamera:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_BACKEND_NAMES = ("CAP_V4L2", "CAP_DSHOW", "CAP_MSMF", "CAP_AVFOUNDATION", "CAP_GSTREAMER", "CAP_FFMPEG", "CAP_IMAGES")


def _backend_label(backend: int) -> str:
    if backend == cv2.CAP_ANY:
        return "CAP_ANY (OpenCV's choice)"
    names = [n for n in _BACKEND_NAMES if getattr(cv2, n, None) == backend]
    return names[0] if names else str(backend)
