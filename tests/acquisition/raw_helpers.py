"""Mosaics, signals and RAW files the file-reading tests share."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import rawpy
import tifffile

from acquisition.files.raw import (
    LINEAR_POSTPROCESS,
)

KODAK = Path("/work/shared/data/raw/kodak_dc50.kdc")


PATTERNS = ["RGGB", "BGGR", "GRBG", "GBRG"]


def _mosaic(shape: tuple[int, int], white: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, white + 1, shape, dtype=np.uint16)


def _smooth_signal(shape: tuple[int, int], peak: float, seed: int = 0) -> np.ndarray:
    """A smooth positive scene with some noise, in counts above black."""
    yy, xx = np.mgrid[0 : shape[0], 0 : shape[1]]
    scene = 1 + np.sin(xx / 7.0) * np.cos(yy / 5.0)
    noisy = scene + np.random.default_rng(seed).normal(0, 0.02, shape)
    return np.floor(np.clip(noisy, 0.05, None) / 2.1 * peak)


def _postprocess(path: Path, **overrides: object) -> np.ndarray:
    params = {**LINEAR_POSTPROCESS, "demosaic_algorithm": rawpy.DemosaicAlgorithm.LINEAR, **overrides}
    with rawpy.imread(str(path)) as raw:
        return raw.postprocess(**params).astype(np.float64)


def _patch_photometric(path: Path, value: int) -> None:
    data = bytearray(path.read_bytes())
    ifd = struct.unpack("<I", data[4:8])[0]
    (count,) = struct.unpack("<H", data[ifd : ifd + 2])
    for i in range(count):
        entry = ifd + 2 + 12 * i
        if struct.unpack("<H", data[entry : entry + 2])[0] == 262:
            data[entry + 8 : entry + 10] = struct.pack("<H", value)
    path.write_bytes(bytes(data))


def _linear_raw_dng(path: Path, data: np.ndarray, black: int) -> Path:
    """A LinearRaw (34892) DNG; tifffile refuses one-sample LinearRaw, so mono files get patched."""
    tags = [
        (33434, "2I", 1, (1, 100), True),
        (50706, "B", 4, (1, 4, 0, 0), True),
        (50708, "s", 0, "mono test", True),
        (50714, "I", 1, black, True),
        (50717, "I", 1, 4095, True),
    ]
    photometric = 34892 if data.ndim == 3 else 1
    tifffile.imwrite(path, data, photometric=photometric, extratags=tags, metadata=None, software="gonio")
    if data.ndim == 2:
        _patch_photometric(path, 34892)
    return path
