"""What one calibration capture shows: the board's corners and the lamp's mirror highlight, in pixels.

The input is an HDR frame (radiance and variance per pixel, counts/s). The board's corners come from
OpenCV's ChArUco detector on a tone-mapped 8-bit copy (sub-pixel refined; about 0.05-0.1 px on a clean
image). The highlight is the mirror image of the lamp in the board's coat: the brightest spot, many times
the printed pattern's level (the board's median, the surroundings left out). Its position is the peak of a
quadratic fitted to the logarithm of the spot's light above the local background over its half-maximum
region (a GGX lobe is close to Gaussian near its peak), weighted by the pixels' own variance; its standard
error is that fit's. A highlight that touches the frame's edge, is too faint against the pattern, or spans
too few pixels is not used (and the reason is kept).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from acquisition.board import ChArUcoBoard

FloatArray = npt.NDArray[np.float64]

#: The highlight must be this many times brighter than the board's typical (median) level. A board pose's
#: brightest pixel (the white print, domed by the beam's falloff) is 1.1-1.2x it, the lamp's highlight 100x in a
#: GGX alpha 0.01 coat and 7x in an alpha 0.03 one (rendered on examples/rig_misaligned.toml).
MIN_CONTRAST = 4.0
#: Pixels below this fraction of the print's bright level (the 90th percentile) are not the board: the lamp
#: lights even the black print at ~4 % of the white, while the surroundings see only stray light.
BOARD_FLOOR = 0.01
#: Corners closer to the highlight than this many half-maximum radii are not used (see observe).
GLARE_RADII = 6.0


@dataclass(frozen=True)
class Highlight:
    """The mirror highlight's peak in continuous pixels, its standard error (px), its peak level (counts/s)
    and the radius (px) of its half-maximum region."""

    x: float
    y: float
    std_error_px: float
    peak: float
    radius_px: float = 0.0


@dataclass(frozen=True)
class FrameObservation:
    """One frame's board corners (ids, continuous pixels) and highlight (or why there is none)."""

    corner_ids: npt.NDArray[np.int64]
    corners_px: FloatArray
    highlight: Highlight | None
    note: str = ""


def tone_map(luminance: FloatArray) -> npt.NDArray[np.uint8]:
    """An 8-bit copy for the board detector: the pattern's bright print near 200, the highlight clipped."""
    lit = luminance[luminance > 0]
    if lit.size == 0:
        return np.zeros(luminance.shape, dtype=np.uint8)
    scale = 200.0 / max(float(np.percentile(lit, 90)), 1e-30)
    return np.clip(luminance * scale, 0, 255).astype(np.uint8)


def find_highlight(luminance: FloatArray, variance: FloatArray) -> tuple[Highlight | None, str]:
    """The highlight's sub-pixel peak in an image (H, W) of counts/s with its variance, or None and why."""
    lit = luminance[np.isfinite(luminance) & (luminance > 0)]
    if lit.size == 0:
        return None, "the frame is black"
    background = float(np.median(lit))
    # The contrast is against the board alone: surroundings lit by stray light made the median of the whole frame
    # thousands of times below the print, so a board pose's white print passed as a highlight (and its "glare"
    # then took every corner).
    board = lit[lit > BOARD_FLOOR * float(np.percentile(lit, 90))]
    level = float(np.median(board)) if board.size else background
    finite = np.where(np.isfinite(luminance), luminance, 0.0)
    iy, ix = (int(i) for i in np.unravel_index(int(np.argmax(finite)), finite.shape))
    peak = float(finite[iy, ix])
    if peak < MIN_CONTRAST * level:
        return None, f"no highlight: the brightest pixel is {peak / level:.1f}x the board, below {MIN_CONTRAST:g}x"
    return peak_of(finite - background, variance, iy, ix, peak)


def peak_of(
    above: FloatArray, variance: FloatArray, iy: int, ix: int, peak: float
) -> tuple[Highlight | None, str]:
    """The sub-pixel peak of a spot (light above its background) around its brightest pixel (iy, ix)."""
    region = _connected(above >= 0.5 * float(above[iy, ix]), iy, ix)
    ys, xs = np.nonzero(region)
    h, w = above.shape
    if ys.min() == 0 or xs.min() == 0 or ys.max() == h - 1 or xs.max() == w - 1:
        return None, "the highlight touches the frame's edge (it lies outside the view)"
    if len(ys) < 6:
        # Too small to fit a peak to: grow to the 3 x 3 around the brightest pixel.
        ys, xs = (g.reshape(-1) for g in np.mgrid[iy - 1 : iy + 2, ix - 1 : ix + 2])
    v = np.maximum(above[ys, xs], 1e-30)
    var = np.where(np.isfinite(variance[ys, xs]), variance[ys, xs], np.inf)
    # log I = c0 + c1 x + c2 y + c3 x^2 + c4 xy + c5 y^2; var(log I) = var(I) / I^2.
    x, y = xs + 0.5 - (ix + 0.5), ys + 0.5 - (iy + 0.5)
    a = np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=-1).astype(np.float64)
    wts = v * v / np.maximum(var, 1e-30)
    sw = np.sqrt(wts)
    coef, *_ = np.linalg.lstsq(a * sw[:, None], np.log(v) * sw, rcond=None)
    hess = np.array([[2 * coef[3], coef[4]], [coef[4], 2 * coef[5]]])
    if not np.all(np.linalg.eigvalsh(hess) < 0):
        return None, "the highlight has no single peak (saturated or flat)"
    offset = -np.linalg.solve(hess, coef[1:3])
    if np.max(np.abs(offset)) > 3 + np.sqrt(len(xs)):
        return None, "the highlight's peak fit left the spot"
    cov = np.linalg.pinv((a * wts[:, None]).T @ a)
    # d offset / d coef by implicit differentiation of hess @ offset + grad = 0.
    jac = np.zeros((2, 6))
    jac[:, 1:3] = -np.linalg.inv(hess)
    jac[:, 3] = -np.linalg.solve(hess, np.array([2 * offset[0], 0.0]))
    jac[:, 4] = -np.linalg.solve(hess, np.array([offset[1], offset[0]]))
    jac[:, 5] = -np.linalg.solve(hess, np.array([0.0, 2 * offset[1]]))
    se = float(np.sqrt(max(np.trace(jac @ cov @ jac.T) / 2.0, 0.0)))
    radius = float(np.sqrt(len(xs) / np.pi))
    return Highlight(float(ix + 0.5 + offset[0]), float(iy + 0.5 + offset[1]), se, peak, radius), ""


def _connected(mask: npt.NDArray[np.bool_], y: int, x: int) -> npt.NDArray[np.bool_]:
    """The 4-connected component of ``mask`` that holds (y, x)."""
    import cv2

    _, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=4)
    out: npt.NDArray[np.bool_] = labels == labels[y, x]
    return out


def observe(
    radiance: FloatArray, variance: FloatArray, board: ChArUcoBoard, *, corners: bool = True
) -> FrameObservation:
    """Corners and highlight of an HDR frame (H, W) or (H, W, C) in counts/s with its variance.

    ``corners=False`` finds the highlight only: at a mirror pose the coat reflects the lamp over the whole
    board (a GGX lobe's tails fall as the fourth power of the angle, and its peak is hundreds of times the
    print), and a corner's saddle on that gradient is found off its place.
    """
    lum = np.asarray(radiance, dtype=np.float64)
    var = np.asarray(variance, dtype=np.float64)
    if lum.ndim == 3:
        c = lum.shape[2]
        lum, var = lum.mean(axis=2), var.sum(axis=2) / (c * c)
    if corners:
        ids, px = board.detect(tone_map(np.where(np.isfinite(lum), lum, 0.0)))
    else:
        ids, px = np.zeros(0, dtype=np.int64), np.zeros((0, 2))
    highlight, why = find_highlight(lum, var)
    if highlight is not None and len(ids):
        # The coat's reflection adds a steep gradient around the highlight, and a corner's saddle on a
        # gradient is found off its place: such corners pulled the camera's angle by a hundredth of a degree.
        far = np.hypot(px[:, 0] - highlight.x, px[:, 1] - highlight.y) > GLARE_RADII * max(highlight.radius_px, 1.0)
        if not far.all():
            why = f"{int((~far).sum())} corners in the highlight's glare left out"
        ids, px = ids[far], px[far]
    return FrameObservation(ids, px, highlight, why)
