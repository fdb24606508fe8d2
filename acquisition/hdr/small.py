"""The linear HDR merge's pass in numpy, for small images: the compiled pass's arithmetic, bit for bit.

Below ``NUMPY_BELOW`` pixel values a frame (an ROI crop) the merge runs here, so numba, whose import and
start-up are a large part of a run's start, is not loaded for it: a simulated run with ROI crops never loads it. Every
value is computed with the operations of :func:`acquisition.hdr.kernel._merge_kernel`, in its order and in
float64, frame by frame (sums accumulate in frame order, as the compiled loop does), so the results are the
same bits; ``tests/acquisition/test_hdr_small.py`` checks that on random brackets. The estimator is described
in :mod:`acquisition.hdr.merge`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
Pass = tuple[F32, F32, npt.NDArray[np.uint8], npt.NDArray[np.uint8]]


@dataclass(frozen=True)
class Inputs:
    """What a pass reads, one entry per frame (:class:`acquisition.hdr.prepared._Prepared` adds which pass runs)."""

    #: Each frame's pixel values, flat (uint16 or float32).
    data: tuple[npt.NDArray[Any], ...]
    #: Each frame's per-pixel offset (counts, flat), or None: ``off_s``.
    offmaps: tuple[npt.NDArray[Any], ...] | None
    #: Each frame's offset (counts) where there are no maps.
    off_s: F64
    #: Each frame's saturation threshold on the raw value (counts).
    thr_raw: F64
    #: Each frame's exposure times gain (s).
    expo: F64
    #: Each frame's shot-noise variance per unit radiance (counts^2 per count/s).
    shot: F64
    #: Each frame's variance at zero signal (counts^2), its dark's included.
    cvar: F64
    #: Index of the shortest frame.
    shortest: int
    #: Index of the longest frame.
    longest: int
    #: DARK below this signal in the longest frame (counts).
    dark_thr: float


#: Frames of fewer pixel values than this merge in numpy. At ROI sizes (a few hundred values) what the numpy pass
#: costs over the compiled one is far less than loading numba, which a run on ROI crops then never does.
NUMPY_BELOW = 1 << 13


class _Sums:
    """The sum pass's per-pixel terms, kept so an inverse-variance pass on the same bracket reuses them.

    Arrays are (frames, pixels). The compiled pass adds a frame's terms to its sums only where the frame is
    used; here every frame adds them there and 0.0 elsewhere, in frame order, which is the same: the sums
    start at +0.0 and never become -0.0 (x + -x is +0.0), and adding 0.0 to anything else changes no bit.
    """

    def __init__(self, prep: Inputs) -> None:
        raw = np.array(prep.data, dtype=np.float64)
        if prep.offmaps is not None:
            self.y = raw - np.array(prep.offmaps, dtype=np.float64)
        else:
            self.y = raw - prep.off_s[:, None]
        # The compiled pass compares the raw value, converted to float64, with the threshold.
        self.use = raw < prep.thr_raw[:, None]
        n_frames, n = raw.shape
        terms = np.empty((n_frames, 4, n))
        terms[:, 0] = self.y
        terms[:, 1] = prep.expo[:, None]
        terms[:, 2] = prep.shot[:, None]
        terms[:, 3] = prep.cvar[:, None]
        s, e, a, b = _ordered_sum(np.where(self.use[:, None, :], terms, 0.0))
        self.m = np.add.reduce(self.use, axis=0, dtype=np.intp)
        self.x = s / e
        self.xp = np.where(self.x > 0.0, self.x, 0.0)
        self.var_sum = (self.xp * a + b) / (e * e)

    def iv(self, prep: Inputs, signal: F64, with_radiance: bool) -> tuple[F64 | None, F64]:
        """The inverse-variance radiance (None unless asked) and variance where ``m > 1``, weighted by ``signal``."""
        xs = np.where(signal > 0.0, signal, 0.0)
        expo, shot, cvar = prep.expo[:, None], prep.shot[:, None], prep.cvar[:, None]
        w = expo / (xs * shot + cvar)
        terms = np.empty((len(self.y), 3, self.x.size))
        if with_radiance:
            np.multiply(w, self.y, out=terms[:, 0])
        else:
            terms[:, 0] = 0.0
        np.multiply(w, expo, out=terms[:, 1])
        np.multiply(w * w, self.xp * shot + cvar, out=terms[:, 2])
        wy, we, ww = _ordered_sum(np.where(self.use[:, None, :], terms, 0.0))
        return (wy / we if with_radiance else None), ww / (we * we)

    def finish(self, prep: Inputs, rad: F64, var: F64) -> Pass:
        """The pass's outputs: pixels used in no frame take the shortest frame's value, +inf and SATURATED."""
        flags = np.where(self.y[prep.longest] < prep.dark_thr, np.uint8(2), np.uint8(0))
        none = self.m == 0
        if none.any():
            rad = np.where(none, self.y[prep.shortest] / prep.expo[prep.shortest], rad)
            var = np.where(none, np.inf, var)
            flags[none] = 1
        return rad.astype(np.float32), var.astype(np.float32), flags, self.m.astype(np.uint8)


def _ordered_sum(terms: F64) -> F64:
    """``terms`` summed over the first axis from +0.0, in order (numpy's own reductions may reorder)."""
    total = terms[0] + 0.0
    for k in range(1, len(terms)):
        total += terms[k]
    return total


def _one_frame(prep: Inputs) -> Pass:
    """The pass on a one-frame bracket: a pixel uses the frame or nothing, so either weighting is the sum pass.

    The sums are that frame's numbers where it is used (s = 0.0 + y, e = expo, a = shot, b = cvar); a pixel
    that does not use it takes y / expo, as the compiled pass's shortest frame.
    """
    raw = prep.data[0].astype(np.float64)
    y = raw - (prep.offmaps[0].astype(np.float64) if prep.offmaps is not None else prep.off_s[0])
    use = raw < prep.thr_raw[0]
    e = prep.expo[0]
    rad = (y + 0.0) / e
    xp = np.where(rad > 0.0, rad, 0.0)
    var = (xp * prep.shot[0] + prep.cvar[0]) / (e * e)
    flags = np.where(y < prep.dark_thr, np.uint8(2), np.uint8(0))
    if not use.all():
        none = ~use
        rad = np.where(none, y / e, rad)
        var = np.where(none, np.inf, var)
        flags[none] = 1
    return rad.astype(np.float32), var.astype(np.float32), flags, use.astype(np.uint8)


def run_small(prep: Inputs, inverse_variance: bool, signal: F64 | None) -> Pass:
    """Radiance, variance, flags and frames used, flat: the compiled pass's outputs, computed in numpy."""
    with np.errstate(all="ignore"):
        if len(prep.data) == 1:
            return _one_frame(prep)
        sums = _Sums(prep)
        if not inverse_variance:
            return sums.finish(prep, sums.x, sums.var_sum)
        assert signal is not None
        rad_iv, var_iv = sums.iv(prep, np.asarray(signal, dtype=np.float64), True)
        assert rad_iv is not None
        several = sums.m > 1
        return sums.finish(prep, np.where(several, rad_iv, sums.x), np.where(several, var_iv, sums.var_sum))


def sum_and_predicted_iv(prep: Inputs) -> tuple[Pass, F32]:
    """The sum pass, and the inverse-variance pass's variance weighted by that pass's radiance (float32).

    What the auto weighting compares, in one go: the same bits as ``run(False)`` then ``run(True, rad)``.
    Where no pixel uses two frames the inverse-variance pass is the sum pass, so it is not computed.
    """
    with np.errstate(all="ignore"):
        if len(prep.data) == 1:
            first = _one_frame(prep)
            return first, first[1]
        sums = _Sums(prep)
        first = sums.finish(prep, sums.x, sums.var_sum)
        several = sums.m > 1
        if not several.any():
            return first, first[1]
        _, var_iv = sums.iv(prep, first[0].astype(np.float64), False)
        var = np.where(several, var_iv, sums.var_sum)
        var = np.where(sums.m == 0, np.inf, var).astype(np.float32)
    return first, var


def top_counts(flat: npt.NDArray[Any], lo: Any, mid: Any) -> tuple[int, int, Any]:
    """Pixels in [lo, mid), pixels >= mid and their sum: the compiled ``_top_counts``, the same numbers.

    Integer data sums exactly in int64; float data in float64 in pixel order (a cumulative sum, not numpy's
    pairwise sum, whose rounding differs).
    """
    if isinstance(lo, int) and flat.dtype.kind in "ui":
        values = flat  # integers compare exactly with any Python int (numpy 2), no int64 copy needed
    else:
        values = flat.astype(np.int64) if isinstance(lo, int) else flat.astype(np.float64)
    top = values >= mid
    n_top = int(np.count_nonzero(top))
    if mid >= lo:  # then every top value is >= lo too (a NaN is neither)
        n_below = int(np.count_nonzero(values >= lo)) - n_top
    else:
        n_below = int(np.count_nonzero((values >= lo) & ~top))
    picked = values[top]
    if isinstance(lo, int):
        return n_below, n_top, int(picked.sum(dtype=np.int64))
    total = float(np.add.accumulate(np.concatenate(([0.0], picked)))[-1])
    return n_below, n_top, total
