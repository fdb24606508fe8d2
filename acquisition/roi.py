"""Region of interest: which pixels of an HDR image make one reading, and their mean with its standard error.

A reading is the mean radiance of the ROI per channel (counts/s above black, the unit of the HDR merge)
with two standard errors:

- ``propagated``: from the merge's per-pixel variances, ``sqrt(sum var_i) / N``. It is the noise of the
  mean (what a repeat of the capture would scatter by) if the per-pixel variances are right and pixel
  noise is independent.
- ``spatial``: from the scatter of the pixel values, ``std(x, ddof=1) / sqrt(N)``. It contains the
  noise and, in addition, any real texture of the sample (and fixed-pattern noise the variances miss).

``RoiReading.std_error`` is the larger of the two per channel by default (conservative: a model error in
the variances, or non-uniform illumination, cannot make the reading look more precise than its scatter
allows). On a textured ROI the spatial term overstates the noise of the mean, since the texture is the
same in every repeat; pass ``error_model="propagated"`` when the ROI is known to be textured and the noise
model is trusted, or ``"spatial"`` for data without per-pixel variances. ``scatter_ratio`` (spatial over
propagated) tells which case a reading is in: about 1 for a uniform ROI, well above 1 for texture.

Flagged pixels (``flags`` non-zero: e.g. saturated in every frame of the bracket) are never averaged in
silently: ``on_flagged="exclude"`` (default) leaves them out and counts them in ``n_flagged``;
``"lower_bound"`` keeps their (clipped) values, without a noise term, and marks the reading
``lower_bound=True``; ``"raise"`` refuses the reading. With an ``HdrImage`` pass ``flags=img.saturated``
(not the whole bit field: excluding the pixels flagged DARK would bias a dim ROI's mean upwards), and
``dark=img.dark``: dark pixels stay in the mean but are counted (``n_dark``), and a reading whose ROI is
mostly dark, or whose mean is not detected above its error, says so (``RoiReading.dark``).
Unflagged pixels with non-finite radiance or variance are an error, except that ``error_model="spatial"``
accepts unknown (NaN) variances, as the 8-bit merge path reports.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from model.errors import GonioError

Box = tuple[int, int, int, int]
"""A pixel box ``(x0, y0, x1, y1)``: columns x0..x1-1 and rows y0..y1-1 (half-open, like slices)."""

FlaggedPolicy = Literal["exclude", "lower_bound", "raise"]
#: A reading whose mean is not above this many standard errors is not a detection (``RoiReading.dark``).
DARK_SIGMA = 3.0
ErrorModel = Literal["max", "propagated", "spatial"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


class RoiError(GonioError, ValueError):
    """An ROI does not fit its image, selects no usable pixel, or meets data it cannot reduce honestly."""


@dataclass(frozen=True, eq=False)
class RoiReading:
    """Mean radiance of an ROI per channel with its standard error (all in counts/s above black).

    Arrays have shape () for a single-channel (H, W) image and (C,) for an (H, W, C) image.

    Parameters
    ----------
    mean:
        Mean radiance over the used pixels, counts/s.
    std_error:
        The standard error the reading reports, per ``error_model``, counts/s.
    std_error_propagated:
        ``sqrt(sum var_i) / N`` from the per-pixel variances, counts/s.
    std_error_spatial:
        ``std(x, ddof=1) / sqrt(N)`` from the pixel scatter (NaN when only one pixel is used), counts/s.
    n_pixels:
        Pixels inside the ROI.
    n_used:
        Pixels that entered the mean, per channel.
    n_flagged:
        Flagged pixels inside the ROI, per channel.
    lower_bound:
        True when flagged (saturated) pixels were kept with their clipped values: the true mean is higher.
    error_model:
        Which estimate ``std_error`` is: ``"max"``, ``"propagated"`` or ``"spatial"``.
    n_dark:
        Pixels inside the ROI marked dark (``dark=``, e.g. an HdrImage's ``dark``), per channel; they are in
        the mean (leaving them out would bias a dim ROI upwards).
    """

    mean: FloatArray
    std_error: FloatArray
    std_error_propagated: FloatArray
    std_error_spatial: FloatArray
    n_pixels: int
    n_used: IntArray
    n_flagged: IntArray
    lower_bound: bool
    error_model: ErrorModel
    n_dark: IntArray = field(default_factory=lambda: np.zeros((), dtype=np.int64))

    @property
    def dark(self) -> bool:
        """Whether a channel is dark: most of its pixels flagged dark, or its mean within 3 errors of zero."""
        # In Python numbers (a reading has 1-3 channels, where numpy's per-call cost is most of the work):
        # the same comparisons, NaN included (not above: undetected).
        n_dark, used = channel_list(self.n_dark), channel_list(self.n_used)
        mean, se = channel_list(self.mean), channel_list(self.std_error)
        if len(n_dark) != len(used) or len(mean) != len(se):  # a reading built by hand, with broadcasting
            nd, nu = np.broadcast_arrays(np.atleast_1d(self.n_dark), np.atleast_1d(self.n_used))
            m, e = np.broadcast_arrays(np.atleast_1d(self.mean), np.atleast_1d(self.std_error))
            with np.errstate(invalid="ignore"):
                return bool(np.any(2 * nd > nu) or np.any(~(m > DARK_SIGMA * e)))
        return any(2 * d > u for d, u in zip(n_dark, used, strict=True)) or any(
            not m > DARK_SIGMA * e for m, e in zip(mean, se, strict=True)
        )

    @property
    def scatter_ratio(self) -> FloatArray:
        """Spatial over propagated standard error: ~1 for a uniform ROI, > 1 with texture or unmodelled noise."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.asarray(self.std_error_spatial / self.std_error_propagated, dtype=np.float64)

    @property
    def relative_error(self) -> FloatArray:
        """Standard error over mean (dimensionless); inf where the mean is 0."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.asarray(self.std_error / np.abs(self.mean), dtype=np.float64)


def channel_list(a: npt.ArrayLike) -> list[Any]:
    """``np.atleast_1d(a).tolist()``: per-channel numbers as a list."""
    return list(np.atleast_1d(a).tolist())


def _image_hw(shape: tuple[int, ...]) -> tuple[int, int]:
    if len(shape) not in (2, 3):
        raise RoiError(f"image has shape {shape}: expected (H, W) or (H, W, C)")
    return shape[0], shape[1]


def validate_box(box: Box | tuple[float, ...], shape: tuple[int, ...]) -> Box:
    """Check a pixel box ``(x0, y0, x1, y1)`` against an image shape (H, W[, C]); return it as ints."""
    h, w = _image_hw(tuple(shape))
    if len(box) != 4:
        raise RoiError(f"ROI box {box!r}: expected 4 numbers (x0, y0, x1, y1)")
    if any(not float(v).is_integer() for v in box):
        raise RoiError(f"ROI box {box!r}: pixel coordinates must be whole numbers")
    x0, y0, x1, y1 = (int(v) for v in box)
    if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
        raise RoiError(
            f"ROI box (x0, y0, x1, y1) = {(x0, y0, x1, y1)} does not fit an image of shape {tuple(shape)}: "
            f"need 0 <= x0 < x1 <= {w} (width) and 0 <= y0 < y1 <= {h} (height)"
        )
    return x0, y0, x1, y1


def box_mask(box: Box, shape: tuple[int, ...]) -> BoolArray:
    """Boolean (H, W) mask of a pixel box ``(x0, y0, x1, y1)`` in an image of shape (H, W[, C])."""
    x0, y0, x1, y1 = validate_box(box, shape)
    mask = np.zeros(_image_hw(tuple(shape)), dtype=bool)
    mask[y0:y1, x0:x1] = True
    return mask


def circle_mask(shape: tuple[int, ...], center_xy: tuple[float, float], radius_px: float) -> BoolArray:
    """Boolean (H, W) mask of the pixels whose centres lie within ``radius_px`` pixels of ``center_xy``.

    Pixel (x, y) has its centre at (x, y) (integer coordinates), the convention of the box.
    """
    h, w = _image_hw(tuple(shape))
    if not (np.isfinite(radius_px) and radius_px > 0):
        raise RoiError(f"circle radius_px = {radius_px!r}: expected a positive number of pixels")
    cx, cy = center_xy
    yy, xx = np.ogrid[:h, :w]
    mask = (xx - cx) ** 2 + (yy - cy) ** 2 <= radius_px**2
    if not mask.any():
        raise RoiError(
            f"circle at {center_xy!r} with radius {radius_px!r} px contains no pixel of an image of shape {shape}"
        )
    return np.asarray(mask, dtype=bool)


def _select(image: npt.NDArray[np.generic], roi: Box | BoolArray, name: str, checked: bool = False) -> FloatArray:
    """ROI pixels of an (H, W[, C]) image as a float array (N, C); ``checked``: a box validated for its shape."""
    if isinstance(roi, np.ndarray):
        if roi.dtype != np.bool_:
            raise RoiError(f"ROI mask has dtype {roi.dtype}: expected bool (use box_mask/circle_mask to build one)")
        if roi.shape != image.shape[:2]:
            raise RoiError(f"ROI mask has shape {roi.shape} but {name} has shape {image.shape}: expected (H, W) equal")
        if not roi.any():
            raise RoiError("ROI mask selects no pixel")
        pixels = image[roi]
    else:
        x0, y0, x1, y1 = roi if checked else validate_box(tuple(roi), image.shape)
        pixels = image[y0:y1, x0:x1].reshape((y1 - y0) * (x1 - x0), *image.shape[2:])
    return np.asarray(pixels, dtype=np.float64).reshape(pixels.shape[0], -1)


def _flags(flags: npt.NDArray[np.generic], roi: Box | BoolArray, checked: bool, name: str = "flags") -> BoolArray:
    """Which ROI pixels of a flag array are set, as (N, C) booleans (``_select(flags != 0) != 0``, cut first)."""
    if isinstance(roi, np.ndarray) or not checked:
        return _select(flags != 0, roi, name, checked) != 0
    x0, y0, x1, y1 = roi
    cut = flags[y0:y1, x0:x1] != 0
    return cut.reshape(cut.shape[0] * cut.shape[1], -1)


def reduce_roi(
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
    _check_options(rad, var, on_flagged, error_model)
    if not isinstance(roi, np.ndarray):
        roi = validate_box(tuple(roi), rad.shape)  # once: the four selections below take it as checked
    box = not isinstance(roi, np.ndarray)
    x = _select(rad, roi, "radiance", box)
    v = _select(var, roi, "variance", box)
    n_pixels = x.shape[0]
    flagged = _flagged(flags, rad.shape, roi, box, x.shape)
    n_flagged = flagged.sum(axis=0)
    n_dark = _dark_counts(dark, rad.shape, roi, box, x.shape)
    if on_flagged == "raise" and n_flagged.any():
        raise RoiError(f"{int(n_flagged.max())} of {n_pixels} ROI pixels are flagged (on_flagged='raise')")
    if not n_flagged.any() and np.isfinite(x).all() and np.isfinite(v).all() and not (v < 0).any():
        # Every pixel is used (the usual reading): the same sums on the same arrays as below, without
        # the masks that would select them all (on a 16-pixel ROI, most of the reduction's cost).
        return _all_used(x, v, n_pixels - n_flagged, n_flagged, n_dark, rad.ndim == 2, error_model)
    return _some_used(x, v, flagged, n_flagged, n_dark, rad.ndim == 2, on_flagged, error_model)


def _check_options(rad: npt.NDArray[Any], var: npt.NDArray[Any], on_flagged: str, error_model: str) -> None:
    """Raise RoiError for an image that is not (H, W[, C]), a variance of another shape, or an unknown option."""
    _image_hw(rad.shape)
    if var.shape != rad.shape:
        raise RoiError(f"variance has shape {var.shape} but radiance has shape {rad.shape}: expected equal shapes")
    if on_flagged not in ("exclude", "lower_bound", "raise"):
        raise RoiError(f"on_flagged = {on_flagged!r}: expected 'exclude', 'lower_bound' or 'raise'")
    if error_model not in ("max", "propagated", "spatial"):
        raise RoiError(f"error_model = {error_model!r}: expected 'max', 'propagated' or 'spatial'")


def _flagged(
    flags: npt.ArrayLike | None, shape: tuple[int, ...], roi: Box | BoolArray, box: bool, x_shape: tuple[int, ...]
) -> BoolArray:
    """Which ROI pixels (N, C) are flagged (none without ``flags``); ``flags`` is (H, W) or the image's shape."""
    if flags is None:
        return np.zeros(x_shape, dtype=bool)
    fl = np.asarray(flags)
    if fl.shape not in (shape[:2], shape):
        raise RoiError(f"flags have shape {fl.shape} but radiance has shape {shape}: expected (H, W) or the same shape")
    sel = _flags(fl, roi, box)
    return np.broadcast_to(sel, x_shape) if sel.shape[1] == 1 else sel


def _dark_counts(
    dark: npt.ArrayLike | None, shape: tuple[int, ...], roi: Box | BoolArray, box: bool, x_shape: tuple[int, ...]
) -> IntArray:
    """How many ROI pixels are dark, per channel (none without ``dark``, an (H, W) or image-shaped mask)."""
    if dark is None:
        return np.zeros(x_shape[1], dtype=np.int64)
    dk = np.asarray(dark)
    if dk.shape not in (shape[:2], shape):
        raise RoiError(f"dark has shape {dk.shape} but radiance has shape {shape}: expected (H, W) or the same")
    sel = _flags(dk, roi, box, "dark")
    n_dark: IntArray = np.broadcast_to(sel, x_shape).sum(axis=0) if sel.shape[1] == 1 else sel.sum(axis=0)
    return n_dark


def _some_used(
    x: FloatArray, v: FloatArray, flagged: BoolArray, n_flagged: IntArray, n_dark: IntArray, one: bool,
    on_flagged: FlaggedPolicy, error_model: ErrorModel,
) -> RoiReading:
    """``reduce_roi``'s reading where some pixel is flagged, not finite or of negative variance."""
    n_pixels, n_ch = x.shape
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


def _all_used(
    x: FloatArray, v: FloatArray, n_used: IntArray, n_flagged: IntArray, n_dark: IntArray, one: bool,
    error_model: ErrorModel,
) -> RoiReading:
    """``reduce_roi``'s reading where no pixel is flagged and all are finite with variances >= 0."""
    mean = x.sum(axis=0) / n_used
    prop = np.sqrt(v.sum(axis=0)) / n_used
    dev2 = ((x - mean) ** 2).sum(axis=0)
    if x.shape[0] > 1:  # every channel uses every pixel: nothing divides by zero, no warning to silence
        spatial = np.where(n_used > 1, np.sqrt(dev2 / (n_used - 1) / n_used), np.nan)
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            spatial = np.where(n_used > 1, np.sqrt(dev2 / (n_used - 1) / n_used), np.nan)
    se = prop if error_model == "propagated" else spatial if error_model == "spatial" else np.fmax(prop, spatial)
    return RoiReading(
        mean=_per_channel(mean, one),
        std_error=_per_channel(se, one),
        std_error_propagated=_per_channel(prop, one),
        std_error_spatial=_per_channel(spatial, one),
        n_pixels=int(x.shape[0]),
        n_used=_per_channel_count(n_used, one),
        n_flagged=_per_channel_count(n_flagged, one),
        lower_bound=False,
        error_model=error_model,
        n_dark=_per_channel_count(n_dark, one),
    )


def _per_channel(a: npt.ArrayLike, single: bool) -> FloatArray:
    out = np.asarray(a, dtype=np.float64)
    return out.reshape(()) if single else out


def _per_channel_count(a: npt.ArrayLike, single: bool) -> IntArray:
    out = np.asarray(a, dtype=np.int64)
    return out.reshape(()) if single else out
