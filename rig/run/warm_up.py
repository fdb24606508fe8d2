"""Load (or, on a first run, compile) the merge's numba kernels before the first point, as a step of its own.

The HDR merge runs compiled passes that numba caches on disk (``cache=True``): the first run on a machine
compiles them (tens of seconds on a loaded 2-core host), later runs load them (about a second, numba's own
start-up included). Left to the first point, that cost hides inside it and inflates the first ETA; here it
runs on a tiny synthetic bracket in each configuration a run uses (without and with dark frames, both
weightings), before the progress bar starts. No frame is taken: the camera's noise stream stays as it was.
"""

from __future__ import annotations

import os

import numpy as np

from acquisition.frame import Frame
from acquisition.hdr.kernel import _merge_kernel
from acquisition.hdr.merge import Weighting, merge_linear
from acquisition.noise import SensorNoise

#: Shown before the step when the kernels are not in numba's cache yet.
COMPILING = "compiling kernels (first run only)..."


def kernels_cached() -> bool:
    """Whether numba's on-disk cache already holds the merge kernels (False where that cannot be told)."""
    for with_maps in (False, True):
        cache = getattr(_merge_kernel(with_maps, False, False), "_cache", None)
        index = getattr(getattr(cache, "_cache_file", None), "_index_path", None)
        if not isinstance(index, str) or not os.path.exists(index):
            return False
    return True


def warm_up(noise: SensorNoise) -> None:
    """Merge a 4 x 4 x 3 two-frame bracket of 16-bit counts each way a run does, so every kernel is loaded."""
    black = noise.black_level_dn

    def frame(level: float, exposure_s: float) -> Frame:
        data = np.full((4, 4, 3), black + level, dtype=np.uint16)
        data[0, 0] += 1  # not perfectly flat: the saturation plateau search sees a spread
        return Frame(data, "linear", exposure_s, black_level=black, white_level=noise.white_level_dn)

    bright = [frame(200.0, 0.01), frame(800.0, 0.04)]
    darks = {t: [frame(0.0, t)] for t in (0.01, 0.04)}
    weightings: tuple[Weighting, ...] = ("sum", "inverse_variance")
    for weighting in weightings:
        merge_linear(bright, noise, weighting=weighting)
        merge_linear(bright, noise, darks=darks, weighting=weighting)
