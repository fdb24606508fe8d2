"""Read TIFF and 8-bit (PNG, JPEG) images into ``Frame`` objects, and dispatch any frame file by extension.

``read_frame`` dispatches on the file extension (RAW through ``acquisition.files.raw``, TIFF, PNG/JPEG) and
is what cameras that deliver files use.
"""

from __future__ import annotations

import io
import math
import struct
from pathlib import Path
from typing import Any

import numpy as np
import tifffile

from acquisition.files.metadata import NO_OPTIONS, PathLike, ReadOptions, _check_file, _tiff_metadata, frame_fields
from acquisition.files.raw import RAW_EXTENSIONS, read_raw
from acquisition.frame import Frame, FrameError, FrameKind

TIFF_EXTENSIONS = frozenset({".tif", ".tiff"})
EIGHT_BIT_EXTENSIONS = frozenset({".png", ".jpg", ".jpeg"})
FRAME_EXTENSIONS = RAW_EXTENSIONS | TIFF_EXTENSIONS | EIGHT_BIT_EXTENSIONS


def read_tiff(path: PathLike, options: ReadOptions = NO_OPTIONS, *, black_level: float = 0.0) -> Frame:
    """Read a TIFF: 16-bit or float as ``linear``, 8-bit as ``8bit``; exposure (seconds) from EXIF ExposureTime.

    A TIFF holding a CFA mosaic or DNG tags is decoded by ``read_raw``. Tethering software writes linear
    TIFFs black-subtracted, hence the default ``black_level`` of 0 counts. Colour data is RGB order.
    """
    p = _check_file(path, "TIFF file")
    where = str(p)
    try:
        with tifffile.TiffFile(p) as tif:
            page = tif.pages.first
            is_raw = page.photometric == tifffile.PHOTOMETRIC.CFA or "DNGVersion" in page.tags
            max_sample = page.tags.valueof("MaxSampleValue")
            data = None if is_raw else page.asarray()
    except (tifffile.TiffFileError, ValueError, OSError, struct.error) as exc:
        raise FrameError(f"{p}: cannot decode as TIFF: {type(exc).__name__}: {exc}") from exc
    if is_raw or data is None:
        return read_raw(p, options)
    meta = _tiff_metadata(p)
    if data.ndim == 3 and data.shape[-1] == 4:
        data = data[..., :3]  # drop alpha
    if data.ndim not in (2, 3) or (data.ndim == 3 and data.shape[-1] != 3):
        raise FrameError(f"{p}: TIFF of shape {data.shape} is neither a single image plane nor RGB")
    kind: FrameKind
    if data.dtype == np.uint8:
        kind, white = "8bit", 255.0
    elif data.dtype in (np.uint16, np.uint32):
        kind, white = "linear", float(np.iinfo(data.dtype).max)
        if isinstance(max_sample, int | float) and max_sample > 0:
            white = float(max_sample)
        elif isinstance(max_sample, tuple) and max_sample:
            white = float(max(max_sample))
    elif np.issubdtype(data.dtype, np.floating):
        kind, white = "linear", math.inf  # a float image has no ADC ceiling
    else:
        raise FrameError(f"{p}: TIFF sample type {data.dtype} is not supported (8/16/32-bit unsigned or float)")
    return _exif_frame(data, kind, float(black_level), white, meta, options, where)


def _exif_frame(
    data: np.ndarray,
    kind: FrameKind,
    black: float,
    white: float,
    meta: dict[str, Any],
    options: ReadOptions,
    where: str,
) -> Frame:
    """A decoded image as a Frame whose exposure, gain and camera come from the file's EXIF tags ``meta``."""
    fields = frame_fields(options, meta, meta.get("ExposureTime"), meta.get("ISOSpeedRatings"), where, where)
    return Frame(data=data, kind=kind, black_level=black, white_level=white, **fields)


def _jpeg_exif(p: Path) -> dict[str, Any]:
    """EXIF of a JPEG: the APP1 payload is a TIFF structure, which tifffile parses."""
    try:
        blob = p.read_bytes()
    except OSError:
        return {}
    if blob[:2] != b"\xff\xd8":
        return {}
    pos = 2
    while pos + 4 <= len(blob) and blob[pos] == 0xFF:
        marker = blob[pos + 1]
        length = int.from_bytes(blob[pos + 2 : pos + 4], "big")
        if marker == 0xE1 and blob[pos + 4 : pos + 10] == b"Exif\x00\x00":
            return _tiff_metadata(io.BytesIO(blob[pos + 10 : pos + 2 + length]))
        if marker == 0xDA:  # start of scan: no metadata after this
            break
        pos += 2 + length
    return {}


def read_8bit(path: PathLike, options: ReadOptions = NO_OPTIONS) -> Frame:
    """Read an 8-bit PNG or JPEG (OpenCV) as an ``8bit`` Frame in RGB order; exposure (seconds) from JPEG EXIF.

    PNG carries no exposure time: pass ``ReadOptions(exposure_s=...)``.
    """
    import cv2  # deferred: OpenCV is slow to import and only 8-bit images need it

    p = _check_file(path, "image file")
    data = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if data is None:
        raise FrameError(f"{p}: OpenCV cannot decode this file as an image (corrupt or unsupported)")
    if data.dtype != np.uint8:
        raise FrameError(
            f"{p}: {data.dtype} image; only 8-bit PNG/JPEG are read (their encoding is a display curve). "
            "Save linear data as 16-bit TIFF or DNG"
        )
    if data.ndim == 3:
        data = cv2.cvtColor(data, cv2.COLOR_BGRA2RGB if data.shape[-1] == 4 else cv2.COLOR_BGR2RGB)
    meta = _jpeg_exif(p) if p.suffix.lower() in (".jpg", ".jpeg") else {}
    return _exif_frame(data, "8bit", 0.0, 255.0, meta, options, str(p))


def read_frame(path: PathLike, options: ReadOptions = NO_OPTIONS) -> Frame:
    """Read a RAW, TIFF, PNG or JPEG file into a Frame by its extension; exposures in seconds.

    ``options.exposure_s`` is used only when the file has no exposure time; ``options.expected_exposure_s`` raises
    FrameError when the file's exposure differs from it by more than ``options.rtol`` (relative).
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in RAW_EXTENSIONS:
        return read_raw(p, options)
    if suffix in TIFF_EXTENSIONS:
        return read_tiff(p, options)
    if suffix in EIGHT_BIT_EXTENSIONS:
        return read_8bit(p, options)
    raw_list = ", ".join(sorted(RAW_EXTENSIONS))
    raise FrameError(
        f"{p}: unsupported file extension {p.suffix or '(none)'!r}; expected a RAW ({raw_list}), TIFF, PNG or JPEG file"
    )
