"""The linear HDR merge's pass in numpy, for small images: the compiled pass's arithmetic, bit for bit.

Below ``NUMPY_BELOW`` pixel values a frame (an ROI crop) the merge runs here, so numba, whose import and
start-up take about a second, is not loaded for it: a simulated run with ROI crops never loads it. Every
value is computed with the operations of :func:`acquisition.hdr.kernel._merge_kernel`, in its order and in
float64, frame by frame (sums accumulate in frame order, as the compiled loop does), so the results are the
same bits; ``tests/acquisition/test_hdr_small.py`` checks that on random brackets. The estimator is described
in :mod:`acquisition.hdr.merge`.
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

F32 = npt.NDArray[np.float32]
F64 = npt.NDArray[np.float64]
Pass = tuple[F32, F32, npt.NDArray[np.uint8], npt.NDArray[np.uint8]]


class Inputs(Protocol):
    """What a pass reads (:class:`acquisition.hdr.prepared._Prepared`): one entry per frame."""

    @property
    def data(self) -> tuple[npt.NDArray[Any], ...]:
        """Each frame's pixel values, flat (uint16 or float32)."""

    @property
    def offmaps(self) -> tuple[npt.NDArray[Any], ...] | None:
        """Each frame's per-pixel offset (counts, flat), or None: ``off_s``."""

    @property
    def off_s(self) -> F64:
        """Each frame's offset (counts) where there are no maps."""

    @property
    def thr_raw(self) -> F64:
        """Each frame's saturation threshold on the raw value (counts)."""

    @property
    def expo(self) -> F64:
        """Each frame's exposure times gain (s)."""

    @property
    def shot(self) -> F64:
        """Each frame's shot-noise variance per unit radiance (counts^2 per count/s)."""

    @property
    def cvar(self) -> F64:
        """Each frame's variance at zero signal (counts^2), its dark's included."""

    @property
    def shortest(self) -> int:
        """Index of the shortest frame."""

    @property
    def longest(self) -> int:
        """Index of the longest frame."""

    @property
    def dark_thr(self) -> float:
        """DARK below this signal in the longest frame (counts)."""


#: Frames of fewer pixel values than this merge in numpy: at ROI sizes a numpy pass costs tens of
#: microseconds, like the compiled pass's call, and spares loading numba (about 1 s on a 2-core host).
NUMPY_BELOW = 1 << 13


class _Sums:
    """The sum pass's per-pixel terms, kept so an inverse-variance pass on the same bracket reuses them."""

    def __init__(self, prep: Inputs) -> None:
        n_frames = len(prep.data)
        data = [np.asarray(d, dtype=np.float64) for d in prep.data]
        if prep.offmaps is not None:
            self.y = [d - np.asarray(o, dtype=np.float64) for d, o in zip(data, prep.offmaps, strict=True)]
        else:
            self.y = [d - prep.off_s[k] for k, d in enumerate(data)]
        # The compiled pass compares the raw value, converted to float64, with the threshold.
        self.use = [d < prep.thr_raw[k] for k, d in enumerate(data)]
        n = data[0].size
        # s, e, a, b of the compiled pass in one array: rows added together where the frame is used.
        acc = np.zeros((4, n))
        for k in range(n_frames):
            terms = np.empty((4, n))
            terms[0] = self.y[k]
            terms[1] = prep.expo[k]
            terms[2] = prep.shot[k]
            terms[3] = prep.cvar[k]
            acc = np.where(self.use[k], acc + terms, acc)
        self.m = np.add.reduce(self.use, axis=0, dtype=np.intp) if n_frames > 1 else self.use[0].astype(np.intp)
        s, e, a, b = acc
        self.e = e
        self.x = s / e
        self.xp = np.where(self.x > 0.0, self.x, 0.0)
        self.var_sum = (self.xp * a + b) / (e * e)

    def iv(self, prep: Inputs, signal: F64, with_radiance: bool) -> tuple[F64 | None, F64]:
        """The inverse-variance radiance (None unless asked) and variance where ``m > 1``, weighted by ``signal``."""
        xs = np.where(signal > 0.0, signal, 0.0)
        n = self.x.size
        wy = np.zeros(n)
        we = np.zeros(n)
        ww = np.zeros(n)
        for k, use in enumerate(self.use):
            w = prep.expo[k] / (xs * prep.shot[k] + prep.cvar[k])
            if with_radiance:
                wy = np.where(use, wy + w * self.y[k], wy)
            we = np.where(use, we + w * prep.expo[k], we)
            ww = np.where(use, ww + w * w * (self.xp * prep.shot[k] + prep.cvar[k]), ww)
        return (wy / we if with_radiance else None), ww / (we * we)

    def finish(self, prep: Inputs, rad: F64, var: F64) -> Pass:
        """The pass's outputs: pixels used in no frame take the shortest frame's value, +inf and SATURATED."""
        none = self.m == 0
        y_short = self.y[prep.shortest]
        rad = np.where(none, y_short / prep.expo[prep.shortest], rad)
        var = np.where(none, np.inf, var)
        flags = np.where(none, 1, np.where(self.y[prep.longest] < prep.dark_thr, 2, 0)).astype(np.uint8)
        return rad.astype(np.float32), var.astype(np.float32), flags, self.m.astype(np.uint8)


def run_small(prep: Inputs, inverse_variance: bool, signal: F64 | None) -> Pass:
    """Radiance, variance, flags and frames used, flat: the compiled pass's outputs, computed in numpy."""
    with np.errstate(all="ignore"):
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
    """
    with np.errstate(all="ignore"):
        sums = _Sums(prep)
        first = sums.finish(prep, sums.x, sums.var_sum)
        _, var_iv = sums.iv(prep, first[0].astype(np.float64), False)
        var = np.where(sums.m > 1, var_iv, sums.var_sum)
        var = np.where(sums.m == 0, np.inf, var).astype(np.float32)
    return first, var


def top_counts(flat: npt.NDArray[Any], lo: Any, mid: Any) -> tuple[int, int, Any]:
    """Pixels in [lo, mid), pixels >= mid and their sum: the compiled ``_top_counts``, the same numbers.

    Integer data sums exactly in int64; float data in float64 in pixel order (a cumulative sum, not numpy's
    pairwise sum, whose rounding differs).
    """
    values = flat.astype(np.int64) if isinstance(lo, int) else flat.astype(np.float64)
    top = values >= mid
    n_top = int(np.count_nonzero(top))
    n_below = int(np.count_nonzero((values >= lo) & ~top))
    picked = values[top]
    if isinstance(lo, int):
        return n_below, n_top, int(picked.sum())
    total = float(np.add.accumulate(np.concatenate(([0.0], picked)))[-1])
    return n_below, n_top, total
