"""File and metadata helpers shared by the frame readers: file checks, exposure checks, TIFF/EXIF tags, camera identity.

``ReadOptions`` is what a caller tells every reader about the frame it expects; ``check_exposure`` compares the
exposure a file reports with the one that was requested, and ``frame_fields`` picks which of the file's and the
caller's exposure to record and fills in what every reader's Frame takes from the metadata. ``_tiff_metadata``
reads identity and exposure tags from any TIFF-based file (TIFF, DNG and most RAW formats, JPEG EXIF),
and ``camera_identity`` turns them into a camera id string.
"""

from __future__ import annotations

import errno
import io
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import tifffile

from acquisition.frame import FrameError

PathLike = str | os.PathLike[str]

DEFAULT_EXPOSURE_RTOL = 0.05
"""Relative tolerance between a requested and a reported exposure time.

Cameras report nominal shutter speeds (1/125 s is 2^-7 s = 0.0078 s on the sensor, 2.4 % off); a
frame from the wrong step of a bracket is at least a third of a stop (26 %) away."""


def _check_file(path: PathLike, what: str) -> Path:
    p = Path(path)
    if not p.exists():
        raise FileNotFoundError(errno.ENOENT, f"{what} not found", str(p))
    if not p.is_file():
        raise FrameError(f"{p}: not a regular file (cannot read it as {what})")
    return p


def check_exposure(actual_s: float, expected_s: float | None, where: str, rtol: float = DEFAULT_EXPOSURE_RTOL) -> None:
    """Raise FrameError when exposure ``actual_s`` (seconds) differs from ``expected_s`` by more than ``rtol``."""
    if expected_s is None:
        return
    if not (math.isfinite(expected_s) and expected_s > 0):
        raise ValueError(f"{where}: expected exposure {expected_s!r} s is not a positive number of seconds")
    if abs(actual_s - expected_s) > rtol * expected_s:
        raise FrameError(
            f"{where}: exposure {actual_s:.6g} s in the file disagrees with the requested {expected_s:.6g} s "
            f"(ratio {actual_s / expected_s:.4g}, tolerance {rtol:.3g} relative)"
        )


@dataclass(frozen=True)
class ReadOptions:
    """What the caller knows of the frame a file holds: every frame reader takes one (exposures in seconds).

    ``exposure_s`` is recorded only for a file that carries no exposure time; ``expected_exposure_s`` makes a file
    whose exposure differs from it by more than ``rtol`` (relative) a FrameError; ``timestamp_s`` is the frame's
    time on the caller's clock.
    """

    exposure_s: float | None = None
    expected_exposure_s: float | None = None
    rtol: float = DEFAULT_EXPOSURE_RTOL
    timestamp_s: float = 0.0


#: A reader's options when the caller knows nothing of the frame.
NO_OPTIONS = ReadOptions()


def frame_fields(
    options: ReadOptions,
    meta: Mapping[str, Any],
    reported_s: float | None,
    iso: float | None,
    where: str,
    source: str | None,
    extra: Mapping[str, object] | None = None,
) -> dict[str, Any]:
    """The Frame fields a file's metadata gives: exposure (s, the file's, else the caller's; checked), gain, camera.

    Also the caller's time stamp, the ``source`` and ``extra`` with where the exposure came from and the ISO added.
    """
    if reported_s is not None and math.isfinite(reported_s) and reported_s > 0:
        value, how = float(reported_s), "metadata"
    elif options.exposure_s is not None:
        value, how = float(options.exposure_s), "caller"
    else:
        raise FrameError(f"{where}: the file carries no exposure time; pass exposure_s= (seconds) if you know it")
    check_exposure(value, options.expected_exposure_s, where, options.rtol)
    return {
        "exposure_s": value,
        "gain": _gain_from_iso(iso),
        "timestamp_s": options.timestamp_s,
        "camera_id": camera_identity(meta),
        "source": source,
        "extra": {**(extra or {}), "exposure_source": how, "iso": iso},
    }


def _tiff_metadata(path: Path | io.BytesIO) -> dict[str, Any]:
    """Identity and exposure tags from IFD0 and its EXIF IFD; empty for files that are not TIFF-based."""
    out: dict[str, Any] = {}
    try:
        with tifffile.TiffFile(path) as tif:
            tags = tif.pages.first.tags
            exif = tags.valueof("ExifTag", {}) or {}
            for key in ("Make", "Model", "UniqueCameraModel", "CameraSerialNumber", "BodySerialNumber"):
                value = exif.get(key) if key == "BodySerialNumber" else tags.valueof(key)
                if isinstance(value, str | bytes) and value.strip():
                    out[key] = (value.decode("ascii", "replace") if isinstance(value, bytes) else value).strip("\x00 ")
            for key, code in (("ExposureTime", 33434), ("ISOSpeedRatings", 34855)):
                value = exif.get(key, tags.valueof(code))
                if isinstance(value, tuple | list) and len(value) == 2 and key == "ExposureTime":
                    value = value[0] / value[1] if value[1] else None
                elif isinstance(value, tuple | list):
                    value = value[0] if value else None
                if value is not None:
                    out[key] = float(value)
    except Exception:  # metadata is best effort; the pixel decoder reports real damage
        return {}
    return out


def camera_identity(meta: Mapping[str, Any]) -> str:
    """Camera identity string from TIFF/DNG metadata (UniqueCameraModel, Make, Model, serial)."""
    make, model = meta.get("Make", ""), meta.get("Model", "")
    if model and make and model.split()[0].lower() in make.lower().split():
        name = model  # "Canon" + "Canon EOS R5", "Eastman Kodak Company" + "Kodak DC50": the model says it all
    else:
        name = f"{make} {model}".strip()
    name = name or meta.get("UniqueCameraModel", "")
    serial = meta.get("BodySerialNumber") or meta.get("CameraSerialNumber")
    if name and serial:
        name = f"{name} #{serial}"
    return name or "unknown"


def _gain_from_iso(iso: float | None) -> float:
    return iso / 100.0 if iso is not None and math.isfinite(iso) and iso > 0 else 1.0
