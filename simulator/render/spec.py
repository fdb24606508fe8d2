"""What the rendered scene needs beyond the rig geometry: the light, the camera, pixel boxes, materials.

Pixels: (x, y) with x to the right and y down, pixel (i, j) covering [i, i + 1) x [j, j + 1); boxes are
(x0, y0, x1, y1) with x1, y1 exclusive, as Mitsuba's film crop.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal, Protocol

import numpy as np

from rig.instrument.geometry import RigGeometry

Box = tuple[int, int, int, int]
"""A pixel box (x0, y0, x1, y1), x1 and y1 exclusive."""


class SupportsToDict(Protocol):
    """A material that gives its Mitsuba BSDF dict (``model.mitsuba.materials.MitsubaMaterial``)."""

    def to_dict(self) -> dict[str, Any]:
        """The Mitsuba BSDF dict."""
        ...


BSDFLike = Mapping[str, Any] | SupportsToDict


@dataclass(frozen=True)
class LightSpec:
    """The light on the light arm: kind, intensity in W/sr, and for a spot its cone in degrees.

    intensity: radiant intensity in W/sr (on the beam axis for a spot), one float or an RGB triple.
    cutoff_deg: spot only; no light beyond this half-angle. None: ``RigGeometry.beam_half_angle_deg``.
    beam_width_deg: spot only; full intensity within this half-angle, falling linearly in angle to 0 at
        the cutoff (Mitsuba's spot). None: 3/4 of the cutoff, Mitsuba's default.
    size_m: point only; the diameter (m) of a disk source in place of a point (0: a point).
    falloff: the fraction by which the irradiance falls at the edge of the lit spot (``edge_deg``),
        quadratically in the angle off the beam's axis (0: uniform); applied by ``RadianceRenderer``.
    """

    kind: Literal["point", "spot"] = "point"
    intensity: float | tuple[float, float, float] = 1.0
    cutoff_deg: float | None = None
    beam_width_deg: float | None = None
    size_m: float = 0.0
    falloff: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in ("point", "spot"):
            raise ValueError(f"LightSpec.kind = {self.kind!r}, expected 'point' or 'spot'")
        rgb = np.asarray(self.intensity, dtype=np.float64).reshape(-1)
        if rgb.size not in (1, 3) or not np.all(np.isfinite(rgb)) or np.any(rgb < 0):
            raise ValueError(f"LightSpec.intensity = {self.intensity!r} W/sr, expected one or three finite values >= 0")
        # Plain floats and tuples keep the spec hashable (it is part of render cache keys).
        value = float(rgb[0]) if np.ndim(self.intensity) == 0 else (float(rgb[0]), float(rgb[1]), float(rgb[2]))
        object.__setattr__(self, "intensity", value)
        for name in ("cutoff_deg", "beam_width_deg"):
            value = getattr(self, name)
            if value is not None and not 0.0 < value <= 90.0:
                raise ValueError(f"LightSpec.{name} = {value!r} deg, expected a value in (0, 90]")
        if not (np.isfinite(self.size_m) and 0.0 <= self.size_m <= 0.2):
            raise ValueError(f"LightSpec.size_m = {self.size_m!r} m, expected a disk diameter in [0, 0.2]")
        if self.size_m > 0 and self.kind != "point":
            raise ValueError("LightSpec.size_m: only a point light can be given a size (a disk source)")
        if not (np.isfinite(self.falloff) and 0.0 <= self.falloff < 1.0):
            raise ValueError(f"LightSpec.falloff = {self.falloff!r}, expected a fraction in [0, 1)")

    def rgb(self) -> tuple[float, float, float]:
        """Intensity in W/sr per RGB channel."""
        v = np.broadcast_to(np.asarray(self.intensity, dtype=np.float64).reshape(-1), (3,))
        return (float(v[0]), float(v[1]), float(v[2]))

    def edge_deg(self, geometry: RigGeometry) -> float:
        """Half-angle (deg) of the lit spot: a spot's cutoff; for a point light the sample's half width."""
        if self.kind == "spot":
            return self.cone_deg(geometry)[1]
        return math.degrees(math.atan2(0.5 * geometry.sample_width_m, geometry.light_radius_m))

    def cone_deg(self, geometry: RigGeometry) -> tuple[float, float]:
        """The spot's (beam_width, cutoff) half-angles in degrees, defaults filled in from the rig."""
        cutoff = geometry.beam_half_angle_deg if self.cutoff_deg is None else self.cutoff_deg
        beam = 0.75 * cutoff if self.beam_width_deg is None else self.beam_width_deg
        if beam > cutoff:
            raise ValueError(f"spot beam width {beam:g} deg exceeds its cutoff {cutoff:g} deg")
        return beam, cutoff


@dataclass(frozen=True)
class CameraSpec:
    """The simulated camera: image size, field of view, region of interest and render samples.

    resolution: (width, height) in pixels.
    fov_deg: full field of view in degrees along ``fov_axis``; None: ``RigGeometry.camera_fov_deg``.
    fov_axis: Mitsuba's ``fov_axis`` ("x", "y", "smaller", "larger", "diagonal").
    roi: the ROI as a pixel box; None: computed per pose by ``default_roi``.
    roi_fraction: area fraction of the sample (of the spot's full-intensity disk for a spot light) that a
        default ROI may cover, centred on the sample centre.
    spp: samples per pixel. sampler: "independent" or "stratified" (Mitsuba rounds spp up to a square).
    seed: sampler seed. variant: preferred Mitsuba variant (falls back; see ``model.mitsuba.variant``).
    """

    resolution: tuple[int, int] = (64, 64)
    fov_deg: float | None = None
    fov_axis: Literal["x", "y", "smaller", "larger", "diagonal"] = "smaller"
    roi: Box | None = None
    roi_fraction: float = 0.25
    spp: int = 4
    sampler: Literal["independent", "stratified"] = "independent"
    seed: int = 0
    variant: str | None = None

    def __post_init__(self) -> None:
        if len(self.resolution) != 2 or not all(isinstance(v, int | np.integer) and v > 0 for v in self.resolution):
            raise ValueError(f"CameraSpec.resolution = {self.resolution!r}, expected two positive ints (pixels)")
        # Tuples of ints keep the spec hashable (it is part of render cache keys).
        object.__setattr__(self, "resolution", (int(self.resolution[0]), int(self.resolution[1])))
        if self.fov_deg is not None and not 0.0 < self.fov_deg < 180.0:
            raise ValueError(f"CameraSpec.fov_deg = {self.fov_deg!r} deg, expected a value in (0, 180)")
        if self.fov_axis not in ("x", "y", "smaller", "larger", "diagonal"):
            raise ValueError(f"CameraSpec.fov_axis = {self.fov_axis!r} is not a Mitsuba fov_axis")
        if self.roi is not None:
            object.__setattr__(self, "roi", check_box(self.roi, self.resolution, "CameraSpec.roi"))
        if not 0.0 < self.roi_fraction <= 1.0:
            raise ValueError(f"CameraSpec.roi_fraction = {self.roi_fraction!r}, expected a value in (0, 1]")
        if not (isinstance(self.spp, int) and self.spp >= 1):
            raise ValueError(f"CameraSpec.spp = {self.spp!r}, expected an int >= 1")
        if self.sampler not in ("independent", "stratified"):
            raise ValueError(f"CameraSpec.sampler = {self.sampler!r}, expected 'independent' or 'stratified'")

    def fov(self, geometry: RigGeometry) -> float:
        """Full field of view in degrees along ``fov_axis``."""
        return geometry.camera_fov_deg if self.fov_deg is None else self.fov_deg


def check_box(box: Box, resolution: tuple[int, int], what: str = "box") -> Box:
    """Validate a pixel box (x0, y0, x1, y1) against a (width, height) image; returns it as ints."""
    if len(box) != 4 or not all(isinstance(v, int | np.integer) for v in box):
        raise ValueError(f"{what} = {box!r}, expected four ints (x0, y0, x1, y1)")
    x0, y0, x1, y1 = (int(v) for v in box)
    w, h = resolution
    if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
        raise ValueError(f"{what} = {box!r} is empty or outside the {w}x{h} image")
    return x0, y0, x1, y1


def bsdf_dict(bsdf: BSDFLike) -> dict[str, Any]:
    """A Mitsuba BSDF dict from a dict or an object with ``to_dict()`` (a copy: the caller's is untouched)."""
    if isinstance(bsdf, Mapping):
        return dict(bsdf)
    return dict(bsdf.to_dict())
