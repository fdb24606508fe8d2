"""The ROI reading and level take shortcuts where every pixel is usable: the same numbers, to the bit, as before.

``reduce_roi`` skips its masks where no pixel is flagged and all are finite, and ``level_of`` its nanmean
where nothing clipped. The references here compute the same statistics another way, through numpy's masked
arrays (the ROI chosen by a boolean mask, a channel's excluded pixels masked out, ``MaskedArray.mean`` and
``.var``), and are compared field by field on random images, with and without saturated, dark and
non-finite pixels. Both sum the used pixels in raster order, so they agree to the bit, not to a tolerance.
"""

from __future__ import annotations

import itertools
import re
from collections.abc import Iterator
from typing import Any

import numpy as np
import numpy.ma as ma
import numpy.typing as npt
import pytest

from acquisition.cfa import colour_planes, reduce_hdr_roi
from acquisition.hdr.merge import HdrFlag, HdrImage
from acquisition.roi import Box, ErrorModel, FlaggedPolicy, RoiError, RoiReading, reduce_roi
from rig.run.measuring.measure import Level, level_of, snr_reached

BoolArray = npt.NDArray[np.bool_]


def reference_level_of(hdr: HdrImage, roi: Box | None) -> Level:
    """The ROI's level by masked arrays: peak, mean and 1st percentile of its finite pixels, and per channel
    the mean of the channel's finite pixels (the overall mean where a channel has none)."""
    h, w = hdr.radiance.shape[:2]
    rad = colour_planes(hdr, roi if roi is not None else (0, 0, w, h))
    finite = ma.masked_invalid(rad)
    values = finite.compressed()
    n = rad.shape[0] * rad.shape[1]
    if values.size == 0:
        return Level(0.0, 0.0, 0.0, n)
    means: tuple[float, ...] = ()
    if rad.ndim == 3 and rad.shape[-1] > 1:
        per = finite.reshape(-1, rad.shape[-1]).mean(axis=0)
        means = tuple(float(values.mean()) if m is ma.masked else float(m) for m in per)
    return Level(float(values.max()), float(values.mean()), float(max(np.percentile(values, 1.0), 0.0)), n, means)


def reference_reading(
    radiance: npt.NDArray[np.floating],
    variance: npt.NDArray[np.floating],
    roi: Box | BoolArray,
    flags: BoolArray | None = None,
    dark: BoolArray | None = None,
    policy: FlaggedPolicy = "exclude",
    model: ErrorModel = "max",
) -> RoiReading | str:
    """The ROI's reading by masked arrays, or the whole RoiError message it must raise.

    A channel's flagged pixels are masked out (``exclude``) or kept with no variance (``lower_bound``); the
    mean is the masked mean, the propagated error sqrt(sum of variances) / n, the spatial one
    sqrt(var(ddof=1) / n) (NaN for one pixel), and ``max`` the larger of the two. Only the inputs of the
    tests below: boxes that fit, policies that do not raise on a flag, finite values where used.
    """
    if isinstance(roi, np.ndarray):
        inside = roi
    else:
        x0, y0, x1, y1 = roi
        inside = np.zeros(radiance.shape[:2], dtype=bool)
        inside[y0:y1, x0:x1] = True
    n_pixels = int(inside.sum())

    def pixels(a: npt.NDArray[Any]) -> npt.NDArray[Any]:
        """The ROI's pixels in raster order as (N, C), a per-pixel (H, W) array repeated over the channels."""
        if a.ndim < radiance.ndim:
            a = np.broadcast_to(a[..., None], radiance.shape)
        return a[inside].reshape(n_pixels, -1)

    x = pixels(radiance).astype(np.float64)
    v = pixels(variance).astype(np.float64)
    flagged = pixels(flags) if flags is not None else np.zeros(x.shape, dtype=bool)
    if policy == "lower_bound":  # a clipped pixel kept as a lower bound: its value, but no noise term
        used, v = np.ones_like(flagged), np.where(flagged, 0.0, v)
    else:
        used = ~flagged
    n_used = used.sum(axis=0)
    if not n_used.all():
        empty = [c for c, n in enumerate(n_used) if n == 0]
        return f"all {n_pixels} ROI pixels are flagged in channel(s) {empty}: no reading possible"
    assert np.isfinite(x[used]).all() and np.isfinite(v[used]).all()
    xm = ma.masked_array(x, mask=~used, shrink=False)
    vm = ma.masked_array(v, mask=~used, shrink=False)
    mean = ma.getdata(xm.mean(axis=0))
    prop = np.sqrt(ma.getdata(vm.sum(axis=0))) / n_used
    spatial = ma.sqrt(xm.var(axis=0, ddof=1) / n_used).filled(np.nan)  # masked where n_used - 1 is 0
    se = {"propagated": prop, "spatial": spatial, "max": np.fmax(prop, spatial)}[model]
    n_dark = pixels(dark).sum(axis=0) if dark is not None else np.zeros(x.shape[1])
    channels = radiance.shape[2:]  # () for an (H, W) image

    def floats(a: npt.ArrayLike) -> npt.NDArray[np.float64]:
        return np.asarray(a, dtype=np.float64).reshape(channels)

    def counts(a: npt.ArrayLike) -> npt.NDArray[np.int64]:
        return np.asarray(a, dtype=np.int64).reshape(channels)

    return RoiReading(
        mean=floats(mean),
        std_error=floats(se),
        std_error_propagated=floats(prop),
        std_error_spatial=floats(spatial),
        n_pixels=n_pixels,
        n_used=counts(n_used),
        n_flagged=counts(flagged.sum(axis=0)),
        lower_bound=policy == "lower_bound" and bool(flagged.any()),
        error_model=model,
        n_dark=counts(n_dark),
    )


def _image(rng: np.random.Generator, shape: tuple[int, ...], kind: str) -> HdrImage:
    rad = rng.uniform(-50.0, 5e4, shape).astype(np.float32)
    var = rng.uniform(0.0, 3e3, shape).astype(np.float32)
    flags = np.zeros(shape, dtype=np.uint8)
    if kind in ("saturated", "both"):
        hit = rng.random(shape) < 0.15
        flags[hit] |= np.uint8(HdrFlag.SATURATED)
        rad[hit], var[hit] = np.float32(6e4), np.float32(np.inf)
    if kind in ("dark", "both"):
        flags[rng.random(shape) < 0.3] |= np.uint8(HdrFlag.DARK)
    if kind == "nan":
        rad[rng.random(shape) < 0.1] = np.nan
    return HdrImage(rad, var, flags, np.ones(shape, dtype=np.uint8), (0.01,), {"kind": "linear"})


def same_reading(a: RoiReading, b: RoiReading) -> None:
    for name in ("mean", "std_error", "std_error_propagated", "std_error_spatial", "n_used", "n_flagged", "n_dark"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape, name
        assert np.array_equal(x, y, equal_nan=True), name
    assert (a.n_pixels, a.lower_bound, a.error_model) == (b.n_pixels, b.lower_bound, b.error_model)


SHAPES = [(12, 12, 3), (2, 4, 3), (8, 10, 3), (1, 1, 3), (6, 5), (4, 4, 1)]


def images(kind: str, seed: int, per_shape: int) -> Iterator[tuple[np.random.Generator, HdrImage]]:
    """``per_shape`` random images of each of SHAPES, with the generator (the caller draws its ROIs from it)."""
    rng = np.random.default_rng(seed)
    for shape, _ in itertools.product(SHAPES, range(per_shape)):
        yield rng, _image(rng, shape, kind)


@pytest.mark.parametrize("kind", ["clean", "saturated", "dark", "both"])
def test_reduce_roi_equals_the_reference(kind: str) -> None:
    for rng, hdr in images(kind, 17, 25):
        h, w = hdr.radiance.shape[:2]
        x0, y0 = int(rng.integers(0, w)), int(rng.integers(0, h))
        boxes: list[Box] = [(0, 0, w, h), (x0, y0, int(rng.integers(x0 + 1, w + 1)), int(rng.integers(y0 + 1, h + 1)))]
        policies: tuple[FlaggedPolicy, ...] = ("exclude", "lower_bound")
        models: tuple[ErrorModel, ...] = ("max", "propagated", "spatial")
        for box, policy, model in itertools.product(boxes, policies, models):
            expected = reference_reading(hdr.radiance, hdr.variance, box, hdr.saturated, hdr.dark, policy, model)
            kw = {"flags": hdr.saturated, "on_flagged": policy, "error_model": model, "dark": hdr.dark}
            if isinstance(expected, str):
                with pytest.raises(RoiError, match=f"^{re.escape(expected)}$"):
                    reduce_roi(hdr.radiance, hdr.variance, box, **kw)  # type: ignore[arg-type]
                continue
            same_reading(reduce_roi(hdr.radiance, hdr.variance, box, **kw), expected)  # type: ignore[arg-type]
        whole = reference_reading(hdr.radiance, hdr.variance, boxes[0], hdr.saturated, hdr.dark)
        if not isinstance(whole, str):
            same_reading(reduce_hdr_roi(hdr, boxes[0]), whole)


def test_reduce_roi_without_flags_and_with_a_mask_equals_the_reference() -> None:
    rng = np.random.default_rng(4)
    for shape in SHAPES:
        hdr = _image(rng, shape, "clean")
        mask = rng.random(shape[:2]) < 0.5
        mask[0, 0] = True
        for roi in (mask, (0, 0, shape[1], shape[0])):
            expected = reference_reading(hdr.radiance, hdr.variance, roi)
            assert isinstance(expected, RoiReading)
            same_reading(reduce_roi(hdr.radiance, hdr.variance, roi), expected)


@pytest.mark.filterwarnings("ignore:Mean of empty slice")  # level_of's nanmean, on a channel with no finite pixel
@pytest.mark.parametrize("kind", ["clean", "saturated", "nan", "both"])
def test_level_of_equals_the_reference(kind: str) -> None:
    for _, hdr in images(kind, 23, 30):
        h, w = hdr.radiance.shape[:2]
        for box in (None, (0, 0, w, h), (0, 0, max(1, w // 2), max(1, h // 2))):
            got, want = level_of(hdr, box), reference_level_of(hdr, box)
            assert repr(got) == repr(want)  # repr: NaN equals NaN, -0.0 differs from 0.0


def test_the_hdr_reading_masks_are_the_images_own() -> None:
    from acquisition import cfa

    rng = np.random.default_rng(2)
    flags = rng.integers(0, 8, (6, 7, 3)).astype(np.uint8)
    hdr = HdrImage(np.ones(flags.shape, np.float32), np.ones(flags.shape, np.float32), flags,
                   np.ones(flags.shape, np.uint8), (0.01,), {"kind": "linear"})  # fmt: skip
    assert np.array_equal((hdr.flags & cfa._SATURATED_BITS) != 0, hdr.saturated)
    assert np.array_equal((hdr.flags & cfa._DARK_BITS) != 0, hdr.dark)


def reference_dark(r: RoiReading) -> bool:
    """``RoiReading.dark`` as it was, in numpy."""
    n_dark, used = np.atleast_1d(r.n_dark), np.atleast_1d(r.n_used)
    mean, se = np.atleast_1d(r.mean), np.atleast_1d(r.std_error)
    with np.errstate(invalid="ignore"):
        undetected = ~(mean > 3.0 * se)
    return bool(np.any(2 * n_dark > used) or np.any(undetected))


def reference_snr_reached(reading: RoiReading) -> float:
    """``rig.run.measuring.measure.snr_reached`` as it was, in numpy."""
    mean = np.atleast_1d(np.asarray(reading.mean, dtype=np.float64))
    se = np.atleast_1d(np.asarray(reading.std_error_propagated, dtype=np.float64))
    ok = se > 0
    return float(np.min(np.abs(mean[ok]) / se[ok])) if np.any(ok) else float("inf")


@pytest.mark.filterwarnings("ignore:invalid value encountered")  # inf / inf, in numpy both ways
def test_dark_reading_and_snr_reached_equal_the_reference() -> None:
    rng = np.random.default_rng(31)
    specials = [0.0, -0.0, np.nan, np.inf, -np.inf, 1e-300]
    for _ in range(3000):
        c = int(rng.integers(1, 4))
        mean = rng.normal(0, 10, c)
        se = np.abs(rng.normal(0, 5, c))
        for arr in (mean, se):
            hit = rng.random(c) < 0.2
            arr[hit] = rng.choice(specials, int(hit.sum()))
        used = rng.integers(0, 20, c)
        n_dark = rng.integers(0, 20, c)
        one = (mean[0], se[0], used[0], n_dark[0]) if c == 1 else (mean, se, used[0], n_dark)
        shapes = [(mean, se, used, n_dark), one]
        for m, s, u, d in shapes:
            r = RoiReading(np.asarray(m), np.asarray(s), np.asarray(s), np.asarray(s), 20, np.asarray(u),
                           np.zeros_like(np.asarray(u)), False, "max", np.asarray(d))  # fmt: skip
            assert r.dark == reference_dark(r)
            assert type(r.dark) is bool
            assert repr(snr_reached(r)) == repr(reference_snr_reached(r))


def test_percentile_equals_numpys() -> None:
    from rig.run.measuring.measure import _percentile

    rng = np.random.default_rng(41)
    for _ in range(4000):
        n = int(rng.choice([1, 2, 3, 4, 16, 48, 99, 100, 101, 144, 432, 1000]))
        values = rng.normal(0, 1, n) * float(10 ** rng.uniform(-5, 5))
        if rng.random() < 0.3:
            values = np.round(values, 1)  # ties
        if rng.random() < 0.3:  # signed zeros: which one numpy picks depends on where its partition puts them
            hit = rng.random(n) < 0.5
            values[hit] = rng.choice([0.0, -0.0], int(hit.sum()))
        q = float(rng.choice([1.0, 0.5, 50.0, 99.0, 0.0, 100.0, float(rng.uniform(0, 100))]))
        assert repr(_percentile(values, q)) == repr(float(np.percentile(values, q))), (n, q)
