"""Validating a bracket and extracting what the linear HDR merge reads from it.

Holds :func:`describe_frame` (how error messages name a frame), :func:`check_bracket` (one kind, one
shape, positive exposures and gains, at most ``MAX_FRAMES``), the flat pixel arrays the compiled pass
reads (``_frame_data``), and the offset subtracted from each frame: its black level as a number or a
per-pixel map (``_black_map``), or a dark looked up by exposure time (``_find_dark``) and turned into an
offset with the variance it adds (``_dark_offset``). Used by :mod:`acquisition.hdr.merge`,
:mod:`acquisition.hdr.saturation` and :mod:`acquisition.hdr.response`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

from acquisition.frame import Frame, FrameError, FrameKind
from acquisition.noise import SensorNoise

DarkSpec = Frame | Sequence[Frame] | npt.NDArray[np.generic] | float
F32 = npt.NDArray[np.float32]

#: A bracket has at most this many frames (the compiled pass is specialised on a padded frame count).
MAX_FRAMES = 64


def describe_frame(index: int, frame: Frame) -> str:
    """How error messages name a frame: its index in the bracket and its file or camera and exposure."""
    if frame.source:
        return f"frame {index} ({frame.source})"
    return f"frame {index} ({frame.camera_id}, {frame.exposure_s:g} s)"


def check_bracket(frames: Sequence[Frame], kinds: Sequence[FrameKind]) -> FrameKind:
    """Validate a bracket (non-empty, one kind among ``kinds``, one shape, positive exposures); its kind."""
    if len(frames) == 0:
        raise FrameError("empty bracket: no frames to merge")
    for i, f in enumerate(frames):
        if not isinstance(f, Frame):
            raise FrameError(f"frame {i}: expected an acquisition.frame.Frame, got {type(f).__name__}")
    first = frames[0]
    for i, f in enumerate(frames):
        if f.kind == first.kind and f.shape == first.shape and f.cfa_pattern == first.cfa_pattern:
            if math.isfinite(f.exposure_s) and f.exposure_s > 0 and math.isfinite(f.gain) and f.gain > 0:
                continue  # the usual case, without building the messages below
        where = describe_frame(i, f)
        if f.kind != first.kind:
            raise FrameError(
                f"{where} is kind {f.kind!r} but {describe_frame(0, first)} is kind {first.kind!r}: "
                "a bracket must be of one kind"
            )
        if f.shape != first.shape:
            raise FrameError(f"{where} has shape {f.shape} but {describe_frame(0, first)} has shape {first.shape}")
        if not (math.isfinite(f.exposure_s) and f.exposure_s > 0):
            raise FrameError(f"{where}: exposure_s = {f.exposure_s!r}, expected a positive number of seconds")
        if not (math.isfinite(f.gain) and f.gain > 0):
            raise FrameError(f"{where}: gain = {f.gain!r}, expected a positive number")
        if f.cfa_pattern != first.cfa_pattern:
            raise FrameError(
                f"{where} has CFA pattern {f.cfa_pattern!r} but {describe_frame(0, first)} has "
                f"{first.cfa_pattern!r}"
            )
    if first.kind not in kinds:
        hint = ": merge 8-bit frames with acquisition.hdr.response.merge_8bit" if first.kind == "8bit" else ""
        raise FrameError(f"{describe_frame(0, first)} is kind {first.kind!r}, expected one of {tuple(kinds)}{hint}")
    if len(frames) > MAX_FRAMES:
        raise FrameError(f"bracket of {len(frames)} frames: at most {MAX_FRAMES} can be merged at once")
    return first.kind


def _min_black(frame: Frame) -> float:
    b = frame.black_level
    return float(min(b)) if isinstance(b, tuple) else float(b)


def _flat(a: npt.NDArray[Any]) -> npt.NDArray[Any]:
    return np.ascontiguousarray(a).reshape(-1)


def _black_map(frame: Frame, index: int, cache: dict[tuple[Any, ...], F32]) -> F32 | float:
    """The frame's black level: a number, or a per-pixel map for per-CFA-site or per-channel levels."""
    b = frame.black_level
    if not isinstance(b, tuple):
        return float(b)
    if len(set(b)) == 1:
        return float(b[0])
    key = (b, frame.shape, frame.kind)
    if key in cache:
        return cache[key]
    if frame.kind == "raw" and len(b) == 4:
        tile = np.asarray(b, np.float32).reshape(2, 2)
        h, w = frame.shape
        full = np.tile(tile, (h // 2 + 1, w // 2 + 1))[:h, :w]
    elif frame.data.ndim == 3 and len(b) == frame.shape[2]:
        full = np.broadcast_to(np.asarray(b, np.float32), frame.shape)
    else:
        raise FrameError(
            f"{describe_frame(index, frame)}: black_level {b!r} has {len(b)} values; expected 1, 4 (one per "
            "CFA site of a raw frame) or one per channel"
        )
    cache[key] = _flat(full.astype(np.float32))
    return cache[key]


def _find_dark(darks: Mapping[float, DarkSpec], exposure_s: float) -> DarkSpec | None:
    for key, spec in darks.items():
        if math.isclose(float(key), exposure_s, rel_tol=1e-4):
            return spec
    return None


def _dark_offset(
    index: int, frame: Frame, spec: DarkSpec, noise: SensorNoise, one_frame_var: float | None = None
) -> tuple[npt.NDArray[Any] | float, float, str]:
    """Offset to subtract (counts: a flat map or a number), the variance it adds (counts^2), a description.

    ``one_frame_var``: the noise model's variance at zero signal for this frame (counts^2), if known already.
    """
    if one_frame_var is None:
        one_frame_var = float(noise.variance_dn2(0.0, frame.exposure_s, frame.gain))
    if isinstance(spec, Frame):
        spec = [spec]
    if isinstance(spec, Sequence) and not isinstance(spec, (str, bytes)) and all(isinstance(d, Frame) for d in spec):
        if len(spec) == 0:
            raise FrameError(f"{describe_frame(index, frame)}: the dark list for {frame.exposure_s:g} s is empty")
        total = np.zeros(frame.shape if len(spec) > 1 else (), np.float32)
        for j, d in enumerate(spec):
            if not (
                d.shape == frame.shape and d.kind == frame.kind and math.isclose(d.gain, frame.gain, rel_tol=1e-4)
                and math.isclose(d.exposure_s, frame.exposure_s, rel_tol=1e-3)
            ):  # fmt: skip
                _mismatched_dark(index, frame, j, d)
            _check_finite(d.data, f"dark {j} for {frame.exposure_s:g} s ({d.source or d.camera_id})")
            if len(spec) > 1:
                total += np.asarray(d.data, dtype=np.float32)
        if len(spec) == 1 and spec[0].data.dtype == np.uint16:
            # As delivered: the compiled pass reads uint16 maps directly, saving a float copy per frame.
            return _flat(spec[0].data), one_frame_var, "1 dark frame"
        total /= len(spec)
        return _flat(total), one_frame_var / len(spec), f"{len(spec)} dark frames averaged"
    where = describe_frame(index, frame)
    arr = np.asarray(spec, dtype=np.float32)
    if arr.ndim == 0:
        if not math.isfinite(float(arr)):
            raise FrameError(f"{where}: dark level {float(arr)!r} for {frame.exposure_s:g} s is not finite")
        return float(arr), 0.0, "mean dark level"
    if arr.shape != frame.shape:
        raise FrameError(f"master dark for {frame.exposure_s:g} s has shape {arr.shape} but {where} has {frame.shape}")
    return _flat(arr), 0.0, "master dark array"


def _check_finite(data: npt.NDArray[Any], what: str) -> None:
    """Raise FrameError naming ``what`` if a dark frame a camera delivered holds NaN or infinite counts.

    Light frames were always checked (``_frame_data``), darks never: a run's reading with a quarter of its dark
    frame NaN came out 40 % high with no flag. A master dark array is the caller's own product and keeps its
    NaN pixels (they give NaN radiance there, which the ROI reduction refuses unless flagged).
    """
    if data.dtype.kind not in "fc":
        return  # integer counts are always finite
    bad = int(np.count_nonzero(~np.isfinite(data)))
    if bad:
        raise FrameError(f"{what} has {bad} non-finite pixel value{'s' if bad > 1 else ''} of {data.size} "
                         "(NaN or infinite counts): the camera delivered a broken dark frame")  # fmt: skip


def _mismatched_dark(index: int, frame: Frame, j: int, d: Frame) -> None:
    """Raise the FrameError naming how dark ``j`` differs from the frame it is for."""
    where = describe_frame(index, frame)
    dwhere = f"dark {j} for {frame.exposure_s:g} s ({d.source or d.camera_id})"
    if d.shape != frame.shape:
        raise FrameError(f"{dwhere} has shape {d.shape} but {where} has shape {frame.shape}")
    if d.kind != frame.kind:
        raise FrameError(f"{dwhere} is kind {d.kind!r} but {where} is kind {frame.kind!r}")
    if not math.isclose(d.gain, frame.gain, rel_tol=1e-4):
        raise FrameError(f"{dwhere} has gain {d.gain!r} but {where} has gain {frame.gain!r}")
    raise FrameError(f"{dwhere} has exposure_s {d.exposure_s!r} but {where} has {frame.exposure_s!r}")


def _frame_data(frames: Sequence[Frame]) -> list[npt.NDArray[Any]]:
    """Flat pixel arrays in one dtype the compiled pass knows: uint16 as delivered, anything else float32."""
    if all(f.data.dtype == np.uint16 for f in frames):
        return [_flat(f.data) for f in frames]
    out = []
    for i, f in enumerate(frames):
        a = _flat(f.data).astype(np.float32, copy=False)
        if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
            raise FrameError(f"{describe_frame(i, f)} has non-finite pixel values")
        out.append(a)
    return out
