"""Write a CFA mosaic as a minimal DNG that rawpy (LibRaw) reads back bit-exact, using tifffile alone.

The file is one uncompressed 16-bit IFD with photometric CFA (32803) and the DNG tags LibRaw needs:
CFARepeatPatternDim/CFAPattern, DNGVersion, UniqueCameraModel, BlackLevelRepeatDim/BlackLevel,
WhiteLevel, plus ColorMatrix1/CalibrationIlluminant1/AsShotNeutral, which the DNG specification
requires of colour cameras but which a linear decode never uses (identity matrix, unit neutral).

Things found by writing files and reading them back through rawpy 0.28 (LibRaw 0.22):

- ExposureTime (33434) is read by LibRaw from IFD0 (the TIFF/EP location) as well as from the EXIF
  IFD; ISO (34855) only from the EXIF IFD. tifffile refuses to write the ExifIFD pointer (34665), so
  the writer emits a placeholder tag, appends the EXIF IFD after the image and patches the pointer.
  ExposureTime goes into both places so readers that only look at one of them find it.
- LibRaw rejects images smaller than 22 x 22 pixels ("Unsupported file format").
- LibRaw stops treating a file as RAW when its Software tag starts with "Adobe", "dcraw", "UFRaw" or
  "Bibble"; the writer sets Software to "gonio".
- No Make tag is written: LibRaw keys vendor-specific quirks on Make. Model and UniqueCameraModel
  carry ``camera_id``.
- Black levels are written as a 2x2 repeat in CFA position order; rawpy reports them per colour index,
  ``black_level_per_channel[raw_pattern[i, j]]`` being the level at position (i, j).
"""

from __future__ import annotations

import math
import os
import struct
from collections.abc import Sequence
from fractions import Fraction
from pathlib import Path
from typing import BinaryIO

import numpy as np
import numpy.typing as npt
import tifffile

from acquisition.files.atomic import atomic_path
from acquisition.frame import Frame

PathLike = str | os.PathLike[str]

MIN_DNG_SIDE = 22
"""LibRaw refuses RAW images narrower or shorter than this many pixels."""

_CFA_CODES = {"R": 0, "G": 1, "B": 2}
_EXIF_PLACEHOLDER = 65000  # private tag code standing in for ExifIFD (34665) until the pointer is patched
_EXIF_IFD = 34665
_U32 = 2**32 - 1


def _rational(value: float) -> tuple[int, int]:
    """The closest fraction to ``value`` whose numerator and denominator fit TIFF's unsigned 32 bits."""
    max_den = _U32 if value <= 1 else max(1, int(_U32 / value))
    frac = Fraction(value).limit_denominator(max_den)
    if frac.numerator > _U32 or frac.numerator == 0:
        raise ValueError(f"{value!r} cannot be written as a TIFF RATIONAL")
    return frac.numerator, frac.denominator


def _as_count(value: float, what: str) -> int:
    if not (math.isfinite(value) and float(value).is_integer() and 0 <= value <= 65535):
        raise ValueError(f"write_dng: {what} = {value!r}, expected a whole number of counts in 0..65535")
    return int(value)


def _mosaic_u16(data: npt.ArrayLike) -> npt.NDArray[np.uint16]:
    arr = np.asarray(data)
    if arr.ndim != 2:
        raise ValueError(f"write_dng: a CFA mosaic must be 2-D, got shape {arr.shape}")
    if min(arr.shape) < MIN_DNG_SIDE:
        raise ValueError(
            f"write_dng: mosaic of shape {arr.shape} is too small; LibRaw refuses RAW images under "
            f"{MIN_DNG_SIDE} x {MIN_DNG_SIDE} pixels"
        )
    if arr.dtype == np.uint16:
        return np.ascontiguousarray(arr)
    if not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise ValueError(f"write_dng: mosaic dtype {arr.dtype} is not numeric")
    if not np.all(np.isfinite(arr)) or arr.min() < 0 or arr.max() > 65535:
        raise ValueError(
            f"write_dng: mosaic values span {arr.min()!r}..{arr.max()!r}; expected whole counts in 0..65535"
        )
    if np.issubdtype(arr.dtype, np.floating) and not np.array_equal(arr, np.round(arr)):
        raise ValueError("write_dng: mosaic has fractional values; round it to whole counts first")
    return np.ascontiguousarray(arr, dtype=np.uint16)


def _exif_ifd(offset: int, exposure: tuple[int, int], iso: int | None) -> bytes:
    """A little-endian EXIF IFD placed at ``offset``: ExposureTime, ISOSpeedRatings, ExifVersion."""
    entries: list[bytes] = []
    n = 2 + (iso is not None)
    data_offset = offset + 2 + 12 * n + 4
    entries.append(struct.pack("<HHII", 33434, 5, 1, data_offset))  # RATIONAL, stored after the IFD
    if iso is not None:
        entries.append(struct.pack("<HHIHH", 34855, 3, 1, iso, 0))  # SHORT, inline
    entries.append(struct.pack("<HHI", 36864, 7, 4) + b"0230")  # ExifVersion, UNDEFINED[4], inline
    return struct.pack("<H", n) + b"".join(entries) + struct.pack("<I", 0) + struct.pack("<II", *exposure)


def _attach_exif(fh: BinaryIO, exposure: tuple[int, int], iso: int | None) -> None:
    """Append the EXIF IFD and turn the placeholder tag in IFD0 into a sorted ExifIFD pointer."""
    fh.seek(0)
    header = fh.read(8)
    if header[:4] != b"II*\x00":
        raise RuntimeError("write_dng: expected a little-endian classic TIFF from tifffile")
    ifd0 = struct.unpack("<I", header[4:8])[0]
    fh.seek(ifd0)
    (count,) = struct.unpack("<H", fh.read(2))
    entries = [fh.read(12) for _ in range(count)]
    end = fh.seek(0, os.SEEK_END)
    if end % 2:  # TIFF offsets are word aligned
        fh.write(b"\x00")
        end += 1
    patched = []
    for entry in entries:
        if struct.unpack("<H", entry[:2])[0] == _EXIF_PLACEHOLDER:
            entry = struct.pack("<HHII", _EXIF_IFD, 4, 1, end)
        patched.append(entry)
    # moving 12-byte entries within the IFD keeps every out-of-line value offset valid
    patched.sort(key=lambda e: struct.unpack("<H", e[:2])[0])
    fh.write(_exif_ifd(end, exposure, iso))
    fh.seek(ifd0 + 2)
    fh.write(b"".join(patched))


def write_dng(
    path: PathLike,
    frame_or_mosaic: Frame | npt.ArrayLike,
    *,
    cfa_pattern: str | None = None,
    black_level: float | Sequence[float] | None = None,
    white_level: float | None = None,
    exposure_s: float | None = None,
    iso: float | None = None,
    camera_id: str | None = None,
) -> Path:
    """Write a CFA mosaic (counts, 0..65535) as an uncompressed 16-bit DNG, atomically; exposure in seconds.

    From a ``raw`` Frame every field comes from the frame (ISO = 100 x gain) unless given here. From an
    array, ``black_level``, ``white_level`` and ``exposure_s`` are required and ``cfa_pattern`` defaults
    to ``"RGGB"``. ``black_level`` is one value or four in CFA position order. Returns the path written.
    """
    if isinstance(frame_or_mosaic, Frame):
        frame = frame_or_mosaic
        if frame.kind != "raw":
            raise ValueError(f"write_dng: frame from {frame.source or frame.camera_id} is {frame.kind!r}, not raw")
        data = frame.data
        cfa_pattern = cfa_pattern or frame.cfa_pattern
        black_level = frame.black_level if black_level is None else black_level
        white_level = frame.white_level if white_level is None else white_level
        exposure_s = frame.exposure_s if exposure_s is None else exposure_s
        iso = round(100 * frame.gain) if iso is None else iso
        camera_id = frame.camera_id if camera_id is None else camera_id
    else:
        data = np.asarray(frame_or_mosaic)
        given = {"black_level": black_level, "white_level": white_level, "exposure_s": exposure_s}
        missing = [k for k, v in given.items() if v is None]
        if missing:
            raise ValueError(f"write_dng: {', '.join(missing)} required when writing a bare mosaic")
    cfa = (cfa_pattern or "RGGB").upper()
    if len(cfa) != 4 or sorted(cfa) != ["B", "G", "G", "R"]:
        raise ValueError(f"write_dng: cfa_pattern = {cfa_pattern!r}, expected a Bayer layout like 'RGGB'")
    mosaic = _mosaic_u16(data)
    assert black_level is not None and white_level is not None and exposure_s is not None
    blacks_in = [black_level] * 4 if isinstance(black_level, int | float) else list(black_level)
    if len(blacks_in) != 4:
        raise ValueError(f"write_dng: black_level needs 1 or 4 values (CFA order), got {len(blacks_in)}")
    blacks = [_as_count(b, "black_level") for b in blacks_in]
    white = _as_count(white_level, "white_level")
    if max(blacks) >= white:
        raise ValueError(f"write_dng: black level {blacks} is not below white level {white}")
    if not (math.isfinite(exposure_s) and exposure_s > 0):
        raise ValueError(f"write_dng: exposure_s = {exposure_s!r}, expected a positive number of seconds")
    exposure = _rational(float(exposure_s))
    iso_value = None
    if iso is not None:
        if not (math.isfinite(iso) and 1 <= iso <= 65535):
            raise ValueError(f"write_dng: iso = {iso!r}, expected 1..65535")
        iso_value = round(iso)
    model = (camera_id or "gonio camera").encode("ascii", "replace").decode("ascii")

    tags = [
        (272, "s", 0, model, True),  # Model
        (274, "H", 1, 1, True),  # Orientation: top-left, so no reader flips the mosaic
        (33421, "H", 2, (2, 2), True),  # CFARepeatPatternDim
        (33422, "B", 4, tuple(_CFA_CODES[c] for c in cfa), True),  # CFAPattern
        (33434, "2I", 1, exposure, True),  # ExposureTime (TIFF/EP location; also in the EXIF IFD)
        (50706, "B", 4, (1, 4, 0, 0), True),  # DNGVersion
        (50707, "B", 4, (1, 1, 0, 0), True),  # DNGBackwardVersion
        (50708, "s", 0, model, True),  # UniqueCameraModel
        (50710, "B", 3, (0, 1, 2), True),  # CFAPlaneColor
        (50711, "H", 1, 1, True),  # CFALayout: rectangular
        (50713, "H", 2, (2, 2), True),  # BlackLevelRepeatDim
        (50714, "I", 4, tuple(blacks), True),  # BlackLevel, CFA position order
        (50717, "I", 1, white, True),  # WhiteLevel
        (50721, "2i", 9, (1, 1, 0, 1, 0, 1, 0, 1, 1, 1, 0, 1, 0, 1, 0, 1, 1, 1), True),  # ColorMatrix1
        (50728, "2I", 3, (1, 1, 1, 1, 1, 1), True),  # AsShotNeutral
        (50778, "H", 1, 21, True),  # CalibrationIlluminant1: D65
        (_EXIF_PLACEHOLDER, "I", 1, 0, True),
    ]
    target = Path(path)
    with atomic_path(target) as tmp:
        tifffile.imwrite(
            tmp,
            mosaic,
            photometric=tifffile.PHOTOMETRIC.CFA,
            compression=None,
            planarconfig=None,
            subfiletype=0,
            byteorder="<",
            metadata=None,
            software="gonio",
            extratags=tags,
        )
        with open(tmp, "r+b") as fh:
            _attach_exif(fh, exposure, iso_value)
    return target
