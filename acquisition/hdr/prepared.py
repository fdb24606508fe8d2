"""What the linear HDR merge's pass reads, per frame, and which pass runs it: numpy or compiled.

Holds ``_Prepared`` (the per-frame arrays and numbers, with a pixel subsample for the auto weighting
decision). Small images (an ROI crop, below ``NUMPY_BELOW`` pixel values) run the numpy pass of
:mod:`acquisition.hdr.small`; larger ones the compiled pass of :mod:`acquisition.hdr.kernel`, imported only
then, so numba loads only for a merge that needs it. Both give the same bits. The estimator is described in
:mod:`acquisition.hdr.merge`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from acquisition.hdr.compiled import compiled
from acquisition.hdr.small import NUMPY_BELOW, Pass, run_small, sum_and_predicted_iv

F32 = npt.NDArray[np.float32]


@dataclass(frozen=True)
class _Prepared:
    """Everything the pass needs, one entry per frame of the bracket."""

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
