"""The compiled pass of the linear HDR merge: the numba kernel factory and the inputs it runs on.

Holds ``_merge_kernel`` (one compiled, all-cores pass per configuration), ``_padded_size`` (the frame
tuple is padded so brackets of similar length share a compilation) and ``_Prepared`` (the per-frame
arrays the pass reads, padded, with a pixel subsample for the auto weighting decision). The estimator it
computes is described in :mod:`acquisition.hdr.merge`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import numpy.typing as npt
from numba import prange

F32 = npt.NDArray[np.float32]

_JIT: dict[str, Any] = {"fastmath": False, "error_model": "numpy", "boundscheck": False, "cache": True}


#: Below this many pixel values the merge runs on one core: waking the thread pool costs more than it saves
#: on an ROI crop (a 12 x 12 x 3 crop took milliseconds in parallel on 2 busy cores, microseconds serially).
SERIAL_BELOW = 1 << 16


@functools.cache
def _merge_kernel(with_maps: bool, inverse_variance: bool, parallel: bool = True) -> Any:
    """The compiled pass for one configuration (compile-time constants, so the other branches fold away).

    ``with_maps``: some offset is a per-pixel map. The frame loop runs over the whole (padded) tuple, a
    compile-time length, so LLVM unrolls it and resolves each tuple item statically; padding frames have
    threshold -inf and are never used. Measured on 1 MP x 3 x 7 frames: a run-time frame count, a run-time
    tuple index, or the inverse-variance loop present but switched off by a run-time flag each made the
    sum pass 2-5x slower.
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


@dataclass(frozen=True)
class _Prepared:
    """Everything the compiled pass needs, per frame padded to ``_padded_size`` (padding is never used)."""

    data: tuple[npt.NDArray[Any], ...]
    offmaps: tuple[npt.NDArray[Any], ...] | None
    off_s: npt.NDArray[np.float64]
    thr_raw: npt.NDArray[np.float64]
    expo: npt.NDArray[np.float64]
    shot: npt.NDArray[np.float64]
    cvar: npt.NDArray[np.float64]
    shortest: int
    longest: int
    dark_thr: float

    def subsample(self, stride: int) -> _Prepared:
        """The same merge on every ``stride``-th pixel."""
        def sub(arrays: tuple[npt.NDArray[Any], ...]) -> tuple[npt.NDArray[Any], ...]:
            cache: dict[int, npt.NDArray[Any]] = {}
            return tuple(cache.setdefault(id(a), np.ascontiguousarray(a[::stride])) for a in arrays)

        maps = None if self.offmaps is None else sub(self.offmaps)
        return dataclasses.replace(self, data=sub(self.data), offmaps=maps)

    def run(
        self, inverse_variance: bool, signal: npt.NDArray[np.float64] | None = None
    ) -> tuple[F32, F32, npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
        """Radiance, variance, flags and frames used, flat.

        ``signal`` (counts/s per pixel, flat) sets the inverse-variance weights; None uses each pixel's own
        first-pass estimate, which is biased at low signal and serves only to predict variances.
        """
        n = self.data[0].size
        if inverse_variance and signal is None:
            signal = self.run(False)[0].astype(np.float64)
        if signal is None:
            signal = np.zeros(1)
        rad = np.empty(n, np.float32)
        var = np.empty(n, np.float32)
        flags = np.empty(n, np.uint8)
        used = np.empty(n, np.uint8)
        with_maps = self.offmaps is not None
        maps = self.offmaps if self.offmaps is not None else (np.zeros(1, np.float32),) * len(self.data)
        _merge_kernel(with_maps, inverse_variance, n >= SERIAL_BELOW)(
            self.data, maps, self.off_s, self.thr_raw, self.expo, self.shot, self.cvar, self.shortest, self.longest,
            self.dark_thr, np.ascontiguousarray(signal, dtype=np.float64), rad, var, flags, used,
        )
        return rad, var, flags, used
