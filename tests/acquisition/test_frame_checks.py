"""A frame's exposure and gain checks: plain floats by ``math``, anything else by numpy, the same verdicts."""

import math

import numpy as np
import pytest

from acquisition.frame import Frame, FrameError, _positive


def reference(x: object) -> bool:
    return bool(np.isfinite(x) and x > 0)  # type: ignore[operator]


@pytest.mark.parametrize("x", [1.0, 5e-324, 1e308, 0.0, -0.0, -1.0, math.inf, -math.inf, math.nan, 3, 0, True,
                               np.float64(0.5), np.float32(-0.5), np.float64(math.nan), np.int64(2)])  # fmt: skip
def test_positive_is_numpys_verdict(x: object) -> None:
    assert _positive(x) is reference(x)  # type: ignore[arg-type]


@pytest.mark.parametrize(("field", "bad"), [("exposure_s", math.nan), ("exposure_s", 0.0), ("gain", -math.inf)])
def test_a_frame_refuses_what_it_refused(field: str, bad: float) -> None:
    data = np.zeros((2, 2), np.uint16)
    kwargs = {"exposure_s": 0.1, "gain": 1.0, field: bad}
    with pytest.raises(FrameError, match=f"frame from unknown: {field} = {bad!r}, expected a positive number"):
        Frame(data, "raw", **kwargs)


@pytest.mark.parametrize("shape", [(0, 16), (16, 0), (0, 0), (4, 0, 3)])
def test_a_frame_without_pixels_is_refused_naming_it(shape: tuple[int, ...]) -> None:
    # Once a numpy message from deep in the merge ("zero-size array to reduction operation maximum").
    with pytest.raises(FrameError, match=rf"frame from cam 7: data has shape \({shape[0]}, .*no pixels"):
        Frame(np.zeros(shape, np.uint16), "linear", 0.01, camera_id="cam 7")
