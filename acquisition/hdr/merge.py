"""Linear HDR merge of a bracket of RAW or linear frames, with per-pixel variance and flags.

Estimator. A pixel read in frame ``k`` (exposure ``t_k`` seconds, gain ``g_k``) reports ``s_k`` counts;
``y_k = s_k - dark_k`` has mean ``X * e_k`` with ``e_k = t_k * g_k`` and ``X`` the radiance in counts per
second at gain 1. Over the frames where the pixel is not saturated the merge returns

    X = sum(y_k) / sum(e_k)                        ("sum", noise-optimal for photon noise),

which is the maximum-likelihood estimate when shot noise dominates (for Poisson counts the total count
over the total exposure is sufficient). When read noise matters it is not: a short frame adds a full
read-noise variance for a sliver of signal. The inverse-variance merge

    X = sum(w_k y_k) / sum(w_k e_k),   w_k = e_k / var_k(Xn)       ("inverse_variance")

uses the noise model ``SensorNoise.variance_dn2`` at ``Xn``, the first-pass (sum) estimate averaged over the
pixel's neighbours of the same colour (the 8 at distance 1, or 2 in a raw mosaic), *without the pixel itself*.
Weights computed from the pixel's own first pass follow its own noise (a frame that read high raises X0,
which shifts weight between frames) and bias the weighted mean: a uniform 2 counts/s patch read about 1 %
high. Weights independent of the pixel's own frames leave the estimator unbiased for any weights; the
neighbours' level is close to the pixel's on anything but a sharp edge, where the weights are merely less
than optimal. Its variance, ``sum(w_k^2 var_k(X0)) / sum(w_k e_k)^2``, reaches the Cramer-Rao bound of the
bracket (``1 / sum(e_k^2 / var_k)``) where Xn = X. The sum merge's variance is ``sum(var_k) / sum(e_k)^2``.
Both are reported per pixel in (counts/s)^2.

Choosing the weighting (``weighting="auto"``): on a strided sample of about 65 000 pixels both variances
are predicted from X0; the second pass runs when it would lower the standard error by more than
``IV_GAIN`` (1 %) for at least ``IV_FRACTION`` (1 %) of the sampled unflagged pixels. With 2-stop
brackets that happens when read noise is comparable to the shot noise of the frames a pixel uses, e.g.
high read noise or a scene whose dim end sits near the noise floor; otherwise the sum merge is within
1 % of the bound and the second pass would only cost time. ``"sum"`` or ``"inverse_variance"`` force it.

Saturation. Sensors can clip at full well below the ADC's white level, so the clip level is measured from
the data (:func:`measure_saturation`: the plateau at the top of the brightest frames) unless
``saturation_dn`` is given; with no plateau in the data (nothing clipped), the noise model's
``SensorNoise.saturation_dn`` is used. A pixel is treated as saturated in a frame when its value is at or
above the clip level minus ``saturation_sigma`` standard deviations of the noise at that level, so that a
pixel whose noise distribution is cut by the clip never enters the estimate. What remains is the bias of
any per-frame threshold: a pixel whose mean sits right at a frame's threshold enters with that frame only
when its noise is negative. Measured on the default sensor: an ROI exactly at a threshold reads 0.12 % low;
1 % above or below it, under 0.01 %.

Flags (:class:`HdrFlag`). ``SATURATED``: saturated in every frame; the radiance is a lower bound (the
shortest frame's value over its exposure) and the variance is +inf. ``DARK``: the longest frame's signal is
below ``dark_sigma`` standard deviations of its noise at zero signal; the radiance is still the unbiased
estimate (it may be negative), and its variance the model's. ``BELOW_BLACK`` (with DARK): the estimate is more
than ``BELOW_BLACK_SIGMA`` standard errors below zero, which no light gives: the frames sit below their black
level or darks (a wrong black level in the metadata, a dark taken at another temperature). ``frames_used``
counts the frames that entered each pixel's estimate.

Darks. ``darks`` maps exposure times (s) to a dark Frame, a sequence of dark Frames (averaged; variance
divided by their number), a master-dark array or a mean dark level (counts, noise neglected). A dark
frame's own noise is added to the variance. Without darks the black level of each frame's metadata is
subtracted and dark current is left in: dim pixels read high by ``dark_current * t / e_per_dn`` counts;
the result's metadata says so.

Speed. One compiled pass (numba, all cores) reads each frame once per pixel and keeps the sums in
registers (bench/hdr times it). Images of fewer than ``NUMPY_BELOW`` values a frame (ROI crops) run the same
arithmetic in numpy (:mod:`acquisition.hdr.small`, the same bits), so numba, slow to import, loads only for a
merge of a larger image.

Layout. This module holds the result types (:class:`HdrImage`, :class:`HdrFlag`) and :func:`merge_linear`
with its weighting decision; bracket validation, frame data, black levels and darks are in
:mod:`acquisition.hdr.bracket`, the clip level per gain in :mod:`acquisition.hdr.saturation` (its measurement
re-exported here as :func:`measure_saturation`), the pass's inputs (offsets, noise terms, saturation thresholds)
in :mod:`acquisition.hdr.prepared`, the numpy pass in :mod:`acquisition.hdr.small` and the compiled one in
:mod:`acquisition.hdr.kernel`.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Literal

import numpy as np
import numpy.typing as npt

from acquisition.frame import Frame
from acquisition.hdr.bracket import F32, DarkSpec, _frame_data, check_bracket
from acquisition.hdr.prepared import _prepare, _Prepared
from acquisition.hdr.saturation import _clip_levels
from acquisition.hdr.saturation import measure_saturation as measure_saturation  # re-exported
from acquisition.hdr.small import Pass
from acquisition.noise import SensorNoise

Weighting = Literal["auto", "sum", "inverse_variance"]

#: Auto weighting: run the inverse-variance pass if it lowers the standard error by more than IV_GAIN ...
IV_GAIN = 0.01
#: ... for at least this fraction of the sampled unflagged pixels.
IV_FRACTION = 0.01
#: Pixels sampled for the auto weighting decision.
IV_SAMPLE = 65536


class HdrFlag(enum.IntFlag):
    """Per-pixel flags of an :class:`HdrImage` (bits of ``HdrImage.flags``)."""

    #: Saturated in every frame: radiance is a lower bound, variance +inf.
    SATURATED = 1
    #: Below ``dark_sigma`` noise sigmas even in the longest frame (undetected): radiance is unreliable.
    DARK = 2
    #: Below zero by more than ``BELOW_BLACK_SIGMA`` standard errors, which no radiance gives: the frames sit
    #: below their black level (or their darks), so that level is wrong. Set together with DARK.
    BELOW_BLACK = 4


#: A pixel whose estimate is this many standard errors below zero is flagged BELOW_BLACK (a zero-signal
#: pixel does so by chance about 3 times in 10 million).
BELOW_BLACK_SIGMA = 5.0


@dataclass(frozen=True, eq=False)
class HdrImage:
    """A merged HDR image with its per-pixel uncertainty.

    Parameters
    ----------
    radiance:
        Radiance per pixel (and channel): counts per second above black at gain 1 for the linear merge,
        relative units per second for the 8-bit path (see ``metadata["units"]``). float32.
    variance:
        Variance of ``radiance`` in its units squared; +inf where saturated in every frame, NaN where
        unknown (8-bit path). float32.
    flags:
        Bits of :class:`HdrFlag`, uint8.
    frames_used:
        Number of frames that entered each pixel's estimate, uint8.
    exposures_s:
        Exposure times of the merged frames in seconds, in input order.
    metadata:
        How the merge was done: method, units, weighting, saturation level, darks, noise model.
    """

    radiance: F32
    variance: F32
    flags: npt.NDArray[np.uint8]
    frames_used: npt.NDArray[np.uint8]
    exposures_s: tuple[float, ...]
    metadata: dict[str, object] = field(default_factory=dict, compare=False)

    @property
    def std_error(self) -> F32:
        """Standard error of ``radiance`` (same units)."""
        return np.sqrt(self.variance)

    @property
    def saturated(self) -> npt.NDArray[np.bool_]:
        """Pixels saturated in every frame."""
        return (self.flags & HdrFlag.SATURATED) != 0

    @property
    def dark(self) -> npt.NDArray[np.bool_]:
        """Pixels dark in every frame (below black included)."""
        return (self.flags & (HdrFlag.DARK | HdrFlag.BELOW_BLACK)) != 0

    @property
    def below_black(self) -> npt.NDArray[np.bool_]:
        """Pixels that read below black by more than BELOW_BLACK_SIGMA standard errors (a wrong black level)."""
        return (self.flags & HdrFlag.BELOW_BLACK) != 0


def merge_linear(
    frames: Sequence[Frame],
    noise: SensorNoise,
    *,
    darks: Mapping[float, DarkSpec] | None = None,
    saturation_dn: float | None = None,
    saturation_sigma: float = 4.0,
    weighting: Weighting = "auto",
    dark_sigma: float = 3.0,
) -> HdrImage:
    """Merge a bracket of raw or linear frames into radiance in counts/s at gain 1, with variance and flags.

    ``noise`` describes the frames as delivered (a photon-transfer calibration of the real camera).
    ``saturation_dn`` is the clip level in counts above black (default: measured, see the module notes).
    """
    kind = check_bracket(frames, ("raw", "linear"))
    _check_options(weighting, saturation_sigma, dark_sigma, saturation_dn)
    data = _frame_data(frames)
    levels = _clip_levels(frames, noise, saturation_dn)
    prep, thresholds, dark_notes = _prepare(frames, data, noise, darks, levels, saturation_sigma, dark_sigma)
    use_iv, reason, (rad, var, flags, used) = _passes(prep, weighting, kind, frames[0])
    flags = _flag_below_black(rad, var, flags)

    no_darks = darks is None
    metadata: dict[str, object] = {
        "method": "linear",
        "units": "counts/s above black at gain 1",
        "kind": kind,
        "cfa_pattern": frames[0].cfa_pattern,
        "camera_id": frames[0].camera_id,
        "weighting": "inverse_variance" if use_iv else "sum",
        "weighting_reason": reason,
        "saturation_level_dn": {g: lv for g, (lv, _) in levels.items()},
        "saturation_source": {g: src for g, (_, src) in levels.items()},
        "saturation_threshold_dn": thresholds,
        "saturation_sigma": saturation_sigma,
        "dark_sigma": dark_sigma,
        "darks_used": not no_darks,
        "darks": (
            "none: black level subtracted, dark current not removed (dim pixels read high by "
            "dark_current_e_per_s * t / e_per_dn counts)" if no_darks else dark_notes
        ),
        "noise": {name: getattr(noise, name) for name in _field_names(type(noise))},  # asdict, without copying
    }
    shape = frames[0].shape
    return HdrImage(
        radiance=rad.reshape(shape), variance=var.reshape(shape), flags=flags.reshape(shape),
        frames_used=used.reshape(shape), exposures_s=tuple(float(f.exposure_s) for f in frames), metadata=metadata,
    )


def _check_options(weighting: str, saturation_sigma: float, dark_sigma: float, saturation_dn: float | None) -> None:
    """Raise ValueError naming the first of merge_linear's options out of its range."""
    if weighting not in ("auto", "sum", "inverse_variance"):
        raise ValueError(f"weighting = {weighting!r}: expected 'auto', 'sum' or 'inverse_variance'")
    if not (math.isfinite(saturation_sigma) and saturation_sigma >= 0):
        raise ValueError(f"saturation_sigma = {saturation_sigma!r}: expected a number >= 0")
    if not (math.isfinite(dark_sigma) and dark_sigma >= 0):
        raise ValueError(f"dark_sigma = {dark_sigma!r}: expected a number >= 0")
    if saturation_dn is not None and not (math.isfinite(saturation_dn) and saturation_dn > 0):
        raise ValueError(f"saturation_dn = {saturation_dn!r}: expected a positive number of counts above black")


def _passes(prep: _Prepared, weighting: Weighting, kind: str, first_frame: Frame) -> tuple[bool, str, Pass]:
    """The merge's pass or passes: (inverse-variance used, why, the pass's flat radiance, variance, flags, frames).

    The sum pass always runs (or comes from the auto decision, on a small image); the inverse-variance pass
    weights by its neighbours' level, each pixel's own left out (see the module notes).
    """
    reason = "forced"
    first: Pass | None = None
    if weighting == "auto":
        use_iv, reason, first = _decide_weighting(prep)
    else:
        use_iv = weighting == "inverse_variance"
    rad, var, flags, used = first if first is not None else prep.run(False)
    if use_iv:
        step = 2 if kind == "raw" or first_frame.cfa_pattern else 1
        signal = neighbour_mean(rad.reshape(first_frame.shape).astype(np.float64), step).reshape(-1)
        rad, var, flags, used = prep.run(True, signal)
    return use_iv, reason, (rad, var, flags, used)


def _flag_below_black(rad: F32, var: F32, flags: npt.NDArray[np.uint8]) -> npt.NDArray[np.uint8]:
    """The flags with DARK and BELOW_BLACK set where the estimate is BELOW_BLACK_SIGMA std errors below zero."""
    if (rad < 0.0).any():  # only a negative estimate can sit standard errors below zero (NaN is neither)
        with np.errstate(invalid="ignore"):
            below = (rad < -BELOW_BLACK_SIGMA * np.sqrt(var)) & (flags != _SATURATED)
        flags = np.where(below, flags | _DARK_BELOW_BLACK, flags).astype(np.uint8)
    return flags


#: The flags as plain numbers: numpy operations with an IntFlag convert it on every call.
_SATURATED = int(HdrFlag.SATURATED)
_DARK_BELOW_BLACK = int(HdrFlag.DARK | HdrFlag.BELOW_BLACK)


_FIELD_NAMES: dict[type, tuple[str, ...]] = {}


def _field_names(cls: type) -> tuple[str, ...]:
    names = _FIELD_NAMES.get(cls)
    if names is None:
        names = _FIELD_NAMES[cls] = tuple(f.name for f in fields(cls))
    return names


def neighbour_mean(image: npt.NDArray[np.float64], step: int = 1) -> npt.NDArray[np.float64]:
    """Mean of each pixel's 8 neighbours at ``step`` pixels (2: the same colour in a mosaic), itself excluded.

    Per channel for an (H, W, C) image; at edges the neighbours that exist. A pixel without any neighbour
    (an image of one same-colour pixel) keeps its own value.
    """
    h, w = image.shape[:2]
    total = np.zeros_like(image)
    count = np.zeros((h, w) + (1,) * (image.ndim - 2))
    for dy in (-step, 0, step):
        for dx in (-step, 0, step):
            if (dy, dx) == (0, 0):
                continue
            ys, yd = (slice(dy, None), slice(None, h - dy)) if dy >= 0 else (slice(None, dy), slice(-dy, None))
            xs, xd = (slice(dx, None), slice(None, w - dx)) if dx >= 0 else (slice(None, dx), slice(-dx, None))
            total[yd, xd] += image[ys, xs]
            count[yd, xd] += 1
    with np.errstate(invalid="ignore", divide="ignore"):
        out: npt.NDArray[np.float64] = np.where(count > 0, total / np.maximum(count, 1), image)
    return out


def _decide_weighting(
    prep: _Prepared,
) -> tuple[bool, str, Pass | None]:
    """Auto weighting: would the inverse-variance pass lower the standard error enough, on a pixel sample?

    Also returns the sample's sum pass when the sample is every pixel (a small image): the merge's own.
    """
    stride = max(1, prep.data[0].size // IV_SAMPLE)
    sample = prep.subsample(stride) if stride > 1 else prep  # every pixel: the arrays as they are
    # The inverse-variance prediction weights by the sum pass: the one just taken, not a second run of it.
    first, var_iv = sample.sum_and_predicted_iv()
    _, var_sum, flags, _ = first
    whole = first if stride == 1 else None
    ok = flags == 0
    n_ok = int(np.count_nonzero(ok))
    if n_ok == 0:
        return False, "auto: no unflagged pixel in the sample", whole
    if var_iv is var_sum:
        # No pixel uses two frames, so both passes are one: v / v - 1 is 0.0, or NaN where v is 0 or not finite.
        v = var_sum[ok]
        fraction, max_gain = 0.0, 0.0 if bool((np.isfinite(v) & (v != 0)).all()) else math.nan
    else:
        gain = np.sqrt(var_sum[ok].astype(np.float64) / var_iv[ok]) - 1.0
        # np.mean of the booleans, exactly: an exact count over the number, rounded once.
        fraction, max_gain = int(np.count_nonzero(gain > IV_GAIN)) / n_ok, float(gain.max())
    verdict = fraction >= IV_FRACTION
    reason = (
        f"auto: the inverse-variance pass lowers the standard error by > {IV_GAIN:.0%} for {fraction:.2%} of "
        f"{n_ok} sampled pixels (threshold {IV_FRACTION:.0%}); max gain {max_gain:.2%}"
    )
    return verdict, reason, whole
