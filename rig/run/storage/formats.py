"""File formats of the run store (rig/run/storage/store.py): OpenEXR images, CSV tables, the JSON-lines journal.

These are pure encoders (values to text or files, ValueError on bad input); rig/run/storage/store.py owns the run
directory, the lock, durability and the errors that name the run's files.

Images: pixels are stored as 32-bit floats (half floats have an 11-bit mantissa, too coarse for HDR readings that are
later averaged over an ROI), losslessly compressed (ZIP). EXR stores channels sorted by name, so the caller's
channel order and the array's rank are kept in two header attributes and restored on reading.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from model.errors import GonioError
from model.plain import json_walk

Float32Array = npt.NDArray[np.float32]

VARIANCE_SUFFIX = ".var"
_CHANNELS_ATTR = "gonioChannels"
_NDIM_ATTR = "gonioNdim"
_CHANNEL_RE = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]{0,63}")


def _as_float32(what: str, data: npt.ArrayLike) -> Float32Array:
    arr = np.asarray(data)
    if arr.dtype.kind not in "biuf":
        raise ValueError(f"{what} has dtype {arr.dtype}: expected real numbers")
    with np.errstate(over="ignore"):  # overflow is reported below, with the name of the array
        out = np.ascontiguousarray(arr, dtype=np.float32)
    # A finite float64 above float32's range would silently become inf in the file.
    if arr.dtype.kind == "f" and np.any(np.isfinite(arr) & ~np.isfinite(out)):
        raise ValueError(f"{what} has finite values beyond the float32 range (|x| > 3.4e38)")
    return out


def _check_channels(channels: Sequence[str]) -> list[str]:
    names = list(channels)
    if isinstance(channels, str) or not names:
        raise ValueError(f"channels = {channels!r}: expected a non-empty sequence of names, e.g. ('R', 'G', 'B')")
    for ch in names:
        if not isinstance(ch, str) or not _CHANNEL_RE.fullmatch(ch) or ch.endswith(VARIANCE_SUFFIX):
            raise ValueError(
                f"channel name {ch!r}: expected letters, digits, '_', '.', '-' (at most 64), "
                f"not ending in {VARIANCE_SUFFIX!r} (reserved for variances)"
            )
    if len(set(names)) != len(names):
        raise ValueError(f"channels = {names!r}: names repeat")
    return names


def _planes(what: str, arr: Float32Array, names: list[str]) -> list[Float32Array]:
    if arr.ndim == 2 and len(names) == 1:
        return [arr]
    if arr.ndim == 3 and arr.shape[2] == len(names):
        return [np.ascontiguousarray(arr[:, :, k]) for k in range(len(names))]
    raise ValueError(
        f"{what} has shape {arr.shape} but {len(names)} channel(s) {names!r}: expected (height, width, "
        f"{len(names)})" + (" or (height, width)" if len(names) == 1 else "; for a 2-D image pass channels=('Y',)")
    )


def write_exr(path: Path, image: npt.ArrayLike, channels: Sequence[str], variance: npt.ArrayLike | None = None) -> None:
    """Write ``image`` (H, W, C) or (H, W) (channel "Y" unless named) and its variance to ``path`` as float32 EXR."""
    names = _check_channels(channels)
    img = _as_float32("image", image)
    if img.ndim == 2 and names == ["R", "G", "B"]:  # the default channels, given a monochrome image
        names = ["Y"]
    planes = _planes("image", img, names)
    if img.shape[0] == 0 or img.shape[1] == 0:
        raise ValueError(f"image has shape {img.shape}: expected at least one pixel")
    pixels: dict[str, Float32Array] = dict(zip(names, planes, strict=True))
    if variance is not None:
        var = _as_float32("variance", variance)
        if var.shape != img.shape:
            raise ValueError(f"variance has shape {var.shape}, image has {img.shape}: expected the same")
        if np.any(var < 0):
            raise ValueError("variance has negative values")
        for ch, plane in zip(names, _planes("variance", var, names), strict=True):
            pixels[ch + VARIANCE_SUFFIX] = plane
    import OpenEXR  # here, not at the top: a run saves images only when asked, and its start waits for imports

    header = {
        "compression": OpenEXR.ZIP_COMPRESSION,
        "type": OpenEXR.scanlineimage,
        _CHANNELS_ATTR: json.dumps(names),
        _NDIM_ATTR: int(img.ndim),
    }
    OpenEXR.File(header, pixels).write(str(path))


def read_exr(path: Path) -> tuple[Float32Array, Float32Array | None, list[str]]:
    """Read an image written by :func:`write_exr`: (image, variance or None, channel names)."""
    import OpenEXR

    try:
        exr = OpenEXR.File(str(path), separate_channels=True)
    except RuntimeError as exc:
        raise ValueError(f"cannot read {path} as OpenEXR: {exc}") from exc
    header = exr.header()
    pixels = {name: np.asarray(ch.pixels, dtype=np.float32) for name, ch in exr.channels().items()}
    if _CHANNELS_ATTR in header:
        names = list(json.loads(header[_CHANNELS_ATTR]))
        ndim = int(header.get(_NDIM_ATTR, 3))
    else:  # an EXR from elsewhere: its channels in file order, variances apart
        names = [n for n in pixels if not n.endswith(VARIANCE_SUFFIX)]
        ndim = 3
    missing = [n for n in names if n not in pixels]
    if missing:
        raise ValueError(f"{path} lacks channel(s) {missing!r}")

    def stack(keys: list[str]) -> Float32Array:
        if ndim == 2 and len(keys) == 1:
            return pixels[keys[0]]
        return np.stack([pixels[k] for k in keys], axis=-1)

    image = stack(names)
    var_keys = [n + VARIANCE_SUFFIX for n in names]
    variance = stack(var_keys) if all(k in pixels for k in var_keys) else None
    return image, variance, names


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not allowed")


def parse_journal(data: bytes) -> tuple[list[dict[str, Any]], int, int]:
    """Records of a JSON-lines journal, the length of its good prefix, the bytes of a torn last line after it."""
    lines = data.split(b"\n")
    complete, torn = lines[:-1], len(lines[-1])  # bytes after the last newline: an interrupted write
    records: list[dict[str, Any]] = []
    good = 0
    for number, line in enumerate(complete, 1):
        try:
            rec = json.loads(line.decode("utf-8"), parse_constant=_no_constant)
        except ValueError as exc:
            if number == len(complete) and not torn:
                return records, good, len(line) + 1  # a complete but unreadable last line is torn too
            raise ValueError(
                f"line {number} is not valid JSON ({exc}); the journal is corrupt (only a torn last line is cut)"
            ) from None
        if not isinstance(rec, dict) or not isinstance(rec.get("kind"), str):
            raise ValueError(f"line {number} is not a record (a JSON object with a str 'kind')")
        records.append(rec)
        good += len(line) + 1
    return records, good, torn


class NotExactJson(GonioError):
    """Raised by ``exact_json`` at anything but exact plain JSON types (a subclass, a numpy value, NaN)."""


def _not_exact(value: Any) -> Any:
    raise NotExactJson


def exact_json(value: Any) -> Any:
    """A fresh copy of ``value`` made only of exact JSON types: what ``json.loads`` reads back from its text.

    The journal keeps this copy instead of parsing the line it wrote. Only exact types qualify: an IntEnum, a
    float or str subclass or a numpy scalar would read back as another type, so it raises ``NotExactJson`` there
    and the caller takes the general path (``model.plain.jsonable``, then a re-parse).
    """
    return _walk_exact(value)


_walk_exact = json_walk(_not_exact, _not_exact)


def _cell(row: int, col: str, value: Any) -> str:
    if type(value) is float and math.isfinite(value):  # most cells: the general checks below, skipped
        return repr(value)
    if isinstance(value, np.generic):
        value = value.item()
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | str):
        return str(value)
    if isinstance(value, float) and math.isfinite(value):
        return repr(value)  # the shortest string that reads back as the same float64
    raise ValueError(f"row {row}, column {col!r} = {value!r}: expected a finite number, str, bool or None (missing)")


def csv_text(rows: Sequence[Mapping[str, Any]], columns: Sequence[str] | None = None) -> str:
    """A tidy CSV: header ``columns`` (default: keys in order of first appearance), exact floats, None as empty."""
    if columns is None:
        first: dict[str, None] = {}
        for row in rows:  # keys in order of first appearance, a row at a time
            first.update(dict.fromkeys(row))
        columns = list(first)
    cols = list(columns)
    if len(set(cols)) != len(cols) or not all(isinstance(c, str) for c in cols):
        raise ValueError(f"columns {cols!r}: expected distinct str names")
    buf = io.StringIO()
    out = csv.writer(buf, lineterminator="\n")  # "\n", not csv's "\r\n": plain text, diffable
    out.writerow(cols)
    known = set(cols)
    for i, row in enumerate(rows):
        extra = [k for k in row if k not in known]
        if extra:
            raise ValueError(f"row {i} has keys {extra!r} not among the columns {cols!r}")
        out.writerow([_cell(i, c, row.get(c)) for c in cols])
    return buf.getvalue()
