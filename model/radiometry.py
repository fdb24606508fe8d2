"""Radiometry of one measurement: solid angles, lights, irradiance and reflected radiance.

Units: lengths in metres, angles in radians, solid angle in sr, intensity in W/sr (or any
"camera units"/sr: everything here is linear), irradiance in W/m^2, radiance in W/(m^2 sr).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from model._params import Channel, channel, scalar

Array = npt.NDArray[np.floating]


def solid_angle_disk(radius: npt.ArrayLike, distance: npt.ArrayLike) -> Array:
    """Solid angle in sr of a disk of radius r seen on-axis from distance d: 2 pi (1 - d / sqrt(d^2 + r^2))."""
    r = np.asarray(radius, dtype=float)
    d = np.asarray(distance, dtype=float)
    # 2 pi r^2 / (sqrt(d^2 + r^2)(sqrt(d^2 + r^2) + d)) is the same without cancellation for r << d.
    s = np.hypot(d, r)
    return 2.0 * np.pi * r * r / (s * (s + d))


def solid_angle_rectangle(width: npt.ArrayLike, height: npt.ArrayLike, distance: npt.ArrayLike) -> Array:
    """Solid angle in sr of a w x h rectangle seen on-axis from its centre normal at distance d."""
    a = 0.5 * np.asarray(width, dtype=float)
    b = 0.5 * np.asarray(height, dtype=float)
    d = np.asarray(distance, dtype=float)
    return 4.0 * np.arcsin(a * b / np.sqrt((a * a + d * d) * (b * b + d * d)))


def irradiance_point(intensity: npt.ArrayLike, distance: npt.ArrayLike, cos_i: npt.ArrayLike) -> Array:
    """Irradiance in W/m^2 from a point source of intensity I (W/sr) at distance d: I cos_i / d^2."""
    d = np.asarray(distance, dtype=float)
    return np.asarray(intensity, dtype=float) * np.maximum(np.asarray(cos_i, dtype=float), 0.0) / (d * d)


@dataclass(frozen=True)
class PointLight:
    """An isotropic point source on the light arm.

    Parameters:
        intensity: radiant intensity in W/sr (or camera units/sr), > 0, scalar or per channel.
        distance: distance from the sample centre in metres, > 0.
    """

    intensity: Channel = 1.0
    distance: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "intensity", channel("PointLight", "intensity", self.intensity, 0.0, np.inf))
        object.__setattr__(
            self, "distance", scalar("PointLight", "distance", self.distance, 0.0, np.inf, lo_open=True)
        )

    def intensity_at(self, off_axis: npt.ArrayLike) -> Array:
        """Intensity in W/sr towards a direction off_axis radians from the beam axis (isotropic)."""
        return np.broadcast_to(np.asarray(self.intensity, dtype=float), np.shape(off_axis) + np.shape(self.intensity))

    def irradiance(self, cos_i: npt.ArrayLike, off_axis: npt.ArrayLike = 0.0) -> Array:
        """Irradiance in W/m^2 at the sample centre for incidence cosine cos_i (channels last)."""
        c = np.asarray(cos_i, dtype=float)
        i = self.intensity_at(off_axis)
        if np.ndim(self.intensity):
            c = c[..., None]
        return i * np.maximum(c, 0.0) / (self.distance * self.distance)


@dataclass(frozen=True)
class SpotLight(PointLight):
    """A spot light: full intensity within beam_width, falling linearly in angle to 0 at cutoff (Mitsuba 3's spot).

    Parameters:
        beam_width: half-angle of full intensity in radians, (0, cutoff].
        cutoff: half-angle beyond which no light leaves, radians, (0, pi/2].
    """

    beam_width: float = np.radians(15.0)
    cutoff: float = np.radians(20.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "cutoff", scalar("SpotLight", "cutoff", self.cutoff, 0.0, np.pi / 2, lo_open=True))
        object.__setattr__(
            self, "beam_width", scalar("SpotLight", "beam_width", self.beam_width, 0.0, self.cutoff, lo_open=True)
        )

    def intensity_at(self, off_axis: npt.ArrayLike) -> Array:
        """Intensity in W/sr at off_axis radians: full inside the beam, linear in angle to 0 at the cutoff."""
        a = np.asarray(off_axis, dtype=float)
        if self.cutoff > self.beam_width:
            t = np.clip((self.cutoff - a) / (self.cutoff - self.beam_width), 0.0, 1.0)
        else:
            t = (a <= self.cutoff).astype(float)
        # Mitsuba 3.9's spot falls off linearly in angle (measured: beam 10, cutoff 20 deg gives 0.75 at 12.5 deg).
        return np.multiply.outer(t, np.asarray(self.intensity, dtype=float))


def reflected_radiance(brdf_value: npt.ArrayLike, irradiance: npt.ArrayLike) -> Array:
    """Radiance in W/(m^2 sr) reflected towards the camera: L = f_r E for a collimated/point source."""
    return np.asarray(brdf_value, dtype=float) * np.asarray(irradiance, dtype=float)
