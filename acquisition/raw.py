"""Decode camera files into linear, unscaled ``Frame`` objects: RAW through rawpy, TIFF, 8-bit images.

What the HDR merge needs from a file is the sensor counts exactly as the ADC delivered them, the black
and white levels, the CFA layout and the exposure the camera says it used. ``read_raw`` gives exactly
that (``raw_image_visible`` with ``black_level_per_channel`` mapped to CFA positions); ``bin_bayer``
turns such a mosaic into a half-size linear RGB image without interpolation, which is what the merge
uses. ``demosaic_linear`` is for full-resolution images: LibRaw's pipeline with every non-linear step
turned off, and bilinear interpolation because LibRaw's adaptive demosaicers (AHD, VNG, PPG, DHT) choose
interpolation directions from the data and so are not linear in the signal (measured: doubling a
mosaic doubled the AHD output to within quantisation at the median pixel, but single pixels moved by
more than 1500 counts of 65535).

``read_frame`` dispatches on the file extension and is what cameras that deliver files use.
"""

from __future__ import annotations

import errno
import io
import math
import os
import struct
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import rawpy
import tifffile

from acquisition.frame import Frame, FrameError, FrameKind

PathLike = str | os.PathLike[str]

DEFAULT_EXPOSURE_RTOL = 0.05
"""Relative tolerance between a requested and a reported exposure time.

Cameras report nominal shutter speeds (1/125 s is 2^-7 s = 0.0078 s on the sensor, 2.4 % off); a
frame from the wrong step of a bracket is at least a third of a stop (26 %) away."""

RAW_EXTENSIONS = frozenset(
    ".dng .kdc .dcr .cr2 .cr3 .crw .nef .nrw .arw .srf .sr2 .orf .rw2 .raf .pef .srw .erf .mrw .3fr "
    ".fff .iiq .mos .mef .rwl .x3f .raw".split()
)
TIFF_EXTENSIONS = frozenset({".tif", ".tiff"})
EIGHT_BIT_EXTENSIONS = frozenset({".png", ".jpg", ".jpeg"})
FRAME_EXTENSIONS = RAW_EXTENSIONS | TIFF_EXTENSIONS | EIGHT_BIT_EXTENSIONS

# Parameters that keep LibRaw's postprocess linear in the sensor counts (REFERENCE.md, HDR section):
# no gamma, no auto brightness, unit white balance, camera colour space, and no "adjust maximum"
# (its default 0.75 rescales any frame whose brightest pixel exceeds 75 % of the white level).
# user_flip=0 keeps the output aligned with the mosaic's pixel grid.
LINEAR_POSTPROCESS: Mapping[str, Any] = {
    "gamma": (1.0, 1.0),
    "no_auto_bright": True,
    "output_bps": 16,
    "user_wb": [1.0, 1.0, 1.0, 1.0],
    "output_color": rawpy.ColorSpace.raw,
    "adjust_maximum_thr": 0.0,
    "user_flip": 0,
}

_RAW_ERRORS: tuple[type[BaseException], ...] = (rawpy.LibRawError, rawpy.NotSupportedError)


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


def _resolve_exposure(
    reported_s: float | None,
    exposure_s: float | None,
    expected_exposure_s: float | None,
    rtol: float,
    where: str,
) -> tuple[float, str]:
    """Pick the exposure to record: the file's metadata, else the caller's fallback; then check it."""
    if reported_s is not None and math.isfinite(reported_s) and reported_s > 0:
        value, source = float(reported_s), "metadata"
    elif exposure_s is not None:
        value, source = float(exposure_s), "caller"
    else:
        raise FrameError(f"{where}: the file carries no exposure time; pass exposure_s= (seconds) if you know it")
    check_exposure(value, expected_exposure_s, where, rtol)
    return value, source


def cfa_pattern_string(raw_pattern: npt.ArrayLike, color_desc: bytes | str, where: str = "RAW") -> str:
    """Turn rawpy's ``raw_pattern`` (2x2 colour indices) and ``color_desc`` into a string like ``"RGGB"``."""
    pattern = np.asarray(raw_pattern)
    desc = color_desc.decode("ascii", "replace") if isinstance(color_desc, bytes) else color_desc
    if pattern.shape != (2, 2):
        raise FrameError(
            f"{where}: colour filter pattern of shape {pattern.shape} (e.g. X-Trans) is not a 2x2 Bayer "
            "pattern; use demosaic_linear() for a linear RGB image instead"
        )
    try:
        letters = "".join(desc[int(i)] for i in pattern.ravel())
    except IndexError:
        raise FrameError(f"{where}: colour indices {pattern.tolist()} do not fit colour description {desc!r}") from None
    if sorted(letters) != ["B", "G", "G", "R"]:
        raise FrameError(
            f"{where}: colour filter pattern {letters!r} is not a Bayer R/G/G/B layout; "
            "use demosaic_linear() for a linear image instead"
        )
    return letters


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


def _raw_extra(raw: rawpy.RawPy) -> dict[str, object]:
    other = raw.other
    extra: dict[str, object] = {
        "color_desc": raw.color_desc.decode("ascii", "replace"),
        "raw_pattern": None if raw.raw_pattern is None else np.asarray(raw.raw_pattern).tolist(),
        "aperture": float(other.aperture) or None,
        "focal_length_mm": float(other.focal_length) or None,
    }
    if other.timestamp is not None and other.timestamp.timestamp() != 0:  # LibRaw reports "unknown" as the epoch
        extra["datetime"] = other.timestamp.isoformat()
    return extra


def _open_raw(p: Path) -> rawpy.RawPy:
    try:
        return rawpy.imread(str(p))
    except _RAW_ERRORS as exc:
        raise FrameError(f"{p}: cannot decode as RAW: {type(exc).__name__}: {_msg(exc)}") from exc


def _msg(exc: BaseException) -> str:
    text = str(exc)
    if text.startswith(("b'", 'b"')):
        text = text[2:-1]
    return text


def _refine(meta: Mapping[str, Any], iso: float, shutter: float) -> tuple[float, float]:
    """Fill and sharpen LibRaw's ISO and shutter from the TIFF tags where the file has them."""
    if not iso > 0:
        # LibRaw reads ISO only from the EXIF IFD, not from IFD0 where TIFF/EP also allows it.
        iso = meta.get("ISOSpeedRatings", 0.0)
    exact = meta.get("ExposureTime")
    if exact and shutter > 0 and abs(exact - shutter) <= 1e-6 * exact:
        shutter = exact  # LibRaw stores the RATIONAL as float32; the tag has it exactly (1/250, not 0.0040000002)
    return iso, shutter


def _gain_from_iso(iso: float | None) -> float:
    return iso / 100.0 if iso is not None and math.isfinite(iso) and iso > 0 else 1.0


def read_raw(
    path: PathLike,
    *,
    exposure_s: float | None = None,
    expected_exposure_s: float | None = None,
    rtol: float = DEFAULT_EXPOSURE_RTOL,
    timestamp_s: float = 0.0,
) -> Frame:
    """Read any RAW that rawpy reads as a linear, unscaled Frame in sensor counts; exposures in seconds.

    Bayer sensors give a ``raw`` mosaic with ``black_level`` as four values in ``cfa_pattern`` order;
    monochrome sensors a 2-D ``linear`` frame; already-demosaiced (LinearRaw) files an (H, W, C)
    ``linear`` frame with one black level per channel. X-Trans and non-RGB mosaics raise FrameError
    (use ``demosaic_linear``). ``exposure_s`` is only a fallback for files without an exposure time;
    ``expected_exposure_s`` makes a disagreeing file an error.
    """
    p = _check_file(path, "RAW file")
    where = str(p)
    with _open_raw(p) as raw:
        try:
            n_colors = int(raw.num_colors)
            blacks = [float(b) for b in raw.black_level_per_channel]
            white = float(raw.white_level)
            if raw.raw_type == rawpy.RawType.Stack:
                data = np.array(raw.raw_image_visible[..., :n_colors], copy=True)
            else:
                data = np.array(raw.raw_image_visible, copy=True)
            pattern = None if raw.raw_pattern is None else np.array(raw.raw_pattern, copy=True)
            color_desc = bytes(raw.color_desc)
            shutter = float(raw.other.shutter_speed)
            iso = float(raw.other.iso_speed)
            extra = _raw_extra(raw)
        except _RAW_ERRORS as exc:
            raise FrameError(f"{p}: cannot decode RAW data: {type(exc).__name__}: {_msg(exc)}") from exc

    meta = _tiff_metadata(p)
    iso, shutter = _refine(meta, iso, shutter)
    value, source = _resolve_exposure(shutter if shutter > 0 else None, exposure_s, expected_exposure_s, rtol, where)
    extra.update(exposure_source=source, iso=iso or None)
    common: dict[str, Any] = {
        "exposure_s": value,
        "gain": _gain_from_iso(iso),
        "white_level": white,
        "timestamp_s": timestamp_s,
        "camera_id": camera_identity(meta),
        "source": where,
        "extra": extra,
    }
    if data.ndim == 3:
        return Frame(data=data, kind="linear", black_level=tuple(blacks[:n_colors]), **common)
    if n_colors == 1:
        return Frame(data=data, kind="linear", black_level=blacks[0], **common)
    if pattern is None:
        raise FrameError(f"{p}: RAW has {n_colors} colours but no colour filter pattern")
    cfa = cfa_pattern_string(pattern, color_desc, where)
    black = tuple(blacks[int(i)] for i in pattern.ravel())
    return Frame(data=data, kind="raw", black_level=black, cfa_pattern=cfa, **common)


def demosaic_linear(
    source: PathLike | rawpy.RawPy,
    *,
    exposure_s: float | None = None,
    expected_exposure_s: float | None = None,
    rtol: float = DEFAULT_EXPOSURE_RTOL,
    half_size: bool = False,
    demosaic_algorithm: rawpy.DemosaicAlgorithm | None = rawpy.DemosaicAlgorithm.LINEAR,
    timestamp_s: float = 0.0,
) -> Frame:
    """Demosaic a RAW (path or open ``rawpy.RawPy``) into a linear (H, W, 3) Frame; exposure in seconds.

    LibRaw subtracts the black level and scales by ``65535 / (white - black)``; the frame therefore has
    black 0 and white 65535, and ``extra["counts_per_output"]`` is the factor back to sensor counts.
    The default bilinear demosaic is linear in the signal; adaptive ones (AHD...) are not.
    """
    if isinstance(source, rawpy.RawPy):
        return _demosaic_open(
            source, None, exposure_s, expected_exposure_s, rtol, half_size, demosaic_algorithm, timestamp_s
        )
    p = _check_file(source, "RAW file")
    with _open_raw(p) as raw:
        return _demosaic_open(raw, p, exposure_s, expected_exposure_s, rtol, half_size, demosaic_algorithm, timestamp_s)


def _demosaic_open(
    raw: rawpy.RawPy,
    p: Path | None,
    exposure_s: float | None,
    expected_exposure_s: float | None,
    rtol: float,
    half_size: bool,
    demosaic_algorithm: rawpy.DemosaicAlgorithm | None,
    timestamp_s: float,
) -> Frame:
    where = str(p) if p is not None else "RAW image"
    try:
        blacks = [float(b) for b in raw.black_level_per_channel]
        white = float(raw.white_level)
        shutter = float(raw.other.shutter_speed)
        iso = float(raw.other.iso_speed)
        extra = _raw_extra(raw)
        rgb = raw.postprocess(demosaic_algorithm=demosaic_algorithm, half_size=half_size, **LINEAR_POSTPROCESS)
    except _RAW_ERRORS as exc:
        raise FrameError(f"{where}: cannot demosaic RAW: {type(exc).__name__}: {_msg(exc)}") from exc
    meta = _tiff_metadata(p) if p is not None else {}
    iso, shutter = _refine(meta, iso, shutter)
    value, source = _resolve_exposure(shutter if shutter > 0 else None, exposure_s, expected_exposure_s, rtol, where)
    # LibRaw scales by 65535 / (maximum - black) with its smallest black level (per-channel offsets are
    # subtracted on top), so this factor is exact for uniform black levels and within the spread otherwise.
    extra.update(exposure_source=source, iso=iso or None, counts_per_output=(white - min(blacks)) / 65535.0)
    return Frame(
        data=np.ascontiguousarray(rgb),
        kind="linear",
        exposure_s=value,
        gain=_gain_from_iso(iso),
        black_level=0.0,
        white_level=65535.0,
        timestamp_s=timestamp_s,
        camera_id=camera_identity(meta),
        source=str(p) if p is not None else None,
        extra=extra,
    )


def bin_bayer(frame: Frame) -> npt.NDArray[np.float64]:
    """Half-size linear RGB (H/2, W/2, 3) from a raw mosaic in counts above black: R, mean of the Gs, B per 2x2 cell.

    No interpolation and no clipping: black-subtracted values may be negative in the dark, which keeps
    averages unbiased. Odd trailing rows or columns are dropped.
    """
    where = frame.source or frame.camera_id
    if frame.kind != "raw" or frame.cfa_pattern is None:
        raise FrameError(f"{where}: bin_bayer needs a raw CFA mosaic, got kind={frame.kind!r}")
    cfa = frame.cfa_pattern
    if sorted(cfa) != ["B", "G", "G", "R"]:
        raise FrameError(f"{where}: bin_bayer needs a Bayer pattern with one R, two G and one B, got {cfa!r}")
    blacks = frame.black_level if isinstance(frame.black_level, tuple) else (frame.black_level,) * 4
    if len(blacks) != 4:
        raise FrameError(f"{where}: expected 1 or 4 black levels for a Bayer mosaic, got {len(blacks)}")
    h, w = (frame.data.shape[0] // 2) * 2, (frame.data.shape[1] // 2) * 2
    mosaic = np.asarray(frame.data[:h, :w], dtype=np.float64)
    planes = [mosaic[i // 2 :: 2, i % 2 :: 2] - blacks[i] for i in range(4)]
    out = np.empty((h // 2, w // 2, 3), dtype=np.float64)
    greens = [planes[i] for i in range(4) if cfa[i] == "G"]
    out[..., 0] = planes[cfa.index("R")]
    out[..., 1] = 0.5 * (greens[0] + greens[1])
    out[..., 2] = planes[cfa.index("B")]
    return out


def read_tiff(
    path: PathLike,
    *,
    exposure_s: float | None = None,
    expected_exposure_s: float | None = None,
    rtol: float = DEFAULT_EXPOSURE_RTOL,
    black_level: float = 0.0,
    timestamp_s: float = 0.0,
) -> Frame:
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
        return read_raw(
            p, exposure_s=exposure_s, expected_exposure_s=expected_exposure_s, rtol=rtol, timestamp_s=timestamp_s
        )
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
    value, source = _resolve_exposure(meta.get("ExposureTime"), exposure_s, expected_exposure_s, rtol, where)
    iso = meta.get("ISOSpeedRatings")
    return Frame(
        data=data,
        kind=kind,
        exposure_s=value,
        gain=_gain_from_iso(iso),
        black_level=float(black_level),
        white_level=white,
        timestamp_s=timestamp_s,
        camera_id=camera_identity(meta),
        source=where,
        extra={"exposure_source": source, "iso": iso},
    )


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


def read_8bit(
    path: PathLike,
    *,
    exposure_s: float | None = None,
    expected_exposure_s: float | None = None,
    rtol: float = DEFAULT_EXPOSURE_RTOL,
    timestamp_s: float = 0.0,
) -> Frame:
    """Read an 8-bit PNG or JPEG (OpenCV) as an ``8bit`` Frame in RGB order; exposure (seconds) from JPEG EXIF.

    PNG carries no exposure time: pass ``exposure_s``.
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
    value, source = _resolve_exposure(meta.get("ExposureTime"), exposure_s, expected_exposure_s, rtol, str(p))
    iso = meta.get("ISOSpeedRatings")
    return Frame(
        data=data,
        kind="8bit",
        exposure_s=value,
        gain=_gain_from_iso(iso),
        black_level=0.0,
        white_level=255.0,
        timestamp_s=timestamp_s,
        camera_id=camera_identity(meta),
        source=str(p),
        extra={"exposure_source": source, "iso": iso},
    )


def read_frame(
    path: PathLike,
    *,
    exposure_s: float | None = None,
    expected_exposure_s: float | None = None,
    rtol: float = DEFAULT_EXPOSURE_RTOL,
    timestamp_s: float = 0.0,
) -> Frame:
    """Read a RAW, TIFF, PNG or JPEG file into a Frame by its extension; exposures in seconds.

    ``exposure_s`` is used only when the file has no exposure time; ``expected_exposure_s`` raises
    FrameError when the file's exposure differs from it by more than ``rtol`` (relative).
    """
    p = Path(path)
    suffix = p.suffix.lower()
    kwargs: dict[str, Any] = {
        "exposure_s": exposure_s,
        "expected_exposure_s": expected_exposure_s,
        "rtol": rtol,
        "timestamp_s": timestamp_s,
    }
    if suffix in RAW_EXTENSIONS:
        return read_raw(p, **kwargs)
    if suffix in TIFF_EXTENSIONS:
        return read_tiff(p, **kwargs)
    if suffix in EIGHT_BIT_EXTENSIONS:
        return read_8bit(p, **kwargs)
    raw_list = ", ".join(sorted(RAW_EXTENSIONS))
    raise FrameError(
        f"{p}: unsupported file extension {p.suffix or '(none)'!r}; expected a RAW ({raw_list}), TIFF, PNG or JPEG file"
    )
