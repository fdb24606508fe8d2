"""A colour-filter-array mosaic read per colour: its 2x2 cells binned into R, G, B planes with their variances.

A RAW camera's HDR merge is a mosaic: each pixel saw one colour. Averaging an ROI of it into one number
mixes the colours (a gold sample's reading would be grey). Here the ROI's whole 2x2 cells are binned
without interpolation: R and B are their cell's one pixel, G the mean of the two greens, and the variance
of each plane follows (the greens' is a quarter of their sum). A cell is flagged in a colour when any of
that colour's pixels is. The CFA phase is that of the mosaic's pixel (0, 0), so a box is cut to the
cells that lie wholly inside it (a box with an odd edge loses that row or column of pixels).

Binning keeps every reading linear and its noise exactly known; demosaicing (interpolation between
cells) is for a full-resolution image a person looks at, and :func:`demosaic_hdr` does it bilinearly,
which is linear in the signal too.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from acquisition.frame import Frame
from acquisition.hdr.merge import HdrFlag, HdrImage
from acquisition.roi import Box, ErrorModel, FlaggedPolicy, RoiError, RoiReading, reduce_roi, validate_box

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

_COLOURS = "RGB"


def _check_pattern(cfa_pattern: str | None) -> str:
    if cfa_pattern is None or len(cfa_pattern) != 4 or sorted(cfa_pattern) != ["B", "G", "G", "R"]:
        raise RoiError(f"cfa_pattern = {cfa_pattern!r}: expected a Bayer layout of one R, two G and one B, e.g. 'RGGB'")
    return cfa_pattern


def shift_pattern(cfa_pattern: str, dx: int, dy: int) -> str:
    """The 2x2 pattern seen from pixel (dx, dy) of a mosaic whose pixel (0, 0) has ``cfa_pattern``."""
    p = _check_pattern(cfa_pattern)
    return "".join(p[((dy + i) % 2) * 2 + (dx + j) % 2] for i in range(2) for j in range(2))


def cell_box(box: Box, shape: tuple[int, ...]) -> Box:
    """The 2x2 cells ``(cx0, cy0, cx1, cy1)`` lying wholly inside a pixel box of a mosaic of ``shape``."""
    x0, y0, x1, y1 = validate_box(box, shape)
    cells = (-(-x0 // 2), -(-y0 // 2), x1 // 2, y1 // 2)
    if cells[2] <= cells[0] or cells[3] <= cells[1]:
        raise RoiError(f"ROI box {box!r} holds no whole 2x2 CFA cell (a colour reading needs at least 2x2 pixels)")
    return cells


def bin_planes(image: npt.ArrayLike, cfa_pattern: str | None, *, mean_greens: bool = True) -> FloatArray:
    """(H/2, W/2, 3) R, G, B planes of an (H, W) mosaic: one value per 2x2 cell (G: the greens' mean or sum).

    ``mean_greens=False`` sums the two greens instead, which is how a variance (or a count of flagged
    pixels) bins: the variance of the greens' mean is a quarter of that sum. Odd trailing rows or columns
    are dropped.
    """
    p = _check_pattern(cfa_pattern)
    a = np.asarray(image, dtype=np.float64)
    if a.ndim != 2:
        raise RoiError(f"a CFA mosaic is (H, W), got shape {a.shape}")
    h, w = (a.shape[0] // 2) * 2, (a.shape[1] // 2) * 2
    if h == 0 or w == 0:
        raise RoiError(f"a mosaic of shape {a.shape} has no whole 2x2 cell")
    sites = [a[i // 2 : h : 2, i % 2 : w : 2] for i in range(4)]
    out = np.empty((h // 2, w // 2, 3), dtype=np.float64)
    greens = [sites[i] for i in range(4) if p[i] == "G"]
    out[..., 0] = sites[p.index("R")]
    out[..., 1] = greens[0] + greens[1]
    if mean_greens:
        out[..., 1] *= 0.5
    out[..., 2] = sites[p.index("B")]
    return out


def bin_hdr(
    radiance: npt.ArrayLike, variance: npt.ArrayLike, flags: npt.ArrayLike | None, cfa_pattern: str | None
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """Binned radiance, variance (same units squared) and flags of an HDR mosaic, each (H/2, W/2, 3)."""
    rad = bin_planes(radiance, cfa_pattern)
    with np.errstate(invalid="ignore"):
        var = bin_planes(variance, cfa_pattern, mean_greens=False)
    var[..., 1] *= 0.25
    if flags is None:
        fl = np.zeros(rad.shape, dtype=bool)
    else:
        fl = bin_planes(np.asarray(flags) != 0, cfa_pattern, mean_greens=False) > 0
    return rad, var, fl


def reduce_mosaic_roi(
    radiance: npt.ArrayLike,
    variance: npt.ArrayLike,
    roi: Box,
    cfa_pattern: str | None,
    flags: npt.ArrayLike | None = None,
    *,
    on_flagged: FlaggedPolicy = "exclude",
    error_model: ErrorModel = "max",
    dark: npt.ArrayLike | None = None,
) -> RoiReading:
    """Per-colour (R, G, B) mean of an HDR mosaic's ROI over its whole 2x2 cells, with standard errors.

    Same units as ``radiance`` (counts/s for the linear merge); ``roi`` is a pixel box of the mosaic;
    ``n_pixels`` of the reading counts cells. See :func:`acquisition.roi.reduce_roi` for the policies; a
    cell's colour counts as dark where any of its pixels of that colour is (``dark``, the HDR's mask).
    """
    rad = np.asarray(radiance)
    cx0, cy0, cx1, cy1 = cell_box(roi, rad.shape)
    sub = (slice(2 * cy0, 2 * cy1), slice(2 * cx0, 2 * cx1))
    fl = None if flags is None else np.asarray(flags)[sub]
    r, v, f = bin_hdr(rad[sub], np.asarray(variance)[sub], fl, cfa_pattern)
    dk = None if dark is None else bin_planes(np.asarray(dark)[sub] != 0, cfa_pattern, mean_greens=False) > 0
    return reduce_roi(r, v, (0, 0, cx1 - cx0, cy1 - cy0), flags=f, on_flagged=on_flagged, error_model=error_model,
                      dark=dk)  # fmt: skip


def counts_above_black(frame: Frame, roi: Box | None = None) -> FloatArray:
    """A frame's pixels (of ``roi``, a pixel box) in counts above black; a raw mosaic's as (h, w, 3) colour cells.

    What metering reads: one value per colour and cell for a mosaic, so the plan is made per colour.
    """
    data = np.asarray(frame.data, dtype=np.float64)
    black = np.asarray(frame.black_level, dtype=np.float64)
    if frame.kind == "raw" and frame.cfa_pattern is not None:
        h, w = data.shape
        x0, y0, x1, y1 = roi if roi is not None else (0, 0, w, h)
        cx0, cy0, cx1, cy1 = cell_box((x0, y0, x1, y1), data.shape)
        # One black level, or one per CFA position; the cut starts on a cell, so the positions line up.
        tile = (black.reshape(-1) if black.size == 4 else np.repeat(black.reshape(-1)[:1], 4)).reshape(2, 2)
        sub = data[2 * cy0 : 2 * cy1, 2 * cx0 : 2 * cx1] - np.tile(tile, (cy1 - cy0, cx1 - cx0))
        return bin_planes(sub, frame.cfa_pattern)
    if black.ndim == 1 and data.ndim == 3 and black.size == data.shape[-1]:
        above = data - black
    else:
        above = data - float(np.max(black))
    if roi is None:
        return above
    x0, y0, x1, y1 = validate_box(roi, above.shape)
    return above[y0:y1, x0:x1]


#: ``HdrImage.saturated`` and ``HdrImage.dark`` are these bits of ``flags``; as plain ints the masks cost less
#: (an IntFlag operand sends numpy through the enum's attribute lookups). The ROI only asks which are non-zero.
_SATURATED_BITS = int(HdrFlag.SATURATED)
_DARK_BITS = int(HdrFlag.DARK | HdrFlag.BELOW_BLACK)


def reduce_hdr_roi(hdr: HdrImage, roi: Box, *, on_flagged: FlaggedPolicy = "exclude") -> RoiReading:
    """An HDR image's ROI reading: per colour over whole 2x2 cells for a raw mosaic, per channel otherwise.

    Saturated pixels are flagged and dark ones counted (see :func:`acquisition.roi.reduce_roi`); units are
    the merge's (counts/s).
    """
    pattern = hdr.metadata.get("cfa_pattern")
    saturated, dark = (hdr.flags & _SATURATED_BITS) != 0, (hdr.flags & _DARK_BITS) != 0
    if hdr.metadata.get("kind") == "raw" and isinstance(pattern, str):
        return reduce_mosaic_roi(hdr.radiance, hdr.variance, roi, pattern, flags=saturated, on_flagged=on_flagged,
                                 dark=dark)  # fmt: skip
    return reduce_roi(hdr.radiance, hdr.variance, roi, flags=saturated, on_flagged=on_flagged, dark=dark)


def colour_planes(hdr: HdrImage, roi: Box) -> FloatArray:
    """The ROI's radiance as (h, w, C): a raw mosaic's binned into R, G, B cells, anything else as it is."""
    pattern = hdr.metadata.get("cfa_pattern")
    if hdr.metadata.get("kind") == "raw" and isinstance(pattern, str):
        cx0, cy0, cx1, cy1 = cell_box(roi, hdr.radiance.shape)
        return bin_planes(hdr.radiance[2 * cy0 : 2 * cy1, 2 * cx0 : 2 * cx1], pattern)
    x0, y0, x1, y1 = validate_box(roi, hdr.radiance.shape)
    return np.asarray(hdr.radiance[y0:y1, x0:x1], dtype=np.float64)


def demosaic_hdr(
    radiance: npt.ArrayLike, variance: npt.ArrayLike, cfa_pattern: str | None
) -> tuple[FloatArray, FloatArray]:
    """Full-resolution (H, W, 3) radiance and variance of an HDR mosaic by bilinear interpolation per colour.

    Each colour at each pixel is the mean of that colour's samples in the pixel's 3x3 neighbourhood
    (the pixel itself where it has the colour); its variance is the propagated one of that mean, treating
    the samples as independent. Non-finite samples (saturated pixels) are left out of their neighbours.
    """
    p = _check_pattern(cfa_pattern)
    rad = np.asarray(radiance, dtype=np.float64)
    var = np.asarray(variance, dtype=np.float64)
    if rad.ndim != 2 or var.shape != rad.shape:
        raise RoiError(f"demosaic_hdr needs (H, W) radiance and variance of one shape, got {rad.shape}, {var.shape}")
    h, w = rad.shape
    yy, xx = np.mgrid[0:h, 0:w]
    site = (yy % 2) * 2 + (xx % 2)
    colour_of = np.array([_COLOURS.index(c) for c in p])[site]
    out = np.full((h, w, 3), np.nan)
    out_var = np.full((h, w, 3), np.nan)
    for c in range(3):
        has = (colour_of == c) & np.isfinite(rad) & np.isfinite(var)
        own = colour_of == c
        total = np.zeros((h, w))
        total_var = np.zeros((h, w))
        count = np.zeros((h, w))
        x = np.where(has, rad, 0.0)
        v = np.where(has, var, 0.0)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                total += _shifted(x, dy, dx)
                total_var += _shifted(v, dy, dx)
                count += _shifted(has.astype(np.float64), dy, dx)
        with np.errstate(invalid="ignore", divide="ignore"):
            interp = total / count
            interp_var = total_var / count**2
        # Where the pixel has the colour it keeps its own value: interpolation only fills the gaps.
        out[..., c] = np.where(own, np.where(has, rad, np.nan), interp)
        out_var[..., c] = np.where(own, np.where(has, var, np.nan), interp_var)
    return out, out_var


def _shifted(a: FloatArray, dy: int, dx: int) -> FloatArray:
    """``a`` moved by (dy, dx) with zeros shifted in: out[y, x] = a[y + dy, x + dx]."""
    out = np.zeros_like(a)
    h, w = a.shape
    ys, yd = (slice(dy, h), slice(0, h - dy)) if dy >= 0 else (slice(0, h + dy), slice(-dy, h))
    xs, xd = (slice(dx, w), slice(0, w - dx)) if dx >= 0 else (slice(0, w + dx), slice(-dx, w))
    out[yd, xd] = a[ys, xs]
    return out
