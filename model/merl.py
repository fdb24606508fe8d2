"""Tabulated isotropic BRDFs in the MERL format (Matusik et al. 2003): read, write, evaluate, tabulate.

File layout: three int32 dimensions (90, 90, 180) for (theta_h, theta_d, phi_d), then 3 x 1,458,000
float64 values, all red, then green, then blue, with index phi_d + 180 theta_d + 16200 theta_h.
theta_h is binned non-linearly, index = sqrt(theta_h / 90 deg) * 90; theta_d uniformly over 90 deg;
phi_d uniformly over 180 deg (reciprocity folds phi_d + pi). Stored values are scaled: multiply red by
1/1500, green by 1.15/1500 and blue by 1.66/1500 to get f_r in 1/sr. Negative entries mean "no data".
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import numpy.typing as npt

from model.base import BRDF, Array, Pair
from model.errors import InputError
from model.geometry import from_half_diff, to_half_diff

N_THETA_H, N_THETA_D, N_PHI_D = 90, 90, 180
SHAPE = (N_THETA_H, N_THETA_D, N_PHI_D)
SCALE = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])
FILE_BYTES = 12 + 3 * 8 * N_THETA_H * N_THETA_D * N_PHI_D


class MerlFormatError(InputError, ValueError):
    """A file is not a valid MERL .binary table."""


def _theta_h_index(theta_h: Array) -> Array:
    idx = np.sqrt(np.clip(theta_h, 0.0, np.pi / 2) / (np.pi / 2)) * N_THETA_H
    return np.clip(np.floor(idx), 0, N_THETA_H - 1).astype(np.intp)


def _theta_d_index(theta_d: Array) -> Array:
    idx = np.clip(theta_d, 0.0, np.pi / 2) / (np.pi / 2) * N_THETA_D
    return np.clip(np.floor(idx), 0, N_THETA_D - 1).astype(np.intp)


def _phi_d_index(phi_d: Array) -> Array:
    folded = np.mod(phi_d, np.pi)
    return np.clip(np.floor(folded / np.pi * N_PHI_D), 0, N_PHI_D - 1).astype(np.intp)


def bin_centers() -> tuple[Array, Array, Array]:
    """The (theta_h, theta_d, phi_d) in radians at the centre of every bin, each of shape SHAPE."""
    th = ((np.arange(N_THETA_H) + 0.5) / N_THETA_H) ** 2 * (np.pi / 2)
    td = (np.arange(N_THETA_D) + 0.5) / N_THETA_D * (np.pi / 2)
    pd = (np.arange(N_PHI_D) + 0.5) / N_PHI_D * np.pi
    return np.meshgrid(th, td, pd, indexing="ij")


@dataclass(frozen=True, eq=False)
class MerlTable:
    """A MERL table as f_r in 1/sr, shape (3, 90, 90, 180) for (channel, theta_h, theta_d, phi_d).

    NaN marks bins without data; :meth:`eval` returns 0 there and :meth:`has_data` says where.
    Lookup is nearest-bin, as in MERL's reference code.
    """

    values: Array = field(repr=False)
    source: str = ""

    reciprocal = True
    energy_conserving = False
    exemption = "measured data: energy conservation is a property of the sample, checked not assumed"

    def __post_init__(self) -> None:
        v = np.asarray(self.values, dtype=np.float64)
        if v.shape != (3, *SHAPE):
            raise MerlFormatError(f"MERL values must have shape (3, 90, 90, 180); got {v.shape}")
        object.__setattr__(self, "values", v)

    @property
    def channels(self) -> int:
        """Always 3 (RGB)."""
        return 3

    def _lookup(self, wi: npt.ArrayLike, wo: npt.ArrayLike) -> tuple[Array, Pair]:
        p = Pair(wi, wo)
        th, _, td, pd = to_half_diff(p.wi, p.wo)
        i, j, k = _theta_h_index(th), _theta_d_index(td), _phi_d_index(pd)
        return np.moveaxis(self.values[:, i, j, k], 0, -1), p

    def eval(self, wi: npt.ArrayLike, wo: npt.ArrayLike) -> Array:
        """Tabulated f_r in 1/sr, shape (..., 3); 0 below the horizon and where the table has no data."""
        v, p = self._lookup(wi, wo)
        out = np.where(p.valid & np.isfinite(v), v, 0.0)
        return out.astype(p.dtype)

    def has_data(self, wi: npt.ArrayLike, wo: npt.ArrayLike) -> npt.NDArray[np.bool_]:
        """Whether the table holds a measurement for each pair (all channels), shape (...)."""
        v, p = self._lookup(wi, wo)
        return np.all(np.isfinite(v), axis=-1) & p.valid[..., 0]

    @classmethod
    def from_model(cls, model: BRDF, chunk: int = 200_000) -> MerlTable:
        """Tabulate any model at the bin centres (a scalar model fills all three channels)."""
        th, td, pd = (a.reshape(-1) for a in bin_centers())
        out = np.empty((th.size, 3))
        for s in range(0, th.size, chunk):
            wi, wo = from_half_diff(th[s : s + chunk], 0.0, td[s : s + chunk], pd[s : s + chunk])
            f = np.asarray(model.eval(wi, wo), dtype=np.float64)
            out[s : s + chunk] = f if f.ndim == 2 else f[:, None]
        return cls(np.moveaxis(out, -1, 0).reshape(3, *SHAPE), source=type(model).__name__)


def read_merl(path: str | os.PathLike[str]) -> MerlTable:
    """Read a MERL .binary file into f_r values in 1/sr (NaN where the file has no data)."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise FileNotFoundError(f"MERL file not found: {p}") from None
    if len(raw) < 12:
        raise MerlFormatError(f"{p}: {len(raw)} bytes is too short for a MERL header (12 bytes)")
    dims = tuple(int(d) for d in np.frombuffer(raw[:12], dtype="<i4"))
    if dims != SHAPE:
        raise MerlFormatError(f"{p}: header dimensions {dims}, expected {SHAPE}")
    if len(raw) != FILE_BYTES:
        raise MerlFormatError(f"{p}: {len(raw)} bytes, expected {FILE_BYTES} for a full MERL table")
    data = np.frombuffer(raw[12:], dtype="<f8").reshape(3, *SHAPE)
    values = np.where(data < 0, np.nan, data * SCALE[:, None, None, None])
    return MerlTable(values, source=str(p))


def write_merl(table: MerlTable, path: str | os.PathLike[str]) -> None:
    """Write a table as a MERL .binary file (NaN becomes -1, "no data"); atomic via rename."""
    p = Path(path)
    stored = table.values / SCALE[:, None, None, None]
    stored = np.where(np.isfinite(stored), stored, -1.0)
    tmp = p.with_name(p.name + ".tmp")
    with open(tmp, "wb") as fh:
        fh.write(np.asarray(SHAPE, dtype="<i4").tobytes())
        fh.write(np.ascontiguousarray(stored, dtype="<f8").tobytes())
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, p)
