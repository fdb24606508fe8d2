"""Linear HDR merge of a bracket of RAW or linear frames, with per-pixel variance and flags.

Estimator. A pixel read in frame ``k`` (exposure ``t_k`` seconds, gain ``g_k``) reports ``s_k`` counts;
``y_k = s_k - dark_k`` has mean ``X * e_k`` with ``e_k = t_k * g_k`` and ``X`` the radiance in counts per
second at gain 1. Over the frames where the pixel is not saturated the merge returns

    X = sum(y_k) / sum(e_k)                        ("sum", the noise-optimal merge of REFERENCE.md),

which is the maximum-likelihood estimate when shot noise dominates (for Poisson counts the total count
over the total exposure is sufficient). When read noise matters it is not: a short frame adds a full
read-noise variance for a sliver of signal. The inverse-variance merge

    X = sum(w_k y_k) / sum(w_k e_k),   w_k = e_k / var_k(X0)       ("inverse_variance")

uses the first-pass estimate X0 in the noise model ``SensorNoise.variance_dn2``; its variance,
``1 / sum(e_k^2 / var_k)``, is the Cramer-Rao bound of the bracket under that model. The sum merge's
variance is ``sum(var_k) / sum(e_k)^2``. Both are reported per pixel in (counts/s)^2.

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
estimate (it may be negative), and its variance the model's. ``frames_used`` counts the frames that entered
each pixel's estimate.

Darks. ``darks`` maps exposure times (s) to a dark Frame, a sequence of dark Frames (averaged; variance
divided by their number), a master-dark array or a mean dark level (counts, noise neglected). A dark
frame's own noise is added to the variance. Without darks the black level of each frame's metadata is
subtracted and dark current is left in: dim pixels read high by ``dark_current * t / e_per_dn`` counts;
the result's metadata says so.

Speed. One compiled pass (numba, all cores) reads each frame once per pixel and keeps the sums in
registers; a bracket of 7 frames of 1 MP x 3 merges in a few tens of milliseconds.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numba
import numpy as np
import numpy.typing as npt
from numba import prange

from acquisition.frame import Frame, FrameError, FrameKind
from acquisition.noise import SensorNoise

Weighting = Literal["auto", "sum", "inverse_variance"]
DarkSpec = Frame | Sequence[Frame] | npt.NDArray[np.generic] | float
F32 = npt.NDArray[np.float32]

#: Auto weighting: run the inverse-variance pass if it lowers the standard error by more than IV_GAIN ...
IV_GAIN = 0.01
#: ... for at least this fraction of the sampled unflagged pixels.
IV_FRACTION = 0.01
#: Pixels sampled for the auto weighting decision.
IV_SAMPLE = 65536
#: A bracket has at most this many frames (the compiled pass is specialised on a padded frame count).
MAX_FRAMES = 64

_JIT: dict[str, Any] = {"fastmath": False, "error_model": "numpy", "boundscheck": False, "cache": True}


class HdrFlag(enum.IntFlag):
    """Per-pixel flags of an :class:`HdrImage` (bits of ``HdrImage.flags``)."""

    #: Saturated in every frame: radiance is a lower bound, variance +inf.
    SATURATED = 1
    #: Below ``dark_sigma`` noise sigmas even in the longest frame (undetected): radiance is unreliable.
    DARK = 2


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
        """Pixels dark in every frame."""
        return (self.flags & HdrFlag.DARK) != 0


def describe_frame(index: int, frame: Frame) -> str:
    """How error messages name a frame: its index in the bracket and its file or camera and exposure."""
    if frame.source:
        return f"frame {index} ({frame.source})"
    return f"frame {index} ({frame.camera_id}, {frame.exposure_s:g} s)"


def check_bracket(frames: Sequence[Frame], kinds: Sequence[FrameKind]) -> FrameKind:
    """Validate a bracket (non-empty, one kind among ``kinds``, one shape, positive exposures); its kind."""
    if len(frames) == 0:
        raise FrameError("empty bracket: no frames to merge")
    for i, f in enumerate(frames):
        if not isinstance(f, Frame):
            raise FrameError(f"frame {i}: expected an acquisition.frame.Frame, got {type(f).__name__}")
    first = frames[0]
    for i, f in enumerate(frames):
        where = describe_frame(i, f)
        if f.kind != first.kind:
            raise FrameError(
                f"{where} is kind {f.kind!r} but {describe_frame(0, first)} is kind {first.kind!r}: "
                "a bracket must be of one kind"
            )
        if f.shape != first.shape:
            raise FrameError(f"{where} has shape {f.shape} but {describe_frame(0, first)} has shape {first.shape}")
        if not (math.isfinite(f.exposure_s) and f.exposure_s > 0):
            raise FrameError(f"{where}: exposure_s = {f.exposure_s!r}, expected a positive number of seconds")
        if not (math.isfinite(f.gain) and f.gain > 0):
            raise FrameError(f"{where}: gain = {f.gain!r}, expected a positive number")
        if f.cfa_pattern != first.cfa_pattern:
            raise FrameError(
                f"{where} has CFA pattern {f.cfa_pattern!r} but {describe_frame(0, first)} has "
                f"{first.cfa_pattern!r}"
            )
    if first.kind not in kinds:
        hint = ": merge 8-bit frames with acquisition.response.merge_8bit" if first.kind == "8bit" else ""
        raise FrameError(f"{describe_frame(0, first)} is kind {first.kind!r}, expected one of {tuple(kinds)}{hint}")
    if len(frames) > MAX_FRAMES:
        raise FrameError(f"bracket of {len(frames)} frames: at most {MAX_FRAMES} can be merged at once")
    return first.kind


def _min_black(frame: Frame) -> float:
    b = frame.black_level
    return float(min(b)) if isinstance(b, tuple) else float(b)


def _flat(a: npt.NDArray[Any]) -> npt.NDArray[Any]:
    return np.ascontiguousarray(a).reshape(-1)


# ---------------------------------------------------------------------------------------------------------
# Saturation


@numba.njit(**_JIT)
def _top_counts(flat: npt.NDArray[Any], lo: Any, mid: Any) -> tuple[int, int, Any]:  # pragma: no cover
    # Pixels in [lo, mid), pixels >= mid and their sum, in one branch-free pass. ``lo - lo`` is a zero of
    # lo's type: integers for integer data (exact sums, and 5x faster than a parallel float reduction).
    zero = lo - lo
    n_below = 0
    n_top = 0
    sum_top = zero
    for i in range(flat.size):
        v = flat[i] + zero
        top = v >= mid
        n_top += 1 if top else 0
        sum_top += v if top else zero
        n_below += 1 if (v >= lo and not top) else 0
    return n_below, n_top, sum_top


def _plateau_level(frame: Frame, min_pixels: int, min_fraction: float) -> float | None:
    """Mean of the clipped plateau at the top of one frame, counts above black; None if there is none."""
    flat = _flat(frame.data)
    if flat.dtype != np.uint16:
        flat = flat.astype(np.float32, copy=False)
    top = float(flat.max())
    black = _min_black(frame)
    # The plateau of a full-well clip is as wide as the read noise after the clip (a few counts); 0.2 % of
    # the range is wide enough for any sensor seen, narrow beside the shot noise of unclipped pixels there.
    width = max(4.0, 2e-3 * (top - black))
    lo, mid = top - 4.0 * width, top - width
    if flat.dtype == np.uint16:
        n_below, n_top, sum_top = _top_counts(flat, math.ceil(lo), math.ceil(mid))
    else:
        n_below, n_top, sum_top = _top_counts(flat, lo, mid)
    # A clip piles pixels up at the top: far more there than the density just below (3 widths) predicts.
    if n_top < max(min_pixels, min_fraction * flat.size) or n_top * 3 < 8 * n_below:
        return None
    level = float(sum_top) / n_top - black
    # A frame whose values all sit in a narrow band (a dark frame, a very short exposure) piles up too;
    # no sensor clips in the bottom tenth of its range.
    return level if level >= 0.1 * (frame.white_level - black) else None


def measure_saturation(
    frames: Sequence[Frame], *, min_pixels: int = 16, min_fraction: float = 1e-5
) -> float | None:
    """Clip level in counts above black, measured from the plateau of clipped pixels; None if nothing clips.

    Looks at the frames from the longest exposure down and takes the median of the plateau levels (mean
    value of the plateau) of the first two that show one: a pile-up of at least ``min_pixels`` (and
    ``min_fraction`` of the pixels) within 0.2 % of the range below the frame's maximum, 8x denser than the
    values just below, and at least a tenth of the way from black to ``white_level`` (a frame whose values
    all sit in a narrow band near black piles up too). A full-well clip below the ADC's white level shows
    up here, which trusting ``white_level`` would miss. The frames should share one gain (the clip in
    counts scales with it); :func:`merge_linear` measures each gain's frames apart.
    """
    check_bracket(frames, ("raw", "linear"))
    levels: list[float] = []
    for f in sorted(frames, key=lambda f: f.exposure_s * f.gain, reverse=True):
        level = _plateau_level(f, min_pixels, min_fraction)
        if level is not None:
            levels.append(level)
            if len(levels) == 2:
                break
    return float(np.median(levels)) if levels else None


# ---------------------------------------------------------------------------------------------------------
# The compiled pass


@functools.cache
def _merge_kernel(with_maps: bool, inverse_variance: bool) -> Any:
    """The compiled pass for one configuration (compile-time constants, so the other branches fold away).

    ``with_maps``: some offset is a per-pixel map. The frame loop runs over the whole (padded) tuple, a
    compile-time length, so LLVM unrolls it and resolves each tuple item statically; padding frames have
    threshold -inf and are never used. Measured on 1 MP x 3 x 7 frames: a run-time frame count, a run-time
    tuple index, or the inverse-variance loop present but switched off by a run-time flag each made the
    sum pass 2-5x slower.
    """

    @numba.njit(parallel=True, **_JIT)
    def kernel(  # pragma: no cover (compiled)
        data: Any, offmaps: Any, off_s: Any, thr_raw: Any, expo: Any, shot: Any, cvar: Any,
        shortest: int, longest: int, dark_thr: float, rad: Any, var: Any, flags: Any, used: Any,
    ) -> None:
        for i in prange(rad.size):
            s = 0.0
            e = 0.0
            a = 0.0
            b = 0.0
            m = 0
            y_short = 0.0
            y_long = 0.0
            for k in range(len(data)):
                y = np.float64(data[k][i]) - (offmaps[k][i] if with_maps else off_s[k])
                # Picked up inside the unrolled loop: indexing the tuple with a run-time index costs more.
                if k == shortest:
                    y_short = y
                if k == longest:
                    y_long = y
                if data[k][i] < thr_raw[k]:
                    s += y
                    e += expo[k]
                    a += shot[k]
                    b += cvar[k]
                    m += 1
            used[i] = m
            if m == 0:
                rad[i] = y_short / expo[shortest]
                var[i] = np.inf
                flags[i] = 1
                continue
            x = s / e
            xp = x if x > 0.0 else 0.0
            if inverse_variance and m > 1:
                wy = 0.0
                we = 0.0
                for k in range(len(data)):
                    if data[k][i] < thr_raw[k]:
                        w = expo[k] / (xp * shot[k] + cvar[k])
                        wy += w * (np.float64(data[k][i]) - (offmaps[k][i] if with_maps else off_s[k]))
                        we += w * expo[k]
                rad[i] = wy / we
                var[i] = 1.0 / we
            else:
                rad[i] = x
                var[i] = (xp * a + b) / (e * e)
            flags[i] = 2 if y_long < dark_thr else 0

    return kernel


def _padded_size(n_frames: int) -> int:
    # The compiled pass is specialised on the tuple length: pad to a multiple of 8 so brackets of 1-8
    # frames share one compilation (cached on disk), 9-16 another, and so on.
    return 8 * math.ceil(n_frames / 8)


@dataclass(frozen=True)
class _Prepared:
    """Everything the compiled pass needs, per frame padded to ``_padded_size`` (padding is never used)."""

    data: tuple[npt.NDArray[Any], ...]
    offmaps: tuple[npt.NDArray[Any], ...] | None
    off_s: npt.NDArray[np.float64]
    thr_raw: npt.NDArray[np.float64]
    expo: npt.NDArray[np.float64]
    shot: npt.NDArray[np.float64]
    cvar: npt.NDArray[np.float64]
    shortest: int
    longest: int
    dark_thr: float

    def subsample(self, stride: int) -> _Prepared:
        """The same merge on every ``stride``-th pixel."""
        def sub(arrays: tuple[npt.NDArray[Any], ...]) -> tuple[npt.NDArray[Any], ...]:
            cache: dict[int, npt.NDArray[Any]] = {}
            return tuple(cache.setdefault(id(a), np.ascontiguousarray(a[::stride])) for a in arrays)

        maps = None if self.offmaps is None else sub(self.offmaps)
        return dataclasses.replace(self, data=sub(self.data), offmaps=maps)

    def run(self, inverse_variance: bool) -> tuple[F32, F32, npt.NDArray[np.uint8], npt.NDArray[np.uint8]]:
        """Radiance, variance, flags and frames used, flat."""
        n = self.data[0].size
        rad = np.empty(n, np.float32)
        var = np.empty(n, np.float32)
        flags = np.empty(n, np.uint8)
        used = np.empty(n, np.uint8)
        with_maps = self.offmaps is not None
        maps = self.offmaps if self.offmaps is not None else (np.zeros(1, np.float32),) * len(self.data)
        _merge_kernel(with_maps, inverse_variance)(
            self.data, maps, self.off_s, self.thr_raw, self.expo, self.shot, self.cvar, self.shortest, self.longest,
            self.dark_thr, rad, var, flags, used,
        )
        return rad, var, flags, used


def _black_map(frame: Frame, index: int, cache: dict[tuple[Any, ...], F32]) -> F32 | float:
    """The frame's black level: a number, or a per-pixel map for per-CFA-site or per-channel levels."""
    b = frame.black_level
    if not isinstance(b, tuple):
        return float(b)
    if len(set(b)) == 1:
        return float(b[0])
    key = (b, frame.shape, frame.kind)
    if key in cache:
        return cache[key]
    if frame.kind == "raw" and len(b) == 4:
        tile = np.asarray(b, np.float32).reshape(2, 2)
        h, w = frame.shape
        full = np.tile(tile, (h // 2 + 1, w // 2 + 1))[:h, :w]
    elif frame.data.ndim == 3 and len(b) == frame.shape[2]:
        full = np.broadcast_to(np.asarray(b, np.float32), frame.shape)
    else:
        raise FrameError(
            f"{describe_frame(index, frame)}: black_level {b!r} has {len(b)} values; expected 1, 4 (one per "
            "CFA site of a raw frame) or one per channel"
        )
    cache[key] = _flat(full.astype(np.float32))
    return cache[key]


def _find_dark(darks: Mapping[float, DarkSpec], exposure_s: float) -> DarkSpec | None:
    for key, spec in darks.items():
        if math.isclose(float(key), exposure_s, rel_tol=1e-4):
            return spec
    return None


def _dark_offset(
    index: int, frame: Frame, spec: DarkSpec, noise: SensorNoise
) -> tuple[npt.NDArray[Any] | float, float, str]:
    """Offset to subtract (counts: a flat map or a number), the variance it adds (counts^2), a description."""
    where = describe_frame(index, frame)
    one_frame_var = float(noise.variance_dn2(0.0, frame.exposure_s, frame.gain))
    if isinstance(spec, Frame):
        spec = [spec]
    if isinstance(spec, Sequence) and not isinstance(spec, (str, bytes)) and all(isinstance(d, Frame) for d in spec):
        if len(spec) == 0:
            raise FrameError(f"{where}: the dark list for {frame.exposure_s:g} s is empty")
        total = np.zeros(frame.shape if len(spec) > 1 else (), np.float32)
        for j, d in enumerate(spec):
            dwhere = f"dark {j} for {frame.exposure_s:g} s ({d.source or d.camera_id})"
            if d.shape != frame.shape:
                raise FrameError(f"{dwhere} has shape {d.shape} but {where} has shape {frame.shape}")
            if d.kind != frame.kind:
                raise FrameError(f"{dwhere} is kind {d.kind!r} but {where} is kind {frame.kind!r}")
            if not math.isclose(d.gain, frame.gain, rel_tol=1e-4):
                raise FrameError(f"{dwhere} has gain {d.gain!r} but {where} has gain {frame.gain!r}")
            if not math.isclose(d.exposure_s, frame.exposure_s, rel_tol=1e-3):
                raise FrameError(f"{dwhere} has exposure_s {d.exposure_s!r} but {where} has {frame.exposure_s!r}")
            if len(spec) > 1:
                total += np.asarray(d.data, dtype=np.float32)
        if len(spec) == 1 and spec[0].data.dtype == np.uint16:
            # As delivered: the compiled pass reads uint16 maps directly, saving a float copy per frame.
            return _flat(spec[0].data), one_frame_var, "1 dark frame"
        total /= len(spec)
        return _flat(total), one_frame_var / len(spec), f"{len(spec)} dark frames averaged"
    arr = np.asarray(spec, dtype=np.float32)
    if arr.ndim == 0:
        if not math.isfinite(float(arr)):
            raise FrameError(f"{where}: dark level {float(arr)!r} for {frame.exposure_s:g} s is not finite")
        return float(arr), 0.0, "mean dark level"
    if arr.shape != frame.shape:
        raise FrameError(f"master dark for {frame.exposure_s:g} s has shape {arr.shape} but {where} has {frame.shape}")
    return _flat(arr), 0.0, "master dark array"


def _frame_data(frames: Sequence[Frame]) -> list[npt.NDArray[Any]]:
    """Flat pixel arrays in one dtype the compiled pass knows: uint16 as delivered, anything else float32."""
    if all(f.data.dtype == np.uint16 for f in frames):
        return [_flat(f.data) for f in frames]
    out = []
    for i, f in enumerate(frames):
        a = _flat(f.data).astype(np.float32, copy=False)
        if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
            raise FrameError(f"{describe_frame(i, f)} has non-finite pixel values")
        out.append(a)
    return out


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
    if weighting not in ("auto", "sum", "inverse_variance"):
        raise ValueError(f"weighting = {weighting!r}: expected 'auto', 'sum' or 'inverse_variance'")
    if not (math.isfinite(saturation_sigma) and saturation_sigma >= 0):
        raise ValueError(f"saturation_sigma = {saturation_sigma!r}: expected a number >= 0")
    if not (math.isfinite(dark_sigma) and dark_sigma >= 0):
        raise ValueError(f"dark_sigma = {dark_sigma!r}: expected a number >= 0")
    if saturation_dn is not None and not (math.isfinite(saturation_dn) and saturation_dn > 0):
        raise ValueError(f"saturation_dn = {saturation_dn!r}: expected a positive number of counts above black")
    n_frames = len(frames)
    data = _frame_data(frames)

    # Clip level per gain (a full-well clip in counts scales with gain; one bracket usually has one gain).
    levels: dict[float, tuple[float, str]] = {}
    for g in sorted({f.gain for f in frames}):
        if saturation_dn is not None:
            levels[g] = (float(saturation_dn), "given")
            continue
        measured = measure_saturation([f for f in frames if f.gain == g])
        if measured is not None:
            levels[g] = (measured, "measured from the data")
        else:
            levels[g] = (noise.saturation_dn(g), "noise model (no clipped plateau in the data)")

    size = _padded_size(n_frames)
    black_cache: dict[tuple[Any, ...], F32] = {}
    maps: list[npt.NDArray[Any] | None] = []
    off_s = np.zeros(size)
    thr_raw = np.full(size, -np.inf)
    thr_above = np.zeros(n_frames)
    expo = np.ones(size)
    expo[:n_frames] = [f.exposure_s * f.gain for f in frames]
    shot = np.zeros(size)
    cvar = np.ones(size)
    dark_notes: list[str] = []
    for i, f in enumerate(frames):
        if darks is None:
            offset: npt.NDArray[Any] | float = _black_map(f, i, black_cache)
            dark_var, note = 0.0, "black level"
        else:
            spec = _find_dark(darks, f.exposure_s)
            if spec is None:
                raise FrameError(
                    f"{describe_frame(i, f)}: no dark for exposure {f.exposure_s:g} s; darks were given for "
                    f"{sorted(float(k) for k in darks)} s"
                )
            offset, dark_var, note = _dark_offset(i, f, spec, noise)
        dark_notes.append(note)
        if isinstance(offset, np.ndarray):
            maps.append(offset)
        else:
            maps.append(None)
            off_s[i] = offset
        shot[i] = expo[i] * f.gain / noise.e_per_dn
        cvar[i] = float(noise.variance_dn2(0.0, f.exposure_s, f.gain)) + dark_var
        black = _min_black(f)
        level = min(levels[f.gain][0], f.white_level - black)
        thr_above[i] = level - saturation_sigma * math.sqrt(float(noise.variance_dn2(level, f.exposure_s, f.gain)))
        thr_raw[i] = black + thr_above[i]

    offmaps: tuple[npt.NDArray[Any], ...] | None = None
    present = [m for m in maps if m is not None]
    if len(present) == n_frames and all(m.dtype == np.uint16 for m in present):
        # One uint16 dark frame per exposure, as delivered.
        offmaps = tuple(present) + (present[0],) * (size - n_frames)
    elif any(m is not None for m in maps):
        # Otherwise all maps float32 (one type per tuple); a frame with a number for offset reads a shared
        # zero map, one array that stays in cache.
        zeros = np.zeros(data[0].size, np.float32)
        as_f32 = [zeros if m is None else m.astype(np.float32, copy=False) for m in maps]
        offmaps = tuple(as_f32) + (zeros,) * (size - n_frames)
    shortest, longest = int(np.argmin(expo[:n_frames])), int(np.argmax(expo[:n_frames]))
    prep = _Prepared(
        data=tuple(data) + (data[0],) * (size - n_frames), offmaps=offmaps, off_s=off_s, thr_raw=thr_raw,
        expo=expo, shot=shot, cvar=cvar, shortest=shortest, longest=longest,
        dark_thr=dark_sigma * math.sqrt(cvar[longest]),
    )

    reason = "forced"
    if weighting == "auto":
        use_iv, reason = _decide_weighting(prep)
    else:
        use_iv = weighting == "inverse_variance"
    rad, var, flags, used = prep.run(use_iv)

    shape = frames[0].shape
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
        "saturation_threshold_dn": tuple(float(t) for t in thr_above),
        "saturation_sigma": saturation_sigma,
        "dark_sigma": dark_sigma,
        "darks_used": not no_darks,
        "darks": (
            "none: black level subtracted, dark current not removed (dim pixels read high by "
            "dark_current_e_per_s * t / e_per_dn counts)" if no_darks else tuple(dark_notes)
        ),
        "noise": asdict(noise),
    }
    return HdrImage(
        radiance=rad.reshape(shape), variance=var.reshape(shape), flags=flags.reshape(shape),
        frames_used=used.reshape(shape), exposures_s=tuple(float(f.exposure_s) for f in frames), metadata=metadata,
    )


def _decide_weighting(prep: _Prepared) -> tuple[bool, str]:
    """Auto weighting: would the inverse-variance pass lower the standard error enough, on a pixel sample?"""
    sample = prep.subsample(max(1, prep.data[0].size // IV_SAMPLE))
    _, var_sum, flags, _ = sample.run(False)
    _, var_iv, _, _ = sample.run(True)
    ok = flags == 0
    if not ok.any():
        return False, "auto: no unflagged pixel in the sample"
    gain = np.sqrt(var_sum[ok].astype(np.float64) / var_iv[ok]) - 1.0
    fraction = float(np.mean(gain > IV_GAIN))
    verdict = fraction >= IV_FRACTION
    return verdict, (
        f"auto: the inverse-variance pass lowers the standard error by > {IV_GAIN:.0%} for {fraction:.2%} of "
        f"{int(ok.sum())} sampled pixels (threshold {IV_FRACTION:.0%}); max gain {float(gain.max()):.2%}"
    )
