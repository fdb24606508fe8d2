"""Measuring a bracket's clip level from the data: the plateau of clipped pixels at the top of its frames.

Holds :func:`measure_saturation`, ``_plateau_level`` (one frame's plateau, from a count of the pixels in
the plateau and just below it: numpy for a small frame, compiled for a large one, the same numbers) and
``_clip_levels`` (the level per gain a merge uses). See :mod:`acquisition.hdr.merge` for how the merge uses it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from acquisition.frame import Frame
from acquisition.hdr.bracket import _flat, _min_black, check_bracket
from acquisition.hdr.compiled import compiled
from acquisition.hdr.small import NUMPY_BELOW, top_counts
from acquisition.noise import SensorNoise


def _plateau_level(frame: Frame, min_pixels: int, min_fraction: float) -> float | None:
    """Mean of the clipped plateau at the top of one frame, counts above black; None if there is none."""
    flat = _flat(frame.data)
    if flat.dtype != np.uint16:
        flat = flat.astype(np.float32, copy=False)
    top = float(flat.max())
    black = _min_black(frame)
    # The plateau of a full-well clip is as wide as the read noise after the clip (a few counts); 0.2 % of
    # the range is wide enough for any sensor seen, narrow beside the shot noise of unclipped pixels there.
    width = max(4.0, 2e-3 * (top - black))
    lo, mid = top - 4.0 * width, top - width
    count = top_counts if flat.size < NUMPY_BELOW else compiled()._top_counts  # numba loads on first use
    if flat.dtype == np.uint16:
        n_below, n_top, sum_top = count(flat, math.ceil(lo), math.ceil(mid))
    else:
        n_below, n_top, sum_top = count(flat, lo, mid)
    # A clip piles pixels up at the top: far more there than the density just below (3 widths) predicts.
    if n_top < max(min_pixels, min_fraction * flat.size) or n_top * 3 < 8 * n_below:
        return None
    level = float(sum_top) / n_top - black
    # A frame whose values all sit in a narrow band (a dark frame, a very short exposure) piles up too;
    # no sensor clips in the bottom tenth of its range.
    return level if level >= 0.1 * (frame.white_level - black) else None


def measure_saturation(
    frames: Sequence[Frame], *, min_pixels: int = 16, min_fraction: float = 1e-5
) -> float | None:
    """Clip level in counts above black, measured from the plateau of clipped pixels; None if nothing clips.

    Looks at the frames from the longest exposure down and takes the median of the plateau levels (mean
    value of the plateau) of the first two that show one: a pile-up of at least ``min_pixels`` (and
    ``min_fraction`` of the pixels) within 0.2 % of the range below the frame's maximum, 8x denser than the
    values just below, and at least a tenth of the way from black to ``white_level`` (a frame whose values
    all sit in a narrow band near black piles up too). A full-well clip below the ADC's white level shows
    up here, which trusting ``white_level`` would miss. The frames should share one gain (the clip in
    counts scales with it); :func:`~acquisition.hdr.merge.merge_linear` measures each gain's frames apart.
    """
    check_bracket(frames, ("raw", "linear"))
    return _measured(frames, min_pixels, min_fraction)


def _measured(frames: Sequence[Frame], min_pixels: int = 16, min_fraction: float = 1e-5) -> float | None:
    """:func:`measure_saturation` of a bracket already checked."""
    levels: list[float] = []
    for f in sorted(frames, key=lambda f: f.exposure_s * f.gain, reverse=True):
        level = _plateau_level(f, min_pixels, min_fraction)
        if level is not None:
            levels.append(level)
            if len(levels) == 2:
                break
    if not levels:
        return None
    # np.median's own arithmetic on one or two values (the mean of the middle two), without its overhead.
    return levels[0] if len(levels) == 1 else (levels[0] + levels[1]) / 2.0


def _clip_levels(
    frames: Sequence[Frame], noise: SensorNoise, saturation_dn: float | None
) -> dict[float, tuple[float, str]]:
    """Per gain of a checked bracket, its clip level in counts above black and where that comes from.

    Given (``saturation_dn``), else measured from the frames of that gain, else the noise model's: a
    full-well clip in counts scales with gain (one bracket usually has one gain).
    """
    levels: dict[float, tuple[float, str]] = {}
    for g in sorted({f.gain for f in frames}):
        if saturation_dn is not None:
            levels[g] = (float(saturation_dn), "given")
            continue
        measured = _measured([f for f in frames if f.gain == g])
        if measured is not None:
            levels[g] = (measured, "measured from the data")
        else:
            levels[g] = (noise.saturation_dn(g), "noise model (no clipped plateau in the data)")
    return levels
