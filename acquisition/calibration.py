"""Calibration against a Lambertian reference target: ROI readings (counts/s) to BRDF values (1/sr).

Derivation. A camera pixel sees a fixed solid angle of the scene and collects power proportional to the
radiance L_o of the surface it looks at (the footprint of a pixel on the sample grows as 1/cos(theta_o),
its projected area shrinks as cos(theta_o): they cancel). With the sample lit by a point source of
intensity I at distance d (or a collimated beam), the irradiance is E = I cos(theta_i) / d^2 and the
reflected radiance L_o = f_r E. Two ways the ROI and the illuminated spot can relate:

``"roi_in_spot"`` (default; the common case): the ROI lies inside the illuminated spot at every geometry
of the run. The ROI mean reading is R = k f_r I cos(theta_i) / d^2, k the camera's constant (aperture,
pixel solid angle, quantum efficiency, gain), independent of theta_o and of the ROI's size. For the
reference of albedo rho (f_ref = rho / pi) measured with the same light and camera,

    f_r = (R / R_ref) (rho / pi) (cos(theta_i_ref) / cos(theta_i)) (d / d_ref)^2.

The last factor applies to a point source measured at different distances (omit both distances for a
collimated beam, or when the distance does not change).

``"spot_in_roi"``: the whole illuminated spot lies inside the ROI (a beam smaller than the ROI's footprint,
wholly intercepted by the sample). The sample then receives the beam's full power P at every theta_i
(the spot grows as 1/cos(theta_i), the irradiance falls as cos(theta_i)), and the ROI sum, or the mean over
a fixed number of pixels, counts the spot's projected area, which shrinks as cos(theta_o):
R = k' f_r P cos(theta_o), so

    f_r = (R / R_ref) (rho / pi) (cos(theta_o_ref) / cos(theta_o)).

The reading per unit f_r falls as cos(theta_o) (the BRDF scales with 1/cos(theta_o) at fixed reading),
and the ROI must have the same number of pixels for the reference and the samples.

In both modes the detector's solid angle cancels in the ratio (same camera and aperture); it is carried
as metadata (``detector_solid_angle_sr``), as users ask for it. ``includes_cosine=True`` on request
returns f_r cos(theta_i) instead of f_r.

Uncertainty (first order, independent errors):
(sigma_f / f)^2 = (sigma_R / R)^2 + (sigma_Rref / R_ref)^2 + (sigma_rho / rho)^2. ``std_error`` has all
three terms; ``std_error_readings`` leaves out the albedo's, which is common to every sample of a run
(systematic) and should not be counted as independent when samples are compared or fitted together.

Light drift: a second ("closing") reference reading taken after the run lets ``to_brdf(..., time_s=t)``
interpolate the reference linearly in time between the two; its variance is
(1-a)^2 sigma_0^2 + a^2 sigma_1^2 with a = (t - t_0)/(t_1 - t_0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
import numpy.typing as npt

from acquisition.roi import RoiReading
from model.errors import InputError
from model.radiometry import solid_angle_disk

Footprint = Literal["roi_in_spot", "spot_in_roi"]
FloatArray = npt.NDArray[np.float64]


class CalibrationError(InputError, ValueError):
    """A calibration input is out of range, mismatched, or at a geometry where the conversion is unreliable."""


def _per_channel(owner: str, name: str, value: npt.ArrayLike) -> FloatArray:
    arr = np.array(value, dtype=np.float64)
    if arr.ndim > 1 or arr.size == 0:
        raise CalibrationError(f"{owner}.{name} = {value!r}: expected a number or one number per channel")
    if not np.all(np.isfinite(arr)):
        raise CalibrationError(f"{owner}.{name} = {value!r}: expected finite numbers")
    arr.setflags(write=False)
    return arr


def _channels(arr: FloatArray) -> str:
    return "1 value" if arr.ndim == 0 else f"{arr.shape[0]} channels"


def _check_angle(owner: str, name: str, value: float, max_deg: float) -> float:
    v = float(value)
    if not math.isfinite(v) or v < 0 or v >= 90:
        raise CalibrationError(f"{owner}: {name} = {value!r} deg: expected a polar angle in [0, 90) degrees")
    if v > max_deg:
        c = math.cos(math.radians(v))
        raise CalibrationError(
            f"{owner}: {name} = {v:g} deg is beyond max_theta_deg = {max_deg:g} deg: cos = {c:.3g} "
            "amplifies every error of the reading and the angle, and the footprint leaves the spot near grazing"
        )
    return v


def detector_solid_angle(aperture_diameter_m: float, distance_m: float) -> float:
    """Solid angle in sr of the camera's entrance pupil (diameter in metres) seen from the sample at distance_m."""
    if not (aperture_diameter_m > 0 and distance_m > 0):
        raise CalibrationError(
            f"detector_solid_angle: aperture_diameter_m = {aperture_diameter_m!r} and distance_m = {distance_m!r} "
            "must be positive"
        )
    return float(solid_angle_disk(0.5 * aperture_diameter_m, distance_m))


@dataclass(frozen=True)
class MeasurementGeometry:
    """Directions of one reading in degrees: polar angles from the sample normal, azimuths where known."""

    theta_i_deg: float
    theta_o_deg: float
    phi_i_deg: float | None = None
    phi_o_deg: float | None = None


@dataclass(frozen=True, eq=False)
class BrdfSample:
    """A calibrated BRDF value per channel with its uncertainty and what it means.

    Parameters
    ----------
    value:
        f_r in 1/sr (or f_r cos(theta_i) in 1/sr if ``includes_cosine``); shape () or (C,).
    std_error:
        Standard error in 1/sr: both readings and the reference albedo.
    std_error_readings:
        Standard error in 1/sr from the two readings only (the albedo's share is common to the whole run).
    includes_cosine:
        Whether ``value`` includes cos(theta_i).
    detector_solid_angle_sr:
        Solid angle of the camera's pupil from the sample, sr (metadata; it cancels in the calibration).
    geometry:
        The directions of the reading.
    lower_bound:
        The reading was a lower bound (saturated pixels kept): the true value is higher.
    metadata:
        How the reading was converted: mode, formula, reference reading used, albedo, reference geometry.
    """

    value: FloatArray
    std_error: FloatArray
    std_error_readings: FloatArray
    includes_cosine: bool
    detector_solid_angle_sr: float | None
    geometry: MeasurementGeometry
    lower_bound: bool = False
    metadata: dict[str, object] = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class ReferenceCalibration:
    """A reading of a Lambertian reference target and what is needed to turn sample readings into BRDF.

    Parameters
    ----------
    reading:
        Mean ROI reading of the reference, counts/s above black, > 0; a number or one per channel.
    reading_std_error:
        Its standard error, counts/s.
    albedo:
        Directional-hemispherical reflectance of the reference (e.g. 0.99 for Spectralon), in (0, 1];
        a number or one per channel.
    albedo_std_error:
        Its standard uncertainty (from the certificate).
    theta_i_deg, theta_o_deg:
        Geometry of the reference reading, degrees.
    light_distance_m:
        Distance light to sample for the reference reading (point source; None for a collimated beam).
    footprint:
        ``"roi_in_spot"`` or ``"spot_in_roi"``; see the module doc.
    time_s:
        When the reference was read (for drift correction), seconds on the run's clock.
    closing_reading, closing_std_error, closing_time_s:
        A second reference reading (counts/s) at the same geometry after the run, for drift correction.
    n_pixels:
        ROI size of the reference reading (checked against samples in ``"spot_in_roi"`` mode).
    detector_solid_angle_sr:
        Camera pupil's solid angle from the sample, sr (metadata).
    max_theta_deg:
        Polar angles beyond this are refused (grazing: cos -> 0 amplifies errors).
    description:
        Light and detector details for the record (source, filters, lens, aperture).
    """

    reading: FloatArray
    reading_std_error: FloatArray
    albedo: FloatArray
    albedo_std_error: FloatArray
    theta_i_deg: float
    theta_o_deg: float
    light_distance_m: float | None = None
    footprint: Footprint = "roi_in_spot"
    time_s: float | None = None
    closing_reading: FloatArray | None = None
    closing_std_error: FloatArray | None = None
    closing_time_s: float | None = None
    n_pixels: int | None = None
    detector_solid_angle_sr: float | None = None
    max_theta_deg: float = 85.0
    description: str = ""

    def __post_init__(self) -> None:
        own = "ReferenceCalibration"
        if not (0 < self.max_theta_deg < 90):
            raise CalibrationError(f"{own}.max_theta_deg = {self.max_theta_deg!r}: expected (0, 90) degrees")
        if self.footprint not in ("roi_in_spot", "spot_in_roi"):
            raise CalibrationError(f"{own}.footprint = {self.footprint!r}: expected 'roi_in_spot' or 'spot_in_roi'")
        reading = _per_channel(own, "reading", self.reading)
        se = _per_channel(own, "reading_std_error", self.reading_std_error)
        albedo = _per_channel(own, "albedo", self.albedo)
        albedo_se = _per_channel(own, "albedo_std_error", self.albedo_std_error)
        if np.any(reading <= 0):
            raise CalibrationError(f"{own}.reading = {self.reading!r} counts/s: the reference must read > 0 "
                                   "(check exposure, dark subtraction and the ROI)")
        if se.shape not in ((), reading.shape) or np.any(se < 0):
            raise CalibrationError(f"{own}.reading_std_error = {self.reading_std_error!r}: expected >= 0 with "
                                   f"the reading's shape ({_channels(reading)})")
        if albedo.shape not in ((), reading.shape):
            raise CalibrationError(f"{own}.albedo has {_channels(albedo)} but reading has {_channels(reading)}")
        if np.any(albedo <= 0) or np.any(albedo > 1):
            raise CalibrationError(f"{own}.albedo = {self.albedo!r}: expected a reflectance in (0, 1]")
        if albedo_se.shape not in ((), albedo.shape, reading.shape) or np.any(albedo_se < 0):
            raise CalibrationError(f"{own}.albedo_std_error = {self.albedo_std_error!r}: expected >= 0 with "
                                   f"the albedo's shape ({_channels(albedo)})")
        for key, val in (("reading", reading), ("reading_std_error", se), ("albedo", albedo),
                         ("albedo_std_error", albedo_se)):
            object.__setattr__(self, key, val)
        _check_angle(own, "theta_i_deg", self.theta_i_deg, self.max_theta_deg)
        _check_angle(own, "theta_o_deg", self.theta_o_deg, self.max_theta_deg)
        d = self.light_distance_m
        if d is not None and not (math.isfinite(d) and d > 0):
            raise CalibrationError(f"{own}.light_distance_m = {self.light_distance_m!r}: expected > 0 metres or None")
        if self.closing_reading is not None:
            closing = _per_channel(own, "closing_reading", self.closing_reading)
            if closing.shape != reading.shape:
                raise CalibrationError(
                    f"{own}.closing_reading has {_channels(closing)} but reading has {_channels(reading)}"
                )
            if np.any(closing <= 0):
                raise CalibrationError(f"{own}.closing_reading = {self.closing_reading!r} counts/s: expected > 0")
            cse = _per_channel(own, "closing_std_error", 0.0 if self.closing_std_error is None
                               else self.closing_std_error)
            if cse.shape not in ((), reading.shape) or np.any(cse < 0):
                raise CalibrationError(f"{own}.closing_std_error = {self.closing_std_error!r}: expected >= 0")
            if self.time_s is None or self.closing_time_s is None or not self.closing_time_s > self.time_s:
                raise CalibrationError(
                    f"{own}: a closing reading needs time_s and a later closing_time_s, got time_s = {self.time_s!r}, "
                    f"closing_time_s = {self.closing_time_s!r}"
                )
            object.__setattr__(self, "closing_reading", closing)
            object.__setattr__(self, "closing_std_error", cse)

    @classmethod
    def from_roi(
        cls,
        reading: RoiReading,
        albedo: npt.ArrayLike,
        theta_i_deg: float,
        theta_o_deg: float,
        *,
        albedo_std_error: npt.ArrayLike = 0.0,
        **kwargs: object,
    ) -> ReferenceCalibration:
        """A calibration from an ROI reading (counts/s) of the reference; other fields as keyword arguments."""
        if reading.lower_bound:
            raise CalibrationError("the reference reading is a lower bound (saturated pixels): retake it shorter")
        return cls(reading.mean, reading.std_error, np.asarray(albedo, dtype=float),
                   np.asarray(albedo_std_error, dtype=float), theta_i_deg, theta_o_deg,
                   n_pixels=reading.n_pixels, **kwargs)  # type: ignore[arg-type]

    def with_closing_reading(
        self, reading: npt.ArrayLike | RoiReading, std_error: npt.ArrayLike = 0.0, *, time_s: float
    ) -> ReferenceCalibration:
        """This calibration with a second reference reading (counts/s) at ``time_s`` seconds, for drift."""
        if isinstance(reading, RoiReading):
            value, se = reading.mean, reading.std_error
        else:
            value, se = np.asarray(reading, dtype=float), np.asarray(std_error, dtype=float)
        return replace(self, closing_reading=value, closing_std_error=se, closing_time_s=time_s)

    def reference_at(self, time_s: float | None = None) -> tuple[FloatArray, FloatArray]:
        """Reference reading and its standard error in counts/s at ``time_s`` (interpolated if there is drift)."""
        if self.closing_reading is None or time_s is None:
            return self.reading, np.broadcast_to(self.reading_std_error, self.reading.shape)
        t0, t1 = float(self.time_s), float(self.closing_time_s)  # type: ignore[arg-type]
        if not (t0 <= time_s <= t1):
            raise CalibrationError(
                f"time_s = {time_s!r} is outside the reference readings' span [{t0:g}, {t1:g}] s: "
                "drift is interpolated, never extrapolated"
            )
        a = (time_s - t0) / (t1 - t0)
        value = (1 - a) * self.reading + a * self.closing_reading
        c_se = self.closing_std_error if self.closing_std_error is not None else 0.0
        se = np.sqrt(((1 - a) * self.reading_std_error) ** 2 + (a * c_se) ** 2)
        return np.asarray(value, dtype=np.float64), np.broadcast_to(se, self.reading.shape).astype(np.float64)

    def to_brdf(
        self,
        reading: RoiReading | npt.ArrayLike,
        theta_i_deg: float,
        theta_o_deg: float,
        *,
        std_error: npt.ArrayLike | None = None,
        time_s: float | None = None,
        light_distance_m: float | None = None,
        include_cosine: bool = False,
        phi_i_deg: float | None = None,
        phi_o_deg: float | None = None,
    ) -> BrdfSample:
        """BRDF in 1/sr of a sample reading (counts/s, RoiReading or value + ``std_error``) at angles in degrees."""
        own = "to_brdf"
        lower = False
        n_pix: int | None = None
        if isinstance(reading, RoiReading):
            value, se = reading.mean, reading.std_error
            lower, n_pix = reading.lower_bound, reading.n_pixels
        else:
            value = _per_channel(own, "reading", reading)
            se = _per_channel(own, "std_error", 0.0 if std_error is None else std_error)
        if not np.all(np.isfinite(value)) or not np.all(np.isfinite(se)) or np.any(se < 0):
            raise CalibrationError(f"{own}: reading {value!r} +- {se!r} counts/s: expected finite, error >= 0")
        if value.shape != self.reading.shape:
            raise CalibrationError(
                f"{own}: the reading has {_channels(value)} but the reference reading has {_channels(self.reading)}"
            )
        ti = _check_angle(own, "theta_i_deg", theta_i_deg, self.max_theta_deg)
        to = _check_angle(own, "theta_o_deg", theta_o_deg, self.max_theta_deg)
        ref, ref_se = self.reference_at(time_s)
        cos = math.cos
        if self.footprint == "roi_in_spot":
            geo = cos(math.radians(self.theta_i_deg)) / cos(math.radians(ti))
            formula = "f = (R / R_ref) (rho / pi) cos(theta_i_ref) / cos(theta_i)"
            if light_distance_m is not None:
                if self.light_distance_m is None:
                    raise CalibrationError(
                        f"{own}: light_distance_m = {light_distance_m!r} given but the reference has no light distance"
                    )
                if not (math.isfinite(light_distance_m) and light_distance_m > 0):
                    raise CalibrationError(f"{own}: light_distance_m = {light_distance_m!r}: expected > 0 metres")
                geo *= (light_distance_m / self.light_distance_m) ** 2
                formula += " (d / d_ref)^2"
        else:
            if n_pix is not None and self.n_pixels is not None and n_pix != self.n_pixels:
                raise CalibrationError(
                    f"{own}: footprint 'spot_in_roi' needs equal ROIs, but the reading has {n_pix} pixels and the "
                    f"reference {self.n_pixels}"
                )
            geo = cos(math.radians(self.theta_o_deg)) / cos(math.radians(to))
            formula = "f = (R / R_ref) (rho / pi) cos(theta_o_ref) / cos(theta_o)"
        if include_cosine:
            geo *= cos(math.radians(ti))
            formula += " x cos(theta_i)"
        f = value / ref * (self.albedo / math.pi) * geo
        # Relative terms times |f| would vanish for a zero reading; write the reading's term absolutely.
        scale = (self.albedo / math.pi) * geo / ref
        var_read = (scale * se) ** 2 + (f * ref_se / ref) ** 2
        var_alb = (f * self.albedo_std_error / self.albedo) ** 2
        return BrdfSample(
            value=np.asarray(f, dtype=np.float64),
            std_error=np.asarray(np.sqrt(var_read + var_alb), dtype=np.float64),
            std_error_readings=np.asarray(np.sqrt(var_read), dtype=np.float64),
            includes_cosine=include_cosine,
            detector_solid_angle_sr=self.detector_solid_angle_sr,
            geometry=MeasurementGeometry(ti, to, phi_i_deg, phi_o_deg),
            lower_bound=lower,
            metadata={
                "method": "ratio to a Lambertian reference",
                "footprint": self.footprint,
                "formula": formula,
                "reference_reading_dn_per_s": ref.tolist(),
                "reference_std_error_dn_per_s": np.asarray(ref_se).tolist(),
                "reference_albedo": self.albedo.tolist(),
                "reference_albedo_std_error": self.albedo_std_error.tolist(),
                "reference_theta_i_deg": self.theta_i_deg,
                "reference_theta_o_deg": self.theta_o_deg,
                "drift_corrected": self.closing_reading is not None and time_s is not None,
                "description": self.description,
            },
        )
