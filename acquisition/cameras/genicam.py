"""Machine-vision cameras (GenICam: GigE Vision, USB3 Vision; e.g. Basler, FLIR, Allied Vision) through
harvesters and the vendor's GenTL producer (.cti file); extra ``gonio[genicam]``.

Tested against a real GenTL stack: harvesters with the ``viky.cti`` producer that the ``genicam`` wheel
ships (a simulated "Viky" camera of three devices, RGBa8 or Mono8, 400 x 400, with no exposure or gain
feature): discovery, opening by serial number and index, pixel formats, acquisition and buffers, and a
camera without exposure control (unconfirmed frames, or ExposureUnconfirmedError with ``strict``).
Untested without hardware: writing ``ExposureTime`` (microseconds) and ``Gain`` (dB) on a camera that has
them (the SFNC names; older Basler models' ``ExposureTimeAbs``), Bayer and 10/12/16-bit formats from a
device, and ``BlackLevel``.
"""

from __future__ import annotations

import math
import os
import re
from typing import Any

import numpy as np

from acquisition.cameras import CameraError, ClockLike, ExposureUnconfirmedError, RealTimeClock, import_backend
from acquisition.frame import ExposureSettings, Frame, FrameError, FrameKind

_BAYER = {"RG": "RGGB", "GR": "GRBG", "GB": "GBRG", "BG": "BGGR"}


def parse_pixel_format(name: str) -> tuple[FrameKind, str | None, int]:
    """(kind, CFA pattern, bits) of a GenICam PixelFormat: ``"BayerRG12"`` -> ("raw", "RGGB", 12).

    ``Mono*`` is a linear single plane; ``RGB8``/``BGR8`` are 8-bit colour. Packed formats (``...p``,
    ``...Packed``) must be unpacked by the producer; they raise ValueError, like unknown formats.
    """
    match = re.fullmatch(r"(Bayer(RG|GR|GB|BG)|Mono)(\d+)", name)
    if match:
        bits = int(match.group(3))
        if match.group(2):
            return "raw", _BAYER[match.group(2)], bits
        return "linear", None, bits
    if name in ("RGB8", "BGR8", "RGB8Packed", "BGR8Packed", "RGBa8", "BGRa8"):
        return "8bit", None, 8
    raise ValueError(
        f"PixelFormat {name!r} is not supported (BayerXX8/10/12/16, Mono8/10/12/16, RGB8, BGR8, RGBa8, BGRa8; "
        "packed formats need unpacking in the GenTL producer)"
    )


class GenICamCamera:
    """A GenICam camera through harvesters: ExposureTime (us), Gain (dB), one buffer per capture.

    UNTESTED WITHOUT HARDWARE. ``gain`` is the linear factor of the Camera protocol and is written as
    ``20 log10(gain)`` dB. Acquisition runs continuously, so after a setting change ``discard_frames``
    buffers (exposed with the old settings) are dropped. Black level is reported as 0: machine-vision
    cameras add a small configurable offset (``BlackLevel``) that the HDR merge removes with dark frames.
    """

    def __init__(
        self,
        cti_file: str | os.PathLike[str],
        *,
        serial_number: str | None = None,
        index: int = 0,
        discard_frames: int = 2,
        timeout_s: float = 5.0,
        clock: ClockLike | None = None,
        pixel_format: str | None = None,
        strict: bool = False,
    ) -> None:
        core = import_backend("harvesters.core", "genicam", "GenICam (harvesters)")
        if not os.path.isfile(os.fspath(cti_file)):
            raise CameraError(f"GenICam: GenTL producer {os.fspath(cti_file)!r} is not a file (the vendor's .cti)")
        self.strict = strict
        self.clock: ClockLike = clock if clock is not None else RealTimeClock()
        self.timeout_s = timeout_s
        self.discard_frames = discard_frames
        self._pending_discard = 0
        self._harvester: Any = core.Harvester()
        self._harvester.add_file(os.fspath(cti_file))
        self._harvester.update()
        if not self._harvester.device_info_list:
            self._harvester.reset()
            raise CameraError(f"GenICam: no camera found through GenTL producer {cti_file}")
        try:
            self._ia: Any = self._harvester.create({"serial_number": serial_number} if serial_number else index)
        except Exception as exc:  # harvesters raises several unrelated types for "not found" / "busy"
            self._harvester.reset()
            raise CameraError(f"GenICam: cannot open camera {serial_number or index} via {cti_file}: {exc}") from exc
        nm = self._ia.remote_device.node_map
        names = ("DeviceVendorName", "DeviceModelName", "DeviceSerialNumber")
        self._identity = " ".join(str(getattr(nm, n).value) for n in names if hasattr(nm, n))
        if not self._identity:
            # Not every device has the SFNC's Device* features; the producer's device list names it all the same.
            info = self._ia.device.module
            parts = (getattr(info, k, "") for k in ("vendor", "model", "serial_number"))
            self._identity = " ".join(str(p) for p in parts if p) or "GenICam camera"
        for auto in ("ExposureAuto", "GainAuto"):
            if hasattr(nm, auto):
                getattr(nm, auto).value = "Off"
        if pixel_format is not None:
            choices = tuple(nm.PixelFormat.symbolics) if hasattr(nm, "PixelFormat") else ()
            if pixel_format not in choices:
                self.close()
                raise CameraError(f"GenICam {self._identity}: PixelFormat {pixel_format!r} not offered; "
                                  f"the camera offers {', '.join(choices) or 'none'}")  # fmt: skip
            nm.PixelFormat.value = pixel_format
        self._ia.start()
        self._confirmed = self._has_exposure()
        self._applied = ExposureSettings(self._read_exposure_s() if self._confirmed else 0.01, self._read_gain())

    @property
    def identity(self) -> str:
        """Vendor, model and serial number as the device reports them."""
        return self._identity

    def _has_exposure(self) -> bool:
        nm = self._ia.remote_device.node_map
        return any(hasattr(nm, n) for n in ("ExposureTime", "ExposureTimeAbs"))

    def _exposure_node(self) -> Any:
        nm = self._ia.remote_device.node_map
        # SFNC name first; older Basler GigE models call it ExposureTimeAbs
        for name in ("ExposureTime", "ExposureTimeAbs"):
            if hasattr(nm, name):
                return getattr(nm, name)
        raise CameraError(f"GenICam {self.identity}: no ExposureTime feature")

    def _read_exposure_s(self) -> float:
        return float(self._exposure_node().value) * 1e-6

    def _read_gain(self) -> float:
        nm = self._ia.remote_device.node_map
        return 10 ** (float(nm.Gain.value) / 20.0) if hasattr(nm, "Gain") else 1.0

    def set_exposure(self, exposure_s: float, gain: float | None = None) -> ExposureSettings:
        """Write ExposureTime (microseconds) and Gain (dB from the linear ``gain``); return the values read back."""
        if not (math.isfinite(exposure_s) and exposure_s > 0):
            raise ValueError(f"GenICam {self.identity}: exposure {exposure_s!r} s is not a positive number")
        if not self._has_exposure():
            if self.strict:
                raise ExposureUnconfirmedError(f"GenICam {self.identity}: the camera has no ExposureTime feature; "
                                               f"cannot set {exposure_s:.6g} s")  # fmt: skip
            # Like a file source: the request is recorded and frames say it is unconfirmed.
            self._pending_discard = self.discard_frames
            self._applied = ExposureSettings(float(exposure_s), self._read_gain())
            return self._applied
        self._exposure_node().value = exposure_s * 1e6
        if gain is not None:
            nm = self._ia.remote_device.node_map
            if not hasattr(nm, "Gain"):
                raise CameraError(f"GenICam {self.identity}: no Gain feature")
            nm.Gain.value = 20.0 * math.log10(gain)
        self._pending_discard = self.discard_frames
        self._applied = ExposureSettings(self._read_exposure_s(), self._read_gain())
        return self._applied

    def capture(self) -> Frame:
        """Fetch one buffer (after dropping stale ones), copy its pixels out and describe them."""
        while self._pending_discard > 0:
            with self._ia.fetch(timeout=self.timeout_s):
                pass
            self._pending_discard -= 1
        with self._ia.fetch(timeout=self.timeout_s) as buffer:
            component = buffer.payload.components[0]
            pixel_format = str(component.data_format)
            height, width = int(component.height), int(component.width)
            # the buffer returns to the producer's pool when the with-block ends: copy first
            data = np.array(component.data, copy=True)
            try:
                device_ts = buffer.timestamp_ns
            except Exception:  # GenTL raises NotAvailable where the device keeps no timestamps (viky.cti)
                device_ts = None
        try:
            kind, cfa, bits = parse_pixel_format(pixel_format)
        except ValueError as exc:
            raise FrameError(f"GenICam {self.identity}: {exc}") from exc
        channels = data.size // (height * width)
        data = data.reshape(height, width, channels) if channels > 1 else data.reshape(height, width)
        if channels == 4:
            data = np.ascontiguousarray(data[..., :3])  # RGBa8: the alpha plane is padding
        if pixel_format.startswith("BGR"):
            data = data[..., ::-1].copy()
        return Frame(
            data=data,
            kind=kind,
            exposure_s=self._applied.exposure_s,
            gain=self._applied.gain,
            black_level=(0.0,) * 4 if kind == "raw" else 0.0,
            white_level=float(2**bits - 1),
            cfa_pattern=cfa,
            timestamp_s=self.clock.now(),
            camera_id=self.identity,
            extra={"pixel_format": pixel_format, "device_timestamp_ns": device_ts,
                   "exposure_confirmed": self._has_exposure()},
        )

    def close(self) -> None:
        """Stop acquisition and release the device and the producer."""
        try:
            self._ia.stop()
            self._ia.destroy()
        finally:
            self._harvester.reset()
