"""Decode camera RAW files through rawpy (LibRaw) into linear, unscaled ``Frame`` objects.

What the HDR merge needs from a file is the sensor counts exactly as the ADC delivered them, the black
and white levels, the CFA layout and the exposure the camera says it used. ``read_raw`` gives exactly
that (``raw_image_visible`` with ``black_level_per_channel`` mapped to CFA positions); ``bin_bayer``
turns such a mosaic into a half-size linear RGB image without interpolation, which is what the merge
uses. ``demosaic_linear`` is for full-resolution images: LibRaw's pipeline with every non-linear step
turned off, and bilinear interpolation because LibRaw's adaptive demosaicers (AHD, VNG, PPG, DHT) choose
interpolation directions from the data and so are not linear in the signal (measured: doubling a
mosaic doubled the AHD output to within quantisation at the median pixel, but single pixels moved by
more than 1500 counts of 65535).

TIFF and 8-bit images, and the ``read_frame`` dispatcher by extension, are in ``acquisition.files.images``.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import rawpy

from acquisition.files.metadata import NO_OPTIONS, PathLike, ReadOptions, _check_file, _tiff_metadata, frame_fields
from acquisition.frame import Frame, FrameError

RAW_EXTENSIONS = frozenset(
    ".dng .kdc .dcr .cr2 .cr3 .crw .nef .nrw .arw .srf .sr2 .orf .rw2 .raf .pef .srw .erf .mrw .3fr "
    ".fff .iiq .mos .mef .rwl .x3f .raw".split()
)

# Parameters that keep LibRaw's postprocess linear in the sensor counts:
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


def _raw_fields(
    meta: Mapping[str, Any],
    iso: float,
    shutter: float,
    options: ReadOptions,
    where: str,
    source: str | None,
    extra: dict[str, object],
) -> dict[str, Any]:
    """``frame_fields`` of a RAW: LibRaw's ISO and shutter filled and sharpened from the TIFF tags ``meta``."""
    if not iso > 0:
        # LibRaw reads ISO only from the EXIF IFD, not from IFD0 where TIFF/EP also allows it.
        iso = meta.get("ISOSpeedRatings", 0.0)
    exact = meta.get("ExposureTime")
    if exact and shutter > 0 and abs(exact - shutter) <= 1e-6 * exact:
        shutter = exact  # LibRaw stores the RATIONAL as float32; the tag has it exactly (1/250, not 0.0040000002)
    return frame_fields(options, meta, shutter if shutter > 0 else None, iso or None, where, source, extra)


def read_raw(path: PathLike, options: ReadOptions = NO_OPTIONS) -> Frame:
    """Read any RAW that rawpy reads as a linear, unscaled Frame in sensor counts; exposures in seconds.

    Bayer sensors give a ``raw`` mosaic with ``black_level`` as four values in ``cfa_pattern`` order;
    monochrome sensors a 2-D ``linear`` frame; already-demosaiced (LinearRaw) files an (H, W, C)
    ``linear`` frame with one black level per channel. X-Trans and non-RGB mosaics raise FrameError
    (use ``demosaic_linear``). ``options.exposure_s`` is only a fallback for files without an exposure time;
    ``options.expected_exposure_s`` makes a disagreeing file an error.
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

    common = _raw_fields(_tiff_metadata(p), iso, shutter, options, where, where, extra)
    common["white_level"] = white
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
    options: ReadOptions = NO_OPTIONS,
    *,
    half_size: bool = False,
    demosaic_algorithm: rawpy.DemosaicAlgorithm | None = rawpy.DemosaicAlgorithm.LINEAR,
) -> Frame:
    """Demosaic a RAW (path or open ``rawpy.RawPy``) into a linear (H, W, 3) Frame; exposure in seconds.

    LibRaw subtracts the black level and scales by ``65535 / (white - black)``; the frame therefore has
    black 0 and white 65535, and ``extra["counts_per_output"]`` is the factor back to sensor counts.
    The default bilinear demosaic is linear in the signal; adaptive ones (AHD...) are not.
    """
    if isinstance(source, rawpy.RawPy):
        return _demosaic_open(source, None, options, half_size, demosaic_algorithm)
    p = _check_file(source, "RAW file")
    with _open_raw(p) as raw:
        return _demosaic_open(raw, p, options, half_size, demosaic_algorithm)


def _demosaic_open(
    raw: rawpy.RawPy,
    p: Path | None,
    options: ReadOptions,
    half_size: bool,
    demosaic_algorithm: rawpy.DemosaicAlgorithm | None,
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
    fields = _raw_fields(meta, iso, shutter, options, where, str(p) if p is not None else None, extra)
    # LibRaw scales by 65535 / (maximum - black) with its smallest black level (per-channel offsets are
    # subtracted on top), so this factor is exact for uniform black levels and within the spread otherwise.
    fields["extra"]["counts_per_output"] = (white - min(blacks)) / 65535.0
    return Frame(data=np.ascontiguousarray(rgb), kind="linear", black_level=0.0, white_level=65535.0, **fields)


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
