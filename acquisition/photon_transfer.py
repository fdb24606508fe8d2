"""Photon transfer: a camera's gain, read noise, dark current, black level, full well and linearity from its frames.

The method of the EMVA 1288 standard, without its photon calibration (no radiometer is needed, and none is
asked for): flat frames at increasing exposure times under a constant uniform light, two per exposure,
and two dark frames per exposure. Per exposure and per colour plane (a mosaic's four CFA sites, a linear
frame's channels, or the one plane of a monochrome sensor):

- the mean signal above dark ``mu = mean((A + B) / 2) - mean((dA + dB) / 2)``;
- the temporal variance from the difference of the two frames, ``var = var(A - B) / 2`` (the difference
  removes the fixed pattern and the pixels' response non-uniformity), and the same of the darks.

Then, in counts (DN):

- gain: ``var - var_dark = mu / e_per_dn`` (shot noise), a weighted least-squares fit through the origin
  over the points below 70 % of saturation, with a quadratic term ``c mu^2`` for the response's compression
  near full well (with 6 points or more); the slope at zero signal is the gain. Weights are the variances'
  own sampling variances, ``2 var^2 / (n - 1)``; the standard error is scaled up by ``sqrt(chi2 / dof)``
  when the scatter exceeds it.
- saturation: the variance peaks where pixels begin to clip (the standard's saturation point); the
  gain and linearity ranges are fractions of the mean there. The clip level ``saturation_dn`` is the
  plateau of the brightest pixels at the longest exposure, which a lens's vignetting would otherwise put
  above the mean at the peak; ``full_well_e = saturation_dn * e_per_dn`` (the standard's saturation
  capacity, whichever of the pixel's well and the ADC's range clips first).
- dark: ``mean_dark(t) = black + dark_rate * t`` and ``var_dark(t) = var_0 + dark_rate / e_per_dn * t``,
  both weighted lines; read noise ``sqrt(var_0 - 1/12) * e_per_dn`` (1/12 count^2 is quantisation), with
  its standard error propagated from both fits.
- linearity: ``mu`` against exposure time between 5 % and 95 % of saturation, a weighted line with offset;
  the linearity error is half the spread of the relative deviations from it, in percent (the standard's LE),
  the largest over the planes.

The result, :class:`PhotonTransfer`, holds every point so it can be plotted (``rig.run.calibrate``) and
gives the :class:`acquisition.noise.SensorNoise` that the HDR merge and the exposure planner assume.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from acquisition.frame import Frame
from acquisition.noise import SensorNoise
from model.errors import CameraFault

FloatArray = npt.NDArray[np.float64]

#: Points used for the gain lie below this fraction of saturation (EMVA 1288).
GAIN_RANGE = 0.7
#: The linearity error is measured between these fractions of saturation (EMVA 1288).
LINEARITY_RANGE = (0.05, 0.95)
QUANTISATION_DN2 = 1.0 / 12.0


class PhotonTransferError(CameraFault, ValueError):
    """The series cannot be fitted: too few points, no saturation, frames that do not pair up."""


@dataclass(frozen=True)
class Estimate:
    """A fitted value with its standard error (same units)."""

    value: float
    std_error: float

    def as_dict(self) -> dict[str, float]:
        """JSON-ready form."""
        return {"value": self.value, "std_error": self.std_error}


@dataclass(frozen=True)
class PtcPoint:
    """One exposure of one colour plane: means (DN) and temporal variances (DN^2) of light and dark, pixels."""

    exposure_s: float
    plane: str
    mean_dn: float
    variance_dn2: float
    dark_mean_dn: float
    dark_variance_dn2: float
    n_pixels: int
    #: Median of the brightest 5 % of one flat's pixels above dark (DN): the clip level once they clip.
    top_dn: float = math.nan

    @property
    def signal_dn(self) -> float:
        """Mean signal above dark (DN)."""
        return self.mean_dn - self.dark_mean_dn

    @property
    def shot_variance_dn2(self) -> float:
        """Temporal variance of the light frames above that of the darks (DN^2)."""
        return self.variance_dn2 - self.dark_variance_dn2


def planes(frame: Frame) -> dict[str, FloatArray]:
    """A frame's colour planes in counts: a mosaic's four CFA sites (``R``, ``G1``, ``G2``, ``B``), a linear
    frame's channels (``c0``...), or the single plane ``mono``."""
    data = np.asarray(frame.data, dtype=np.float64)
    if frame.kind == "raw" and frame.cfa_pattern is not None:
        h, w = (data.shape[0] // 2) * 2, (data.shape[1] // 2) * 2
        out: dict[str, FloatArray] = {}
        greens = 0
        for i, letter in enumerate(frame.cfa_pattern):
            name = letter
            if letter == "G":
                greens += 1
                name = f"G{greens}"
            out[name] = data[i // 2 : h : 2, i % 2 : w : 2]
        return out
    if data.ndim == 3:
        return {f"c{c}": data[..., c] for c in range(data.shape[2])}
    return {"mono": data}


def pair_points(
    exposure_s: float, flats: Sequence[Frame], darks: Sequence[Frame]
) -> list[PtcPoint]:
    """The points of one exposure from two (or more) flat frames and two (or more) darks, one per plane."""
    if len(flats) < 2 or len(darks) < 2:
        raise PhotonTransferError(
            f"exposure {exposure_s:g} s: {len(flats)} flat and {len(darks)} dark frames; photon transfer needs "
            "two of each (their difference is the temporal noise)"
        )
    fa, fb = planes(flats[0]), planes(flats[1])
    da, db = planes(darks[0]), planes(darks[1])
    points = []
    for name in fa:
        a, b, c, d = fa[name], fb[name], da[name], db[name]
        n = a.size
        points.append(PtcPoint(
            exposure_s=float(exposure_s), plane=name, mean_dn=float(0.5 * (a.mean() + b.mean())),
            variance_dn2=float(np.var(a - b, ddof=1) / 2.0), dark_mean_dn=float(0.5 * (c.mean() + d.mean())),
            dark_variance_dn2=float(np.var(c - d, ddof=1) / 2.0), n_pixels=int(n),
            top_dn=float(np.median(a[a >= np.quantile(a, 0.95)]) - 0.5 * (c.mean() + d.mean())),
        ))  # fmt: skip
    return points


def _line(
    x: FloatArray, y: FloatArray, var: FloatArray, *, origin: bool, quadratic: bool = False
) -> tuple[FloatArray, FloatArray, float]:
    """Weighted least squares ``y = a + b x`` (or ``b x``, or ``b x + c x^2``): coefficients, covariance, chi2/dof."""
    w = 1.0 / np.maximum(var, 1e-300)
    if quadratic:
        design = np.stack([x, x**2], axis=1)
    else:
        design = x[:, None] if origin else np.stack([np.ones_like(x), x], axis=1)
    normal = design.T @ (design * w[:, None])
    cov = np.linalg.inv(normal)
    coef = cov @ (design.T @ (w * y))
    dof = len(x) - design.shape[1]
    chi2 = float(np.sum(w * (y - design @ coef) ** 2))
    red = chi2 / dof if dof > 0 else 1.0
    # The a-priori weights set the error; a scatter beyond them (model error) widens it, never narrows it.
    return coef, cov * max(1.0, red), red


@dataclass(frozen=True)
class PhotonTransfer:
    """A camera's photon-transfer calibration: values with standard errors, and the points they came from."""

    e_per_dn: Estimate
    read_noise_e: Estimate
    dark_current_e_per_s: Estimate
    black_level_dn: Estimate
    full_well_e: Estimate
    saturation_dn: float
    white_level_dn: float
    linearity_error_percent: float
    points: tuple[PtcPoint, ...]
    gain_points: int
    chi2_gain: float
    notes: tuple[str, ...] = ()
    meta: dict[str, Any] = field(default_factory=dict, compare=False)

    def noise(self) -> SensorNoise:
        """The noise model of the calibrated camera (what the merge and the planner assume)."""
        return SensorNoise(
            e_per_dn=self.e_per_dn.value, read_noise_e=max(self.read_noise_e.value, 0.0),
            dark_current_e_per_s=max(self.dark_current_e_per_s.value, 0.0),
            black_level_dn=max(self.black_level_dn.value, 0.0), white_level_dn=self.white_level_dn,
            full_well_e=self.full_well_e.value,
        )  # fmt: skip

    def as_json(self) -> dict[str, Any]:
        """The calibration as JSON: ``noise`` (the [camera.noise] keys), each value with its error, the points."""
        fits = {k: getattr(self, k).as_dict() for k in
                ("e_per_dn", "read_noise_e", "dark_current_e_per_s", "black_level_dn", "full_well_e")}  # fmt: skip
        return {
            "noise": {k: float(v) for k, v in self.noise().__dict__.items()},
            "parameters": fits,
            "saturation_dn": self.saturation_dn,
            "linearity_error_percent": self.linearity_error_percent,
            "gain_points": self.gain_points,
            "chi2_per_dof_gain": self.chi2_gain,
            "notes": list(self.notes),
            "points": [p.__dict__ for p in self.points],
            **self.meta,
        }


def fit_photon_transfer(points: Sequence[PtcPoint], white_level_dn: float) -> PhotonTransfer:
    """Fit a series of points (see the module doc); ``white_level_dn`` is the frames' white level (counts)."""
    pts = sorted(points, key=lambda p: (p.exposure_s, p.plane))
    if len({p.exposure_s for p in pts}) < 4:
        raise PhotonTransferError(f"{len({p.exposure_s for p in pts})} exposures: photon transfer needs at least 4")
    notes: list[str] = []
    names = sorted({p.plane for p in pts})
    # Saturation: where each plane's variance peaks; the lowest level of the planes that got there is the
    # camera's (a dim colour under a coloured light may not reach it: its peak is only a lower bound).
    sat_per_plane, reached = {}, {}
    for name in names:
        mine = [p for p in pts if p.plane == name]
        peak = max(range(len(mine)), key=lambda i: mine[i].variance_dn2)
        sat_per_plane[name] = mine[peak].signal_dn
        if peak < len(mine) - 1:
            reached[name] = mine[peak].signal_dn
    if reached:
        # Under a vignetted (or any non-uniform) light the mean at the variance peak is below the clip: the
        # brightest pixels clip first and end the rise. The clip level itself is their plateau.
        longest = max(p.exposure_s for p in pts)
        saturation = float(min(p.top_dn for p in pts if p.plane in reached and p.exposure_s == longest))
        sat_per_plane = {n: min(v, saturation) for n, v in sat_per_plane.items()}
    else:
        saturation = float(max(sat_per_plane.values()))
        notes.append("the variance still rises at the longest exposure: saturation not reached, full well is a lower "
                     "bound; lengthen the series")  # fmt: skip
    if not saturation > 0:
        raise PhotonTransferError("no signal above dark: is the light on, and the lens uncapped for the flat frames?")

    # Gain from the shot-noise line.
    use = [p for p in pts if 0 < p.signal_dn <= GAIN_RANGE * sat_per_plane[p.plane]]
    if len(use) < 3:
        raise PhotonTransferError(f"{len(use)} points below {GAIN_RANGE:.0%} of saturation: need at least 3; "
                                  "take more exposures at low signal")  # fmt: skip
    mu = np.array([p.signal_dn for p in use])
    sv = np.array([p.shot_variance_dn2 for p in use])
    vv = np.array([2 * p.variance_dn2**2 / (p.n_pixels - 1) + 2 * p.dark_variance_dn2**2 / (p.n_pixels - 1)
                   for p in use])  # fmt: skip
    # A quadratic term takes up the response's compression towards full well, which bends the line and
    # would bias a straight one (by about 2 % at 2 % non-linearity); the slope at zero signal is the gain.
    coef, cov, chi2 = _line(mu, sv, vv, origin=True, quadratic=len(use) >= 6)
    k, k_se = float(coef[0]), float(math.sqrt(cov[0, 0]))
    if not k > 0:
        raise PhotonTransferError(f"the variance does not grow with the signal (slope {k:.3g} DN): no shot noise?")
    e_per_dn = Estimate(1.0 / k, k_se / k**2)

    # Darks: one line for the mean, one for the variance, over one point per exposure (planes averaged).
    times = np.array(sorted({p.exposure_s for p in pts}))
    dmean = np.array([np.mean([p.dark_mean_dn for p in pts if p.exposure_s == t]) for t in times])
    dvar = np.array([np.mean([p.dark_variance_dn2 for p in pts if p.exposure_s == t]) for t in times])
    npx = np.array([sum(p.n_pixels for p in pts if p.exposure_s == t) for t in times], dtype=float)
    (b0, b1), bcov, _ = _line(times, dmean, dvar / npx, origin=False)
    (v0, _), vcov, _ = _line(times, dvar, 2 * dvar**2 / (npx - 1), origin=False)
    dark_dn_s, dark_dn_s_se = float(b1), float(math.sqrt(bcov[1, 1]))
    dark = Estimate(dark_dn_s * e_per_dn.value,
                    math.hypot(dark_dn_s_se * e_per_dn.value, dark_dn_s * e_per_dn.std_error))  # fmt: skip
    read_dn2 = float(v0) - QUANTISATION_DN2
    if read_dn2 <= 0:
        notes.append("dark variance at zero exposure is at or below quantisation: read noise under a count")
    read_dn = math.sqrt(max(read_dn2, 0.0))
    read_dn_se = math.sqrt(vcov[0, 0]) / (2 * read_dn) if read_dn > 0 else math.sqrt(vcov[0, 0])
    read = Estimate(read_dn * e_per_dn.value, math.hypot(read_dn_se * e_per_dn.value, read_dn * e_per_dn.std_error))
    black = Estimate(float(b0), float(math.sqrt(bcov[0, 0])))
    full_well = Estimate(saturation * e_per_dn.value, saturation * e_per_dn.std_error)

    le = 0.0
    lo, hi = LINEARITY_RANGE
    for name in names:
        mine = [p for p in pts if p.plane == name and lo * saturation <= p.signal_dn <= hi * saturation]
        if len(mine) < 3:
            notes.append(f"plane {name}: {len(mine)} points in {lo:.0%}-{hi:.0%} of saturation; linearity not measured")
            continue
        t = np.array([p.exposure_s for p in mine])
        y = np.array([p.signal_dn for p in mine])
        var_y = np.array([p.variance_dn2 / p.n_pixels for p in mine])
        (a0, a1), _, _ = _line(t, y, var_y, origin=False)
        dev = (y - (a0 + a1 * t)) / (a0 + a1 * t)
        le = max(le, 100.0 * float(dev.max() - dev.min()) / 2.0)
    return PhotonTransfer(
        e_per_dn=e_per_dn, read_noise_e=read, dark_current_e_per_s=dark, black_level_dn=black,
        full_well_e=full_well, saturation_dn=saturation, white_level_dn=float(white_level_dn),
        linearity_error_percent=le, points=tuple(pts), gain_points=len(use), chi2_gain=chi2, notes=tuple(notes),
    )  # fmt: skip
