"""The compiled passes of the HDR merge (numba): the merge kernel factory, its call, the plateau count.

Holds ``_merge_kernel`` (one compiled, all-cores pass per configuration), ``run_compiled`` (pads the
bracket's frames, so brackets of similar length share a compilation, and calls it) and ``_top_counts`` (the
saturation plateau's count). Imported only for images too large for the numpy pass of
:mod:`acquisition.hdr.small`, which computes the same bits: importing numba is a large part of a start. The
estimator is described in :mod:`acquisition.hdr.merge`.
"""

from __future__ import annotations

import functools
import math
import os
from typing import TYPE_CHECKING, Any

import numba
import numpy as np
import numpy.typing as npt
from numba import prange

if TYPE_CHECKING:
    from acquisition.hdr.small import Inputs, Pass

_JIT: dict[str, Any] = {"fastmath": False, "error_model": "numpy", "boundscheck": False, "cache": True}


#: Below this many pixel values the merge runs on one core: on an ROI crop, waking the thread pool (on busy cores,
#: waiting for a time slice) costs more than the parallel pass saves.
SERIAL_BELOW = 1 << 16


@functools.cache
def _merge_kernel(with_maps: bool, inverse_variance: bool, parallel: bool = True) -> Any:
    """The compiled pass for one configuration (compile-time constants, so the other branches fold away).

    ``with_maps``: some offset is a per-pixel map. The frame loop runs over the whole (padded) tuple, a
    compile-time length, so LLVM unrolls it and resolves each tuple item statically; padding frames have
    threshold -inf and are never used. A run-time frame count, a run-time tuple index, or the inverse-variance
    loop present but switched off by a run-time flag each kept LLVM from specialising the sum pass, which then
    ran several times slower (bench/hdr).
    """

    @numba.njit(parallel=parallel, **_JIT)
    def kernel(  # pragma: no cover (compiled)
        data: Any, offmaps: Any, off_s: Any, thr_raw: Any, expo: Any, shot: Any, cvar: Any,
        shortest: int, longest: int, dark_thr: float, signal: Any, rad: Any, var: Any, flags: Any, used: Any,
    ) -> None:
        for i in prange(rad.size):
            s = 0.0
            e = 0.0
            a = 0.0
            b = 0.0
            m = 0
            y_short = 0.0
            y_long = 0.0
            for k in range(len(data)):
                y = np.float64(data[k][i]) - (offmaps[k][i] if with_maps else off_s[k])
                # Picked up inside the unrolled loop: indexing the tuple with a run-time index costs more.
                if k == shortest:
                    y_short = y
                if k == longest:
                    y_long = y
                if data[k][i] < thr_raw[k]:
                    s += y
                    e += expo[k]
                    a += shot[k]
                    b += cvar[k]
                    m += 1
            used[i] = m
            if m == 0:
                rad[i] = y_short / expo[shortest]
                var[i] = np.inf
                flags[i] = 1
                continue
            x = s / e
            xp = x if x > 0.0 else 0.0
            if inverse_variance and m > 1:
                # Weights from ``signal`` (the neighbours' level), never from this pixel's own frames: weights
                # that follow a pixel's own noise bias the weighted mean (high at low signal).
                xs = signal[i] if signal[i] > 0.0 else 0.0
                wy = 0.0
                we = 0.0
                ww = 0.0
                for k in range(len(data)):
                    if data[k][i] < thr_raw[k]:
                        w = expo[k] / (xs * shot[k] + cvar[k])
                        wy += w * (np.float64(data[k][i]) - (offmaps[k][i] if with_maps else off_s[k]))
                        we += w * expo[k]
                        ww += w * w * (xp * shot[k] + cvar[k])
                rad[i] = wy / we
                var[i] = ww / (we * we)
            else:
                rad[i] = x
                var[i] = (xp * a + b) / (e * e)
            flags[i] = 2 if y_long < dark_thr else 0

    return kernel


def _padded_size(n_frames: int) -> int:
    # The compiled pass is specialised on the tuple length: pad to a multiple of 8 so brackets of 1-8
    # frames share one compilation (cached on disk), 9-16 another, and so on.
    return 8 * math.ceil(n_frames / 8)


def run_compiled(prep: Inputs, inverse_variance: bool, signal: npt.NDArray[np.float64] | None) -> Pass:
    """Radiance, variance, flags and frames used, flat, from the compiled pass (``signal`` as in ``run``)."""
    n_frames = len(prep.data)
    pad = _padded_size(n_frames) - n_frames

    def padded(values: npt.NDArray[np.float64], fill: float) -> npt.NDArray[np.float64]:
        return np.concatenate((values, np.full(pad, fill)))

    # Padding frames have threshold -inf and are never used; their offsets and exposures only need to exist.
    data = prep.data + (prep.data[0],) * pad
    n = prep.data[0].size
    if signal is None:
        signal = np.zeros(1)
    rad = np.empty(n, np.float32)
    var = np.empty(n, np.float32)
    flags = np.empty(n, np.uint8)
    used = np.empty(n, np.uint8)
    with_maps = prep.offmaps is not None
    zeros = (np.zeros(1, np.float32),) * len(data)
    maps = prep.offmaps + (prep.offmaps[0],) * pad if prep.offmaps is not None else zeros
    _merge_kernel(with_maps, inverse_variance, n >= SERIAL_BELOW)(
        data, maps, padded(prep.off_s, 0.0), padded(prep.thr_raw, -np.inf), padded(prep.expo, 1.0),
        padded(prep.shot, 0.0), padded(prep.cvar, 1.0), prep.shortest, prep.longest, prep.dark_thr,
        np.ascontiguousarray(signal, dtype=np.float64), rad, var, flags, used,
    )
    return rad, var, flags, used


@numba.njit(**_JIT)
def _top_counts(flat: npt.NDArray[Any], lo: Any, mid: Any) -> tuple[int, int, Any]:  # pragma: no cover
    # Pixels in [lo, mid), pixels >= mid and their sum, in one branch-free pass. ``lo - lo`` is a zero of
    # lo's type: integers for integer data (exact sums, and quicker than a parallel float reduction).
    zero = lo - lo
    n_below = 0
    n_top = 0
    sum_top = zero
    for i in range(flat.size):
        v = flat[i] + zero
        top = v >= mid
        n_top += 1 if top else 0
        sum_top += v if top else zero
        n_below += 1 if (v >= lo and not top) else 0
    return n_below, n_top, sum_top


def cached() -> bool:
    """Whether numba's on-disk cache already holds the compiled passes (False where that cannot be told)."""
    for dispatcher in (_merge_kernel(False, False, False), _merge_kernel(True, False, False), _top_counts):
        index = getattr(getattr(getattr(dispatcher, "_cache", None), "_cache_file", None), "_index_path", None)
        if not isinstance(index, str) or not os.path.exists(index):
            return False
    return True
