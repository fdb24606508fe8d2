"""The simulated camera sensor: a linear radiance image in, one exposure of a bracket out, as a :class:`Frame`.

Units. ``radiance`` is in camera units per second: the counts per second above black that the pixel
would report at gain 1 if there were no noise. A pixel exposed for ``t`` seconds at gain ``g`` therefore
collects on average ``radiance * t * e_per_dn`` photo-electrons (``e_per_dn`` electrons make one count at
gain 1) and reports on average ``black + radiance * t * g`` counts below saturation.

The chain, per pixel, with the parameters of :class:`acquisition.noise.SensorNoise` (the same ones the
HDR merge and the exposure planner assume):

1. photo-electrons ~ Poisson(radiance * t * e_per_dn) plus dark-current electrons ~ Poisson(dark_e_per_s
   * t), drawn as one Poisson of the summed mean (the sum of independent Poissons is Poisson);
2. the collected charge clips at ``full_well_e`` (before readout, so a full pixel still shows read noise);
3. read noise, Gaussian with ``read_noise_e`` electrons RMS;
4. conversion to counts (``gain / e_per_dn`` counts per electron), plus ``black_level_dn``;
5. quantisation (round to the nearest count) and the ADC range clip to [0, ``white_level_dn``].

Its mean and variance are those of ``SensorNoise.variance_dn2`` (the 1/12 of step 5 is exact when the
read noise spans a count or more). ``kind="raw"`` samples an RGB radiance through a 2x2 colour filter
array first; ``kind="8bit"`` passes the counts through a tone curve to 8-bit codes, the way a camera
without RAW output would (code 255 at the sensor's saturation, ``SensorNoise.saturation_dn``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from acquisition.frame import Frame, FrameKind
from acquisition.noise import SensorNoise

FloatArray = npt.NDArray[np.float64]
#: Maps relative linear exposure in [0, 1] (1 = sensor saturation) to an encoded value in [0, 1].
ToneCurve = Callable[[FloatArray], FloatArray]

_CFA_CHANNEL = {"R": 0, "G": 1, "B": 2}


def srgb_curve(x: FloatArray) -> FloatArray:
    """sRGB transfer function (IEC 61966-2-1): relative linear exposure in [0, 1] to encoded [0, 1]."""
    x = np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


@dataclass(frozen=True)
class GammaCurve:
    """Pure power-law response ``x ** (1 / gamma)`` on relative linear exposure in [0, 1]."""

    gamma: float = 2.2

    def __post_init__(self) -> None:
        if not (math.isfinite(self.gamma) and self.gamma > 0):
            raise ValueError(f"GammaCurve.gamma = {self.gamma!r}: expected a positive number")

    def __call__(self, x: FloatArray) -> FloatArray:
        """Encode relative linear exposure in [0, 1] to [0, 1]."""
        return np.power(np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0), 1.0 / self.gamma)


@dataclass(frozen=True)
class SCurve:
    """A filmic S-shaped response: gamma encoding followed by a contrast S, ``g^c / (g^c + (1 - g)^c)``.

    ``contrast`` 1 is the plain gamma curve; larger values compress shadows and highlights, as the tone
    curves of consumer cameras do. Monotone, 0 -> 0 and 1 -> 1.
    """

    gamma: float = 2.2
    contrast: float = 1.6

    def __post_init__(self) -> None:
        for key in ("gamma", "contrast"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"SCurve.{key} = {value!r}: expected a positive number")

    def __call__(self, x: FloatArray) -> FloatArray:
        """Encode relative linear exposure in [0, 1] to [0, 1]."""
        g = np.power(np.clip(np.asarray(x, dtype=np.float64), 0.0, 1.0), 1.0 / self.gamma)
        gc = np.power(g, self.contrast)
        return gc / (gc + np.power(1.0 - g, self.contrast))


def as_generator(rng: np.random.Generator | int) -> np.random.Generator:
    """A numpy Generator: ``rng`` itself, or a new one seeded with the integer ``rng``."""
    if isinstance(rng, np.random.Generator):
        return rng
    if isinstance(rng, (int, np.integer)) and not isinstance(rng, bool):
        return np.random.default_rng(int(rng))
    raise TypeError(f"rng = {rng!r}: expected a numpy.random.Generator or an integer seed")


def mosaic(rgb: npt.ArrayLike, cfa_pattern: str = "RGGB") -> FloatArray:
    """Sample an (H, W, 3) RGB image through a 2x2 colour filter array: the (H, W) mosaic, same units."""
    image = np.asarray(rgb, dtype=np.float64)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"mosaic needs an (H, W, 3) image, got shape {image.shape}")
    _check_pattern(cfa_pattern)
    out = np.empty(image.shape[:2], dtype=np.float64)
    for pos, letter in enumerate(cfa_pattern):
        dy, dx = divmod(pos, 2)
        out[dy::2, dx::2] = image[dy::2, dx::2, _CFA_CHANNEL[letter]]
    return out


def _check_pattern(cfa_pattern: str) -> None:
    if len(cfa_pattern) != 4 or set(cfa_pattern) - set("RGB"):
        raise ValueError(f"cfa_pattern = {cfa_pattern!r}: expected 4 letters of R, G, B, e.g. 'RGGB'")


def _validated_radiance(radiance: npt.ArrayLike) -> FloatArray:
    rad = np.asarray(radiance, dtype=np.float64)
    if rad.ndim not in (2, 3):
        raise ValueError(f"radiance has shape {rad.shape}: expected (H, W) or (H, W, C)")
    # One reduction instead of separate isfinite and >= 0 passes: NaN fails the comparison too.
    if not bool(np.all((rad >= 0.0) & (rad < np.inf))):
        raise ValueError("radiance must be finite and >= 0 (counts per second at gain 1)")
    return rad


def _check_exposure(exposure_s: float, gain: float) -> None:
    if not (math.isfinite(exposure_s) and exposure_s > 0):
        raise ValueError(f"exposure_s = {exposure_s!r}: expected a positive number of seconds")
    if not (math.isfinite(gain) and gain > 0):
        raise ValueError(f"gain = {gain!r}: expected a positive number")


def sensor_counts(
    radiance: npt.ArrayLike,
    noise: SensorNoise,
    exposure_s: float,
    rng: np.random.Generator | int,
    gain: float = 1.0,
    offset_dn: npt.ArrayLike | None = None,
    pixel_gain: npt.ArrayLike | None = None,
    nonlinearity: float = 0.0,
) -> npt.NDArray[np.unsignedinteger]:
    """Raw counts (black included, quantised, clipped to the ADC range) of one exposure of ``radiance`` (counts/s).

    ``offset_dn`` is a fixed-pattern offset in counts (per pixel, broadcast against the image) added to the
    black level: the same in every frame of a camera, so dark frames carry it and subtracting them removes it.
    ``pixel_gain`` is each pixel's relative response to light (vignetting times PRNU, broadcast against
    the image); ``nonlinearity`` bends the collected charge ``e`` to ``e (1 - nonlinearity e / full_well_e)``.
    """
    rad = _validated_radiance(radiance)
    _check_exposure(exposure_s, gain)
    gen = as_generator(rng)
    mean_e = rad * (exposure_s * noise.e_per_dn)
    if pixel_gain is not None:
        mean_e *= np.asarray(pixel_gain, dtype=np.float64).reshape(mean_e.shape[:2] + (1,) * (mean_e.ndim - 2))
    mean_e += noise.dark_current_e_per_s * exposure_s
    # A mean of ten full wells clips just as surely as any larger one, and keeps Poisson's argument far
    # from its overflow limit whatever radiance the caller passes.
    np.minimum(mean_e, 10.0 * noise.full_well_e + 100.0, out=mean_e)
    electrons = gen.poisson(mean_e)
    np.minimum(electrons, math.floor(noise.full_well_e), out=electrons)
    signal = electrons.astype(np.float32)
    del electrons
    if nonlinearity:
        signal *= np.float32(1.0) - np.float32(nonlinearity / noise.full_well_e) * signal
    if noise.read_noise_e > 0:
        read = gen.standard_normal(signal.shape, dtype=np.float32)
        read *= np.float32(noise.read_noise_e)
        signal += read
        del read
    signal *= np.float32(gain / noise.e_per_dn)
    signal += np.float32(noise.black_level_dn)
    if offset_dn is not None:
        signal += np.asarray(offset_dn, dtype=np.float32)
    np.rint(signal, out=signal)
    white = math.floor(noise.white_level_dn)
    np.clip(signal, 0.0, white, out=signal)
    counts: npt.NDArray[np.unsignedinteger] = signal.astype(np.uint16 if white <= 65535 else np.uint32)
    return counts


def tone_lut(noise: SensorNoise, tone_curve: ToneCurve = srgb_curve, gain: float = 1.0) -> npt.NDArray[np.uint8]:
    """8-bit code for every raw count 0..white: ``round(255 * curve((count - black) / saturation))``."""
    counts = np.arange(math.floor(noise.white_level_dn) + 1, dtype=np.float64)
    x = np.clip((counts - noise.black_level_dn) / noise.saturation_dn(gain), 0.0, 1.0)
    encoded = np.asarray(tone_curve(x), dtype=np.float64)
    if encoded.shape != x.shape or not np.all(np.isfinite(encoded)):
        raise ValueError("tone_curve must map an array of values in [0, 1] to finite values of the same shape")
    return np.clip(np.rint(255.0 * encoded), 0, 255).astype(np.uint8)


def capture(
    radiance: npt.ArrayLike,
    noise: SensorNoise,
    exposure_s: float,
    rng: np.random.Generator | int,
    *,
    gain: float = 1.0,
    kind: FrameKind = "linear",
    cfa_pattern: str | None = None,
    tone_curve: ToneCurve = srgb_curve,
    camera_id: str = "simulated",
    timestamp_s: float = 0.0,
    offset_dn: npt.ArrayLike | None = None,
    pixel_gain: npt.ArrayLike | None = None,
    nonlinearity: float = 0.0,
) -> Frame:
    """One exposure (seconds) of ``radiance`` (counts/s at gain 1, (H, W) or (H, W, C)) as a Frame.

    ``kind="linear"``: counts per pixel and channel. ``kind="raw"``: an (H, W) mosaic in counts, sampled
    through ``cfa_pattern`` (default ``"RGGB"``) from an (H, W, 3) radiance, or taken as an already
    mosaicked (H, W) radiance. ``kind="8bit"``: ``tone_curve`` applied to the counts relative to
    saturation, 8-bit codes (black level 0, white level 255).
    """
    rad = _validated_radiance(radiance)
    pattern = None
    if kind == "raw":
        pattern = cfa_pattern or "RGGB"
        _check_pattern(pattern)
        if rad.ndim == 3:
            rad = mosaic(rad, pattern)
    elif kind not in ("linear", "8bit"):
        raise ValueError(f"kind = {kind!r}: expected 'raw', 'linear' or '8bit'")
    elif cfa_pattern is not None:
        raise ValueError(f"cfa_pattern = {cfa_pattern!r} given for kind {kind!r}: only raw frames have one")
    counts = sensor_counts(rad, noise, exposure_s, rng, gain, offset_dn, pixel_gain, nonlinearity)
    extra: dict[str, object] = {"simulated": True}
    if kind == "8bit":
        extra["tone_curve"] = getattr(tone_curve, "__name__", repr(tone_curve))
        return Frame(
            data=tone_lut(noise, tone_curve, gain)[counts], kind="8bit", exposure_s=exposure_s, gain=gain,
            black_level=0.0, white_level=255.0, timestamp_s=timestamp_s, camera_id=camera_id, extra=extra,
        )
    return Frame(
        data=counts, kind=kind, exposure_s=exposure_s, gain=gain, black_level=noise.black_level_dn,
        white_level=noise.white_level_dn, cfa_pattern=pattern, timestamp_s=timestamp_s, camera_id=camera_id,
        extra=extra,
    )


def dark_frame(
    shape: tuple[int, ...],
    noise: SensorNoise,
    exposure_s: float,
    rng: np.random.Generator | int,
    *,
    gain: float = 1.0,
    kind: FrameKind = "linear",
    cfa_pattern: str | None = None,
    camera_id: str = "simulated",
    timestamp_s: float = 0.0,
    offset_dn: npt.ArrayLike | None = None,
) -> Frame:
    """A frame of ``exposure_s`` seconds with the shutter closed: black level, dark current and read noise."""
    if kind == "raw" and len(shape) != 2:
        raise ValueError(f"a raw dark frame is an (H, W) mosaic, got shape {shape}")
    return capture(
        np.zeros(shape), noise, exposure_s, rng, gain=gain, kind=kind, cfa_pattern=cfa_pattern,
        camera_id=camera_id, timestamp_s=timestamp_s, offset_dn=offset_dn,
    )


def capture_bracket(
    radiance: npt.ArrayLike,
    noise: SensorNoise,
    exposures_s: Sequence[float],
    rng: np.random.Generator | int,
    *,
    gain: float = 1.0,
    kind: FrameKind = "linear",
    cfa_pattern: str | None = None,
    tone_curve: ToneCurve = srgb_curve,
    camera_id: str = "simulated",
    start_s: float = 0.0,
) -> list[Frame]:
    """One frame per exposure (seconds) of the same radiance (counts/s), time-stamped back to back from start_s."""
    gen = as_generator(rng)
    rad = _validated_radiance(radiance)
    frames, clock = [], start_s
    for t in exposures_s:
        frames.append(capture(
            rad, noise, t, gen, gain=gain, kind=kind, cfa_pattern=cfa_pattern, tone_curve=tone_curve,
            camera_id=camera_id, timestamp_s=clock,
        ))
        clock += t
    return frames
