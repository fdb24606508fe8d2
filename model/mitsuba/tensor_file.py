"""Mitsuba 3's tensor file (``mitsuba/core/tensor.h``), the container of the RGL ``.bsdf`` materials.

Layout, all little-endian, as ``TensorFile`` in Mitsuba's ``src/core/tensor.cpp`` reads it:

- 12 bytes ``"tensor_file\\0"``, two bytes of version (1, 0), a uint32 field count;
- per field: uint16 name length, the name (UTF-8), uint16 rank, uint8 dtype (Mitsuba's ``Struct::Type``:
  1 uint8, 10 float32, ...), uint64 byte offset of its data from the start of the file, rank x uint64 shape;
- the fields' data, C order, each starting at a multiple of 8 bytes.

:func:`tensor_bytes` builds a file in memory (so a writer can place it atomically), :func:`read_tensor_file`
reads one back (for checks; Mitsuba memory-maps the file itself).
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

MAGIC = b"tensor_file\0"
VERSION = (1, 0)
#: Mitsuba's Struct::Type codes of the dtypes a tensor file may hold.
DTYPE_CODES: dict[np.dtype[np.generic], int] = {
    np.dtype(np.uint8): 1, np.dtype(np.int8): 2, np.dtype(np.uint16): 3, np.dtype(np.int16): 4,
    np.dtype(np.uint32): 5, np.dtype(np.int32): 6, np.dtype(np.uint64): 7, np.dtype(np.int64): 8,
    np.dtype(np.float16): 9, np.dtype(np.float32): 10, np.dtype(np.float64): 11,
}  # fmt: skip
ALIGN = 8


def tensor_bytes(fields: Mapping[str, npt.NDArray[Any]]) -> bytes:
    """The tensor file holding ``fields`` (name -> array, any rank), as bytes."""
    arrays = {name: np.ascontiguousarray(value) for name, value in fields.items()}
    for name, a in arrays.items():
        if a.dtype.newbyteorder("<") not in DTYPE_CODES or a.dtype.byteorder == ">":
            raise ValueError(f"tensor field {name!r}: dtype {a.dtype} has no Mitsuba Struct::Type code")
    header_size = len(MAGIC) + 2 + 4 + sum(2 + len(n.encode()) + 2 + 1 + 8 + 8 * a.ndim for n, a in arrays.items())
    offsets, pos = {}, header_size
    for name, a in arrays.items():
        pos = -(-pos // ALIGN) * ALIGN
        offsets[name] = pos
        pos += a.nbytes
    out = bytearray(MAGIC + struct.pack("<BBI", *VERSION, len(arrays)))
    for name, a in arrays.items():
        label = name.encode()
        out += struct.pack("<H", len(label)) + label
        out += struct.pack("<HBQ", a.ndim, DTYPE_CODES[a.dtype], offsets[name])
        out += struct.pack(f"<{a.ndim}Q", *a.shape)
    for name, a in arrays.items():
        out += bytes(offsets[name] - len(out))
        out += a.astype(a.dtype.newbyteorder("<"), copy=False).tobytes()
    return bytes(out)


def read_tensor_file(path: str | Path) -> dict[str, npt.NDArray[Any]]:
    """The fields of a tensor file (name -> array); raises ValueError naming the file if it is not one."""
    data = Path(path).read_bytes()
    if len(data) < 18 or data[:12] != MAGIC:
        raise ValueError(f"{path}: not a Mitsuba tensor file (no 'tensor_file' header)")
    if tuple(data[12:14]) != VERSION:
        raise ValueError(f"{path}: tensor file version {tuple(data[12:14])}; expected {VERSION}")
    (count,) = struct.unpack_from("<I", data, 14)
    codes = {v: k for k, v in DTYPE_CODES.items()}
    pos, fields = 18, {}
    try:
        for _ in range(count):
            (n,) = struct.unpack_from("<H", data, pos)
            name = data[pos + 2 : pos + 2 + n].decode()
            pos += 2 + n
            ndim, code, offset = struct.unpack_from("<HBQ", data, pos)
            pos += 11
            shape = struct.unpack_from(f"<{ndim}Q", data, pos)
            pos += 8 * ndim
            dtype = codes[code].newbyteorder("<")
            size = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
            if offset + size > len(data):
                raise ValueError(f"{path}: field {name!r} runs past the end of the file (truncated?)")
            fields[name] = np.frombuffer(data, dtype=dtype, count=size // dtype.itemsize, offset=offset).reshape(shape)
    except (struct.error, KeyError) as exc:
        raise ValueError(f"{path}: damaged tensor file header ({exc})") from exc
    return fields
