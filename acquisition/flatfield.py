"""Flat-field correction: each pixel's relative response (vignetting times PRNU) from a flat-field series.

A flat-field series is frames of a uniform light (an integrating sphere, a diffuser) and as many darks at
the same exposure. Their mean difference, divided by its mean per colour (per CFA colour of a mosaic,
both greens together, or per channel), is each pixel's gain relative to its colour's mean: the lens's
vignetting and the pixels' response non-uniformity (PRNU) together. Dividing an HDR image by it (its
variance by its square) removes both, so a reading no longer depends on where on the sensor the ROI
lies. The map's own error (``gain_std_error``: the flats' temporal noise over their number) is per
pixel and tiny after a few frames; it is kept, not added to readings (like the reference albedo it is
common to every reading of a pixel).

The map is in sensor coordinates; a frame read out as a window (``Frame.origin_xy``) is corrected with
the window's part. For a report, the map is split into a smooth radial part (``vignetting``: the loss at
the sensor's corner of a fitted ``c (1 - v r^2)``) and the rest (``prnu_rms``, with the map's own noise
taken out).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from acquisition.files.atomic import atomic_path
from acquisition.frame import Frame, FrameError
from acquisition.hdr.merge import HdrImage
from model.errors import InputError

FloatArray = npt.NDArray[np.float64]
FORMAT = "gonio-flat-field/1"


class FlatFieldError(InputError, ValueError):
    """A flat-field series or file is unusable, or a map does not cover the frame it should correct."""


def _colour_index(frame: Frame) -> npt.NDArray[np.int64] | None:
    """Each pixel's colour (0 R, 1 G, 2 B) for a mosaic; None for frames whose channels are their colours."""
    if frame.kind != "raw" or frame.cfa_pattern is None:
        return None
    h, w = frame.shape[:2]
    codes = np.array(["RGB".index(c) for c in frame.cfa_pattern]).reshape(2, 2)
    return np.asarray(np.tile(codes, (h // 2 + 1, w // 2 + 1))[:h, :w], dtype=np.int64)


@dataclass(frozen=True, eq=False)
class FlatField:
    """Relative response per sensor pixel (mean 1 per colour), its standard error, and what it was made of."""

    gain: npt.NDArray[np.float32]
    gain_std_error: npt.NDArray[np.float32]
    kind: str
    cfa_pattern: str | None
    n_frames: int
    signal_dn: float
    vignetting: float
    prnu_rms: float
    camera_id: str = "unknown"
    meta: dict[str, Any] = field(default_factory=dict, compare=False)

    def window(self, origin_xy: tuple[int, int], shape: tuple[int, ...]) -> npt.NDArray[np.float32]:
        """The map under a frame of ``shape`` whose pixel (0, 0) is sensor pixel ``origin_xy``."""
        x0, y0 = origin_xy
        h, w = shape[0], shape[1]
        if not (0 <= x0 and 0 <= y0 and y0 + h <= self.gain.shape[0] and x0 + w <= self.gain.shape[1]):
            raise FlatFieldError(
                f"flat field of {self.gain.shape[1]}x{self.gain.shape[0]} pixels does not cover a {w}x{h} frame at "
                f"sensor pixel {origin_xy}: was it made with this camera at its full resolution?"
            )
        part = self.gain[y0 : y0 + h, x0 : x0 + w]
        if len(shape) == 3 and part.ndim == 2:
            part = part[..., None]
        elif len(shape) != part.ndim:
            raise FlatFieldError(f"flat field of shape {self.gain.shape} cannot correct frames of shape {shape}")
        return part

    def apply(self, hdr: HdrImage, origin_xy: tuple[int, int] = (0, 0)) -> HdrImage:
        """The HDR image divided by the map (variance by its square); flags and frame counts as they were."""
        g = self.window(origin_xy, hdr.radiance.shape)
        with np.errstate(divide="ignore", invalid="ignore"):
            rad = (hdr.radiance / g).astype(np.float32)
            var = (hdr.variance / (g * g)).astype(np.float32)
        meta = {**hdr.metadata, "flat_field": f"{self.n_frames} frames at {self.signal_dn:.0f} DN ({self.camera_id})"}
        return dataclasses.replace(hdr, radiance=rad, variance=var, metadata=meta)

    def save(self, path: str | Path) -> Path:
        """Write the map to an ``.npz`` file (atomically); returns the path."""
        target = Path(path)
        info = {"format": FORMAT, "kind": self.kind, "cfa_pattern": self.cfa_pattern, "n_frames": self.n_frames,
                "signal_dn": self.signal_dn, "vignetting": self.vignetting, "prnu_rms": self.prnu_rms,
                "camera_id": self.camera_id, **self.meta}  # fmt: skip
        with atomic_path(target) as tmp, open(tmp, "wb") as fh:
            np.savez_compressed(fh, gain=self.gain, gain_std_error=self.gain_std_error, info=json.dumps(info))
        return target

    @classmethod
    def load(cls, path: str | Path) -> FlatField:
        """Read a map written by :meth:`save`; FlatFieldError names the file and what is wrong."""
        p = Path(path)
        try:
            with np.load(p, allow_pickle=False) as z:
                gain, se, info = z["gain"], z["gain_std_error"], json.loads(str(z["info"]))
        except FileNotFoundError:
            raise FlatFieldError(f"{p}: no such flat-field file (write one with `gonio calibrate camera`)") from None
        except (OSError, KeyError, ValueError) as exc:
            raise FlatFieldError(f"{p}: not a gonio flat-field file: {exc}") from None
        if info.get("format") != FORMAT:
            raise FlatFieldError(f"{p}: format {info.get('format')!r}, expected {FORMAT!r}")
        if not (np.all(np.isfinite(gain)) and np.all(gain > 0)):
            raise FlatFieldError(f"{p}: the map has pixels that are not positive finite numbers")
        keys = ("kind", "cfa_pattern", "n_frames", "signal_dn", "vignetting", "prnu_rms", "camera_id")
        meta = {k: v for k, v in info.items() if k not in (*keys, "format")}
        return cls(gain.astype(np.float32), se.astype(np.float32), info["kind"], info["cfa_pattern"],
                   int(info["n_frames"]), float(info["signal_dn"]), float(info["vignetting"]),
                   float(info["prnu_rms"]), str(info["camera_id"]), meta)  # fmt: skip


def estimate_flat_field(flats: Sequence[Frame], darks: Sequence[Frame]) -> FlatField:
    """The flat field of a series: flat frames of a uniform light and darks at their exposure (see module doc)."""
    if len(flats) < 2 or len(darks) < 1:
        raise FlatFieldError(f"{len(flats)} flat and {len(darks)} dark frames: need at least 2 flats and 1 dark")
    first = flats[0]
    for f in (*flats, *darks):
        if f.shape != first.shape or f.kind != first.kind or f.cfa_pattern != first.cfa_pattern:
            raise FlatFieldError(f"frame {f.source or f.camera_id} ({f.kind}, {f.shape}) does not match the first "
                                 f"flat ({first.kind}, {first.shape}): one camera, one mode, full frames")  # fmt: skip
        if f.origin_xy != (0, 0):
            raise FlatFieldError(f"frame at sensor pixel {f.origin_xy}: a flat field is made from full frames")
    if first.kind == "8bit":
        raise FrameError("a flat field needs linear or raw frames, not 8-bit ones")
    stack = np.stack([np.asarray(f.data, dtype=np.float64) for f in flats])
    dark = np.mean([np.asarray(d.data, dtype=np.float64) for d in darks], axis=0)
    mean = stack.mean(axis=0)
    se = stack.std(axis=0, ddof=1) / np.sqrt(len(flats))
    signal = mean - dark
    colours = _colour_index(first)
    gain = np.empty_like(signal)
    if colours is not None:
        for c in range(3):
            sel = colours == c
            gain[sel] = signal[sel] / signal[sel].mean()
    elif signal.ndim == 3:
        gain = signal / signal.reshape(-1, signal.shape[2]).mean(axis=0)
    else:
        gain = signal / signal.mean()
    if not np.all(gain > 0):
        raise FlatFieldError(f"{int(np.sum(gain <= 0))} pixels have no signal above dark: is the light on?")
    with np.errstate(divide="ignore", invalid="ignore"):
        gain_se = np.abs(gain) * se / np.abs(signal)
    vignetting, prnu = _split(gain, gain_se)
    return FlatField(gain.astype(np.float32), gain_se.astype(np.float32), first.kind, first.cfa_pattern,
                     len(flats), float(np.median(signal)), vignetting, prnu, first.camera_id)  # fmt: skip


def _split(gain: FloatArray, gain_se: FloatArray) -> tuple[float, float]:
    """Corner loss of a fitted ``c (1 - v r^2)`` and the RMS of the rest with the map's own noise removed."""
    g = gain if gain.ndim == 2 else gain.mean(axis=2)
    h, w = g.shape
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    r2 = ((xx - cx) ** 2 + (yy - cy) ** 2) / max(cx**2 + cy**2, 1e-12)
    design = np.stack([np.ones(g.size), r2.ravel()], axis=1)
    (c0, c1), *_ = np.linalg.lstsq(design, g.ravel(), rcond=None)
    smooth = (c0 + c1 * r2).reshape(g.shape)
    rest = g / smooth - 1.0
    noise = gain_se if gain_se.ndim == 2 else gain_se.mean(axis=2) / np.sqrt(gain.shape[2])
    prnu2 = float(np.var(rest) - np.mean((noise / smooth) ** 2))
    return float(-c1 / c0), float(np.sqrt(max(prnu2, 0.0)))
