"""The ROI reading and level take shortcuts where every pixel is usable: the same numbers, to the bit, as before.

``reduce_roi`` skips its masks where no pixel is flagged and all are finite, and ``level_of`` its nanmean
where nothing clipped. The functions as they were (before the shortcuts) are kept here as the reference and
compared field by field on random images, with and without saturated, dark and non-finite pixels.
"""

from __future__ import annotations

import itertools

import numpy as np
import numpy.typing as npt
import pytest

from acquisition.cfa import colour_planes, reduce_hdr_roi
from acquisition.hdr.merge import HdrFlag, HdrImage
from acquisition.roi import (
    Box,
    ErrorModel,
    FlaggedPolicy,
    RoiError,
    RoiReading,
    _image_hw,
    _per_channel,
    _per_channel_count,
    reduce_roi,
)
from rig.run.measuring.measure import Level, level_of, snr_reached

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


def reference_level_of(hdr: HdrImage, roi: Box | None) -> Level:
    """``rig.run.measuring.measure.level_of`` before its shortcut."""
    h, w = hdr.radiance.shape[:2]
    rad = colour_planes(hdr, roi if roi is not None else (0, 0, w, h))
    finite = rad[np.isfinite(rad)]
    n = int(rad.shape[0] * rad.shape[1])
    if finite.size == 0:
        return Level(0.0, 0.0, 0.0, n)
    means: tuple[float, ...] = ()
    if rad.ndim == 3 and rad.shape[-1] > 1:
        with np.errstate(invalid="ignore"):
            per = np.nanmean(np.where(np.isfinite(rad), rad, np.nan).reshape(-1, rad.shape[-1]), axis=0)
        means = tuple(float(m) if np.isfinite(m) else float(finite.mean()) for m in per)
    return Level(float(finite.max()), float(finite.mean()), float(max(np.percentile(finite, 1.0), 0.0)), n, means)


def _reference_select(image: npt.NDArray[np.generic], roi: Box | BoolArray, name: str) -> FloatArray:
    """ROI pixels of an (H, W[, C]) image as a float array (N, C)."""
    if isinstance(roi, np.ndarray):
        if roi.dtype != np.bool_:
            raise RoiError(f"ROI mask has dtype {roi.dtype}: expected bool (use box_mask/circle_mask to build one)")
        if roi.shape != image.shape[:2]:
            raise RoiError(f"ROI mask has shape {roi.shape} but {name} has shape {image.shape}: expected (H, W) equal")
        if not roi.any():
            raise RoiError("ROI mask selects no pixel")
        pixels = image[roi]
    else:
        x0, y0, x1, y1 = _validate_box(tuple(roi), image.shape)
        pixels = image[y0:y1, x0:x1].reshape((y1 - y0) * (x1 - x0), *image.shape[2:])
    return np.asarray(pixels, dtype=np.float64).reshape(pixels.shape[0], -1)


def reference_reduce_roi(
    radiance: npt.ArrayLike,
    variance: npt.ArrayLike,
    roi: Box | BoolArray,
    flags: npt.ArrayLike | None = None,
    *,
    on_flagged: FlaggedPolicy = "exclude",
    error_model: ErrorModel = "max",
    dark: npt.ArrayLike | None = None,
) -> RoiReading:
    """Mean radiance (counts/s) of the ROI per channel with its standard error (counts/s); see the module doc.

    ``radiance`` and ``variance`` ((counts/s)^2) are (H, W) or (H, W, C) arrays of one shape (e.g. an
    HdrImage's fields); ``roi`` a box ``(x0, y0, x1, y1)`` or a boolean (H, W) mask; ``flags`` an (H, W)
    or (H, W, C) array whose non-zero entries mark pixels that must not be averaged in as they are.
    """
    rad = np.asarray(radiance)
    var = np.asarray(variance)
    _image_hw(rad.shape)
    if var.shape != rad.shape:
        raise RoiError(f"variance has shape {var.shape} but radiance has shape {rad.shape}: expected equal shapes")
    if on_flagged not in ("exclude", "lower_bound", "raise"):
        raise RoiError(f"on_flagged = {on_flagged!r}: expected 'exclude', 'lower_bound' or 'raise'")
    if error_model not in ("max", "propagated", "spatial"):
        raise RoiError(f"error_model = {error_model!r}: expected 'max', 'propagated' or 'spatial'")
    x = _reference_select(rad, roi, "radiance")
    v = _reference_select(var, roi, "variance")
    n_pixels, n_ch = x.shape
    if flags is None:
        flagged = np.zeros_like(x, dtype=bool)
    else:
        fl = np.asarray(flags)
        if fl.shape not in (rad.shape[:2], rad.shape):
            raise RoiError(
                f"flags have shape {fl.shape} but radiance has shape {rad.shape}: expected (H, W) or the same shape"
            )
        sel = _reference_select(fl != 0, roi, "flags") != 0
        flagged = np.broadcast_to(sel, x.shape) if sel.shape[1] == 1 else sel
    n_flagged = flagged.sum(axis=0)
    n_dark = np.zeros(n_ch, dtype=np.int64)
    if dark is not None:
        dk = np.asarray(dark)
        if dk.shape not in (rad.shape[:2], rad.shape):
            raise RoiError(f"dark has shape {dk.shape} but radiance has shape {rad.shape}: expected (H, W) or the same")
        sel_dark = _reference_select(dk != 0, roi, "dark") != 0
        n_dark = np.broadcast_to(sel_dark, x.shape).sum(axis=0) if sel_dark.shape[1] == 1 else sel_dark.sum(axis=0)
    if on_flagged == "raise" and n_flagged.any():
        raise RoiError(f"{int(n_flagged.max())} of {n_pixels} ROI pixels are flagged (on_flagged='raise')")
    used = ~flagged if on_flagged == "exclude" else np.ones_like(flagged)
    lower_bound = on_flagged == "lower_bound" and bool(n_flagged.any())

    # A pixel saturated in every frame has a clipped (lower-bound) radiance and no variance (the HDR merge
    # reports +inf): kept as a lower bound, it contributes its value but no noise term.
    if on_flagged == "lower_bound":
        v = np.where(flagged, 0.0, v)
    # Without per-pixel variances (8-bit path: NaN) only the spatial estimate can be made.
    need_var = error_model != "spatial"
    bad = used & ~(np.isfinite(x) & (np.isfinite(v) if need_var else True))
    if bad.any():
        what = "flagged ROI pixels" if on_flagged == "lower_bound" and (bad & flagged).any() else "ROI pixels"
        quantity = "radiance or variance" if need_var else "radiance"
        raise RoiError(
            f"{int(bad.any(axis=1).sum())} {what} have non-finite {quantity}; flag them and use on_flagged='exclude'"
        )
    if (used & (v < 0)).any():
        raise RoiError(f"{int((used & (v < 0)).any(axis=1).sum())} ROI pixels have negative variance")
    n_used = used.sum(axis=0)
    if not n_used.all():
        empty = [c for c in range(n_ch) if n_used[c] == 0]
        raise RoiError(f"all {n_pixels} ROI pixels are flagged in channel(s) {empty}: no reading possible")

    xs = np.where(used, x, 0.0)
    mean = xs.sum(axis=0) / n_used
    with np.errstate(invalid="ignore"):
        prop = np.sqrt(np.where(used, v, 0.0).sum(axis=0)) / n_used  # NaN without variances
    dev2 = np.where(used, (x - mean) ** 2, 0.0).sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        spatial = np.where(n_used > 1, np.sqrt(dev2 / (n_used - 1) / n_used), np.nan)
    if error_model == "propagated":
        se = prop
    elif error_model == "spatial":
        se = spatial
    else:
        se = np.fmax(prop, spatial)  # fmax: a single pixel has no spatial estimate, use the propagated one

    one = rad.ndim == 2
    return RoiReading(
        mean=_per_channel(mean, one),
        std_error=_per_channel(se, one),
        std_error_propagated=_per_channel(prop, one),
        std_error_spatial=_per_channel(spatial, one),
        n_pixels=int(n_pixels),
        n_used=_per_channel_count(n_used, one),
        n_flagged=_per_channel_count(n_flagged, one),
        lower_bound=lower_bound,
        error_model=error_model,
        n_dark=_per_channel_count(n_dark, one),
    )



def _validate_box(box: tuple[float, ...], shape: tuple[int, ...]) -> Box:
    from acquisition.roi import validate_box

    return validate_box(box, shape)


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


@pytest.mark.parametrize("kind", ["clean", "saturated", "dark", "both"])
def test_reduce_roi_equals_the_reference(kind: str) -> None:
    rng = np.random.default_rng(17)
    for shape, _ in itertools.product(SHAPES, range(25)):
        hdr = _image(rng, shape, kind)
        h, w = shape[:2]
        x0, y0 = int(rng.integers(0, w)), int(rng.integers(0, h))
        boxes: list[Box] = [(0, 0, w, h), (x0, y0, int(rng.integers(x0 + 1, w + 1)), int(rng.integers(y0 + 1, h + 1)))]
        policies, models = ("exclude", "lower_bound"), ("max", "propagated", "spatial")
        for box, policy, model in itertools.product(boxes, policies, models):
            args = (hdr.radiance, hdr.variance, box)
            kw = {"flags": hdr.saturated, "on_flagged": policy, "error_model": model, "dark": hdr.dark}
            try:
                expected = reference_reduce_roi(*args, **kw)  # type: ignore[arg-type]
            except RoiError as exc:
                with pytest.raises(RoiError, match=str(exc)[:30]):
                    reduce_roi(*args, **kw)  # type: ignore[arg-type]
                continue
            same_reading(reduce_roi(*args, **kw), expected)  # type: ignore[arg-type]
        try:
            whole = reference_reduce_roi(hdr.radiance, hdr.variance, boxes[0], flags=hdr.saturated, dark=hdr.dark)
        except RoiError:
            continue
        same_reading(reduce_hdr_roi(hdr, boxes[0]), whole)


def test_reduce_roi_without_flags_and_with_a_mask_equals_the_reference() -> None:
    rng = np.random.default_rng(4)
    for shape in SHAPES:
        hdr = _image(rng, shape, "clean")
        mask = rng.random(shape[:2]) < 0.5
        mask[0, 0] = True
        for roi in (mask, (0, 0, shape[1], shape[0])):
            expected = reference_reduce_roi(hdr.radiance, hdr.variance, roi)
            same_reading(reduce_roi(hdr.radiance, hdr.variance, roi), expected)


@pytest.mark.filterwarnings("ignore:Mean of empty slice")  # a channel without a finite pixel, both ways
@pytest.mark.parametrize("kind", ["clean", "saturated", "nan", "both"])
def test_level_of_equals_the_reference(kind: str) -> None:
    rng = np.random.default_rng(23)
    for shape, _ in itertools.product(SHAPES, range(30)):
        hdr = _image(rng, shape, kind)
        h, w = shape[:2]
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
