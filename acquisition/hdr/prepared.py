"""What the linear HDR merge's pass reads, per frame, and which pass runs it: numpy or compiled.

Holds ``_Prepared`` (the per-frame arrays and numbers of ``small.Inputs``, with a pixel subsample for the auto weighting
decision) and ``_prepare``, which works them out from a bracket: offsets (black levels or darks), noise terms
and saturation thresholds. Small images (an ROI crop, below ``NUMPY_BELOW`` pixel values) run the numpy pass of
:mod:`acquisition.hdr.small`; larger ones the compiled pass of :mod:`acquisition.hdr.kernel`, imported only
then, so numba loads only for a merge that needs it. Both give the same bits. The estimator is described in
:mod:`acquisition.hdr.merge`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from acquisition.frame import Frame, FrameError
from acquisition.hdr.bracket import DarkSpec, _black_map, _dark_offset, _find_dark, _min_black, describe_frame
from acquisition.hdr.compiled import compiled
from acquisition.hdr.small import NUMPY_BELOW, Inputs, Pass, run_small, sum_and_predicted_iv
from acquisition.noise import SensorNoise

F32 = npt.NDArray[np.float32]


@dataclass(frozen=True)
class _Prepared(Inputs):
    """Everything the pass needs, one entry per frame of the bracket, and the pass that runs it."""

    @property
    def small(self) -> bool:
        """Whether the numpy pass runs this bracket (few pixel values a frame)."""
        return self.data[0].size < NUMPY_BELOW

    def subsample(self, stride: int) -> _Prepared:
        """The same merge on every ``stride``-th pixel."""
        def sub(arrays: tuple[npt.NDArray[Any], ...]) -> tuple[npt.NDArray[Any], ...]:
            cache: dict[int, npt.NDArray[Any]] = {}
            return tuple(cache.setdefault(id(a), np.ascontiguousarray(a[::stride])) for a in arrays)

        maps = None if self.offmaps is None else sub(self.offmaps)
        return dataclasses.replace(self, data=sub(self.data), offmaps=maps)

    def run(self, inverse_variance: bool, signal: npt.NDArray[np.float64] | None = None) -> Pass:
        """Radiance, variance, flags and frames used, flat.

        ``signal`` (counts/s per pixel, flat) sets the inverse-variance weights; None uses each pixel's own
        first-pass estimate, which is biased at low signal and serves only to predict variances.
        """
        if inverse_variance and signal is None:
            signal = self.run(False)[0].astype(np.float64)
        if self.small:
            return run_small(self, inverse_variance, signal)
        result: Pass = compiled().run_compiled(self, inverse_variance, signal)  # numba loads on first use
        return result

    def sum_and_predicted_iv(self) -> tuple[Pass, F32]:
        """The sum pass and the inverse-variance variance it predicts: ``run(False)``, ``run(True, rad)[1]``."""
        if self.small:
            return sum_and_predicted_iv(self)
        first = self.run(False)
        return first, self.run(True, first[0].astype(np.float64))[1]


def _prepare(
    frames: Sequence[Frame], data: Sequence[npt.NDArray[Any]], noise: SensorNoise,
    darks: Mapping[float, DarkSpec] | None, levels: Mapping[float, tuple[float, str]], saturation_sigma: float,
    dark_sigma: float,
) -> tuple[_Prepared, tuple[float, ...], tuple[str, ...]]:
    """The pass's inputs for a checked bracket (``data``: its flat pixels), each frame's saturation threshold in
    counts above black, and what was subtracted from each frame.

    ``levels`` is the clip level (counts above black) per gain; a frame is saturated ``saturation_sigma``
    noise sigmas below it. A pixel is dark below ``dark_sigma`` sigmas of the longest frame's zero-signal noise.
    """
    n_frames = len(frames)
    black_cache: dict[tuple[Any, ...], F32] = {}
    maps: list[npt.NDArray[Any] | None] = []
    # Per frame, as Python floats (the same IEEE arithmetic as numpy's scalars, without their overhead).
    off_s = [0.0] * n_frames
    thr_raw = [0.0] * n_frames
    thr_above = [0.0] * n_frames
    expo = [f.exposure_s * f.gain for f in frames]
    shot = [0.0] * n_frames
    cvar = [0.0] * n_frames
    dark_notes: list[str] = []
    for i, f in enumerate(frames):
        zero_var = float(noise.variance_dn2(0.0, f.exposure_s, f.gain))
        offset, dark_var, note = _offset(i, f, noise, darks, zero_var, black_cache)
        dark_notes.append(note)
        if isinstance(offset, np.ndarray):
            maps.append(offset)
        else:
            maps.append(None)
            off_s[i] = offset
        shot[i] = expo[i] * f.gain / noise.e_per_dn
        cvar[i] = zero_var + dark_var
        black = _min_black(f)
        level = min(levels[f.gain][0], f.white_level - black)
        thr_above[i] = level - saturation_sigma * math.sqrt(float(noise.variance_dn2(level, f.exposure_s, f.gain)))
        thr_raw[i] = black + thr_above[i]

    # np.argmin and np.argmax's picks (the first of equals), without their overhead on a few numbers.
    shortest, longest = expo.index(min(expo)), expo.index(max(expo))
    prep = _Prepared(
        data=tuple(data), offmaps=_offmaps(maps, data[0].size), off_s=np.array(off_s), thr_raw=np.array(thr_raw),
        expo=np.array(expo), shot=np.array(shot), cvar=np.array(cvar), shortest=shortest, longest=longest,
        dark_thr=dark_sigma * math.sqrt(cvar[longest]),
    )
    return prep, tuple(thr_above), tuple(dark_notes)


def _offset(
    index: int, frame: Frame, noise: SensorNoise, darks: Mapping[float, DarkSpec] | None, zero_var: float,
    black_cache: dict[tuple[Any, ...], F32],
) -> tuple[npt.NDArray[Any] | float, float, str]:
    """What to subtract from a frame (counts: a flat map or a number), the variance it adds (counts^2), what it is.

    Without darks, the frame's black level; with darks, the one for its exposure (``zero_var``: the noise
    model's variance at zero signal for this frame, counts^2).
    """
    if darks is None:
        return _black_map(frame, index, black_cache), 0.0, "black level"
    spec = _find_dark(darks, frame.exposure_s)
    if spec is None:
        raise FrameError(
            f"{describe_frame(index, frame)}: no dark for exposure {frame.exposure_s:g} s; darks were given for "
            f"{sorted(float(k) for k in darks)} s"
        )
    return _dark_offset(index, frame, spec, noise, zero_var)


def _offmaps(maps: Sequence[npt.NDArray[Any] | None], size: int) -> tuple[npt.NDArray[Any], ...] | None:
    """The per-pixel offsets as the pass reads them (None: every frame's offset is a number)."""
    present = [m for m in maps if m is not None]
    if len(present) == len(maps) and all(m.dtype == np.uint16 for m in present):
        # One uint16 dark frame per exposure, as delivered.
        return tuple(present)
    if any(m is not None for m in maps):
        # Otherwise all maps float32 (one type per tuple); a frame with a number for offset reads a shared
        # zero map, one array that stays in cache.
        zeros = np.zeros(size, np.float32)
        return tuple(zeros if m is None else m.astype(np.float32, copy=False) for m in maps)
    return None
