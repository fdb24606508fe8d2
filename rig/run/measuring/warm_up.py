"""Load the merge before the first point, as a step of its own; its compiled passes where they are needed.

The HDR merge runs ROI-sized images in numpy and larger ones in compiled passes that numba caches on disk
(``cache=True``): the first run on a machine compiles them, later runs only load them (numba's own start-up
included; bench/first_reading times both). Which a run needs is known only from its
frames, so the compiled passes load at the first large merge (a run on ROI crops never loads numba), and
:func:`notify_before_compiling` arms the notice shown before they compile. The warm-up step merges a tiny
synthetic bracket in each configuration a run uses (without and with dark frames, both weightings), so the
merge's own code is loaded before the progress bar starts. No frame is taken: the camera's noise stream
stays as it was.
"""

from __future__ import annotations

import numpy as np

from acquisition.frame import Frame
from acquisition.hdr.compiled import notify_before_compiling
from acquisition.hdr.merge import Weighting, merge_linear
from acquisition.noise import SensorNoise

__all__ = ["COMPILING", "kernels_cached", "notify_before_compiling", "warm_up"]

#: Shown before the compiled passes compile (not in numba's cache yet).
COMPILING = "compiling kernels (first run only)..."


def kernels_cached() -> bool:
    """Whether numba's on-disk cache already holds the merge's compiled passes (imports numba)."""
    from acquisition.hdr.kernel import cached

    return cached()


def warm_up(noise: SensorNoise) -> None:
    """Merge a 4 x 4 x 3 two-frame bracket of 16-bit counts each way a run does (numpy: no kernel loads)."""
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
