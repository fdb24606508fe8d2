"""The bracket check's settings and cropped frames: what ``dataclasses.replace`` made before, field by field."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

import rig.run.measuring.measure as measure
from acquisition.exposure.spec import CameraTiming
from acquisition.frame import Frame
from acquisition.noise import SensorNoise
from rig.run.measuring.measure import CaptureSettings, _Check, _check_settings, _cropped


def reference_roi_check(settings: CaptureSettings, frames: list[Frame]) -> _Check:
    """``rig.run.measuring.measure._roi_check`` before its shortcuts (replace for the settings and every frame)."""
    check = dataclasses.replace(settings, dark_frames=0)
    if settings.roi is not None:
        x0, y0, x1, y1 = settings.roi
        cx, cy = x0 - x0 % 2, y0 - y0 % 2
        box = (cx, cy, x1 + x1 % 2, y1 + y1 % 2)
        frames = [dataclasses.replace(f, data=measure._crop(f.data, box), origin_xy=(f.origin_xy[0] + cx,
                                      f.origin_xy[1] + cy)) for f in frames]  # fmt: skip
        check = dataclasses.replace(check, roi=(x0 - cx, y0 - cy, x1 - cx, y1 - cy))
    hdr, box = measure._merged(check, frames, None)
    return _Check(measure.reduce_hdr_roi(hdr, box), hdr, box)  # as patched, if a test patches them


class Tagged(Frame):
    pass


def fields_of(frame: Frame) -> dict[str, Any]:
    return {f.name: getattr(frame, f.name) for f in dataclasses.fields(frame)}


@pytest.mark.parametrize("roi", [None, (0, 0, 4, 4), (1, 3, 6, 8), (3, 2, 5, 3)])
def test_the_check_is_what_replace_made(roi: tuple[int, int, int, int] | None) -> None:
    rng = np.random.default_rng(4)
    settings = CaptureSettings(SensorNoise(), CameraTiming(), roi=roi)
    frames = [Frame(rng.integers(500, 9000, (10, 12, 3)).astype(np.uint16), "linear", 0.01 * k, black_level=512.0,
                    origin_xy=(k, 2 * k), extra={"k": k}) for k in (1, 2)]  # fmt: skip
    frames.append(Tagged(frames[0].data, "linear", 0.05, black_level=512.0, origin_xy=(7, 1)))
    for _ in range(2):  # the second time from the cached settings
        check, crop = _check_settings(settings)
        want = dataclasses.replace(settings, dark_frames=0)
        if roi is not None:
            x0, y0, x1, y1 = roi
            want = dataclasses.replace(want, roi=(x0 % 2, y0 % 2, x1 - (x0 - x0 % 2), y1 - (y0 - y0 % 2)))
        assert check == want
        if crop is None:
            continue
        for f in frames:
            cut = _cropped(f, crop)
            cx, cy = crop[:2]
            origin = (f.origin_xy[0] + cx, f.origin_xy[1] + cy)
            before = dataclasses.replace(f, data=measure._crop(f.data, crop), origin_xy=origin)
            assert type(cut) is type(before)
            got, ref = fields_of(cut), fields_of(before)
            assert np.array_equal(got.pop("data"), ref.pop("data")) and cut.data.base is not None
            assert got == ref and cut.extra is f.extra


def test_another_settings_object_is_not_taken_from_the_cache() -> None:
    a = CaptureSettings(SensorNoise(), CameraTiming(), roi=(1, 1, 5, 5))
    b = dataclasses.replace(a, roi=(2, 2, 4, 4))
    assert _check_settings(a)[1] == (0, 0, 6, 6)
    assert _check_settings(b)[1] == (2, 2, 4, 4)
    assert _check_settings(a)[0].roi == (1, 1, 5, 5)
