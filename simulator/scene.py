"""The Mitsuba 3 scene of the rig at one pose: the sample, one light and the camera, nothing else.

World frame and units are those of ``rig.kinematics`` (metres, sample centre at the origin, z up along
the arm axis). What is modelled, and what is not ("model only what the scene requires"):

- The sample is a ``rectangle`` of the rig's sample size. Its ``to_world`` maps local x to
  ``pose.sample_tangent``, y to ``pose.sample_bitangent`` and z to ``pose.sample_normal``, centred at
  ``pose.sample_centre_m``. Mitsuba builds the BSDF's shading frame from the same axes (s along local x),
  so the BSDF local frame is the kinematics' local frame: phi angles and anisotropic materials agree.
  The rectangle is one-sided for ordinary BSDFs: seen or lit from behind it renders black.
- One light at ``pose.light_position_m``: an isotropic ``point`` emitter, or a ``spot`` aimed at the
  sample centre. Both are delta lights.
- A ``perspective`` camera at ``pose.camera_position_m`` looking at the sample centre (image up is the
  world +z, the arm axis, unless the view is nearly vertical). The rig's ``camera_fov_deg`` is a cone;
  by default it spans the image's smaller side (``fov_axis="smaller"``), so the circle of
  ``RigGeometry.view_radius_m`` lies inside the image.
- No environment light, no sample holder, no arms, no back side of the sample, no interreflection: a flat
  sample under one light needs direct lighting only, so the integrator is ``direct``. Light from a delta
  emitter can only be reached by emitter sampling (a BSDF-sampled ray never hits a point), so
  ``bsdf_samples`` is 0 and one ``emitter_samples`` is exact; spp then only antialiases (sub-pixel
  positions), which matters at the sample's edges and for textured materials. A smooth (delta) BSDF, such
  as ``conductor``, renders black: a mirror shows a point light at a single point only.

Pixels: (x, y) with x to the right and y down, pixel (i, j) covering [i, i + 1) x [j, j + 1); boxes are
(x0, y0, x1, y1) with x1, y1 exclusive, as Mitsuba's film crop.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal, Protocol

import mitsuba.scalar_rgb as mis  # variant-free scalar types; the transforms load under any variant
import numpy as np
import numpy.typing as npt

from rig.geometry import RigGeometry
from rig.kinematics_types import RigPose

FloatArray = npt.NDArray[np.float64]
Box = tuple[int, int, int, int]
"""A pixel box (x0, y0, x1, y1), x1 and y1 exclusive."""

#: Cosine of the angle between the view direction and world z above which world z cannot serve as up.
_UP_DEGENERATE_COS = 0.999


class SupportsToDict(Protocol):
    """A material that gives its Mitsuba BSDF dict (``simulator.materials.MitsubaMaterial``)."""

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
    """

    kind: Literal["point", "spot"] = "point"
    intensity: float | tuple[float, float, float] = 1.0
    cutoff_deg: float | None = None
    beam_width_deg: float | None = None

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

    def rgb(self) -> tuple[float, float, float]:
        """Intensity in W/sr per RGB channel."""
        v = np.broadcast_to(np.asarray(self.intensity, dtype=np.float64).reshape(-1), (3,))
        return (float(v[0]), float(v[1]), float(v[2]))

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
    seed: sampler seed. variant: preferred Mitsuba variant (falls back; see ``simulator.mitsuba_variant``).
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


def _vec3(name: str, value: npt.ArrayLike) -> FloatArray:
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"pose.{name} = {value!r}, expected one finite 3-vector (a single pose, not a batch)")
    return a


def _unit(v: FloatArray) -> FloatArray:
    out: FloatArray = v / np.linalg.norm(v)
    return out


@dataclass(frozen=True)
class CameraView:
    """The pinhole camera Mitsuba's ``perspective`` sensor implements, in world metres and pixels.

    ``left``/``up``/``forward`` are the columns of Mitsuba's ``look_at``; image x grows towards -left and
    image y towards -up, and ``focal_px`` is the focal length in pixels (square pixels).
    """

    origin: FloatArray
    forward: FloatArray
    left: FloatArray
    up: FloatArray
    focal_px: float
    width: int
    height: int

    def project(self, points_m: npt.ArrayLike) -> FloatArray:
        """Continuous pixel coordinates (..., 2) of world points (..., 3) in metres (in front of the camera)."""
        d = np.asarray(points_m, dtype=np.float64) - self.origin
        z = d @ self.forward
        x = 0.5 * self.width - self.focal_px * (d @ self.left) / z
        y = 0.5 * self.height - self.focal_px * (d @ self.up) / z
        return np.stack([x, y], axis=-1)

    def ray(self, px: npt.ArrayLike, py: npt.ArrayLike) -> FloatArray:
        """Unit world directions (..., 3) of the rays through continuous pixel coordinates."""
        a = (0.5 * self.width - np.asarray(px, dtype=np.float64))[..., None]
        b = (0.5 * self.height - np.asarray(py, dtype=np.float64))[..., None]
        d = self.focal_px * self.forward + a * self.left + b * self.up
        out: FloatArray = d / np.linalg.norm(d, axis=-1, keepdims=True)
        return out


def _up_for(forward: FloatArray) -> FloatArray:
    """World z, the arm axis, unless the view is nearly vertical; then world x (a top-down view)."""
    z = np.array([0.0, 0.0, 1.0])
    return z if abs(float(forward @ z)) < _UP_DEGENERATE_COS else np.array([1.0, 0.0, 0.0])


def camera_view(geometry: RigGeometry, pose: RigPose, camera: CameraSpec) -> CameraView:
    """The camera of ``build_scene`` as a numpy pinhole model: where world points land in the image."""
    origin = _vec3("camera_position_m", pose.camera_position_m)
    target = _vec3("sample_centre_m", pose.sample_centre_m)
    forward = _unit(target - origin)
    left = _unit(np.cross(_up_for(forward), forward))
    up = np.cross(forward, left)
    w, h = camera.resolution
    size = {"x": w, "y": h, "smaller": min(w, h), "larger": max(w, h), "diagonal": math.hypot(w, h)}
    focal = 0.5 * size[camera.fov_axis] / math.tan(math.radians(0.5 * camera.fov(geometry)))
    return CameraView(origin, forward, left, up, focal, w, h)


def pixel_on_sample(view: CameraView, pose: RigPose, px: npt.ArrayLike, py: npt.ArrayLike) -> tuple[FloatArray, ...]:
    """Where pixel rays meet the sample plane: world points (..., 3) and local (u, v) in metres (..., 2).

    u runs along the tangent and v along the bitangent; rays parallel to the plane or meeting it behind
    the camera give NaN. Whether (u, v) lies on the sample is for the caller to test against its size.
    """
    centre = _vec3("sample_centre_m", pose.sample_centre_m)
    n = _vec3("sample_normal", pose.sample_normal)
    d = view.ray(px, py)
    denom = d @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = ((centre - view.origin) @ n) / denom
    t = np.where((np.abs(denom) > 1e-12) & (t > 0), t, np.nan)
    p = view.origin + t[..., None] * d
    q = p - centre
    tangent = _vec3("sample_tangent", pose.sample_tangent)
    bitangent = _vec3("sample_bitangent", pose.sample_bitangent)
    uv = np.stack([q @ tangent, q @ bitangent], axis=-1)
    return p, uv


def _roi_mask(
    geometry: RigGeometry, pose: RigPose, light: LightSpec, camera: CameraSpec
) -> tuple[npt.NDArray[np.bool_], int, int]:
    """Pixels whose centre sees the central ``roi_fraction`` of the sample (and of a spot); window origin.

    Only the window around the region's projection is computed (it is convex, so its image lies within
    the bounding box of its projected corners): a full 2048 x 1536 frame would cost about a second.
    """
    view = camera_view(geometry, pose, camera)
    centre = _vec3("sample_centre_m", pose.sample_centre_m)
    k = math.sqrt(camera.roi_fraction)  # area fraction -> linear fraction
    half = (0.5 * k * geometry.sample_width_m, 0.5 * k * geometry.sample_height_m)
    corners = [centre + su * half[0] * _vec3("sample_tangent", pose.sample_tangent)
               + sv * half[1] * _vec3("sample_bitangent", pose.sample_bitangent)
               for su in (-1.0, 1.0) for sv in (-1.0, 1.0)]
    pix = view.project(np.array(corners))
    x0 = max(0, min(int(np.floor(pix[:, 0].min())) - 1, (view.width - 1) // 2))
    x1 = min(view.width, max(int(np.ceil(pix[:, 0].max())) + 1, view.width // 2 + 1))
    y0 = max(0, min(int(np.floor(pix[:, 1].min())) - 1, (view.height - 1) // 2))
    y1 = min(view.height, max(int(np.ceil(pix[:, 1].max())) + 1, view.height // 2 + 1))
    py, px = np.mgrid[y0:y1, x0:x1] + 0.5
    p, uv = pixel_on_sample(view, pose, px, py)
    with np.errstate(invalid="ignore"):
        mask = (np.abs(uv[..., 0]) <= half[0]) & (np.abs(uv[..., 1]) <= half[1])
        if light.kind == "spot":
            src = _vec3("light_position_m", pose.light_position_m)
            axis = _unit(centre - src)
            to_p = p - src
            cos_off = (to_p @ axis) / np.linalg.norm(to_p, axis=-1)
            beam, _ = light.cone_deg(geometry)
            mask &= cos_off >= math.cos(math.radians(k * beam))
    return mask, x0, y0


def default_roi(geometry: RigGeometry, pose: RigPose, light: LightSpec, camera: CameraSpec) -> Box:
    """The largest centred pixel box whose pixel centres all see the sample's central ``roi_fraction``.

    The box is grown about the image centre (where the sample centre projects) one pixel a side at a
    time, alternating x and y, while it stays inside the mask; it is at least the central 1-2 pixels
    even when those miss the region (a grazing view at low resolution).
    """
    mask, ox, oy = _roi_mask(geometry, pose, light, camera)
    h, w = mask.shape
    area = np.zeros((h + 1, w + 1), dtype=np.int64)
    area[1:, 1:] = np.cumsum(np.cumsum(mask, axis=0), axis=1)

    def inside(x0: int, y0: int, x1: int, y1: int) -> bool:
        x0, x1, y0, y1 = x0 - ox, x1 - ox, y0 - oy, y1 - oy
        if x0 < 0 or y0 < 0 or x1 > w or y1 > h:
            return False
        count = area[y1, x1] - area[y0, x1] - area[y1, x0] + area[y0, x0]
        return bool(count == (x1 - x0) * (y1 - y0))

    width, height = camera.resolution
    x0, x1 = (width - 1) // 2, width // 2 + 1
    y0, y1 = (height - 1) // 2, height // 2 + 1
    grow = [True, True]
    while any(grow):
        if grow[0]:
            grow[0] = inside(x0 - 1, y0, x1 + 1, y1)
            if grow[0]:
                x0, x1 = x0 - 1, x1 + 1
        if grow[1]:
            grow[1] = inside(x0, y0 - 1, x1, y1 + 1)
            if grow[1]:
                y0, y1 = y0 - 1, y1 + 1
    return x0, y0, x1, y1


def roi_box(geometry: RigGeometry, pose: RigPose, light: LightSpec, camera: CameraSpec) -> Box:
    """The camera's ROI: ``camera.roi`` if given, else ``default_roi`` for this pose."""
    return camera.roi if camera.roi is not None else default_roi(geometry, pose, light, camera)


def bsdf_dict(bsdf: BSDFLike) -> dict[str, Any]:
    """A Mitsuba BSDF dict from a dict or an object with ``to_dict()`` (a copy: the caller's is untouched)."""
    if isinstance(bsdf, Mapping):
        return dict(bsdf)
    return dict(bsdf.to_dict())


def _transform(matrix: FloatArray) -> Any:
    return mis.ScalarTransform4f(np.asarray(matrix, dtype=np.float64))


def _look_at(origin: FloatArray, forward: FloatArray, left: FloatArray, up: FloatArray) -> Any:
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, up, forward, origin
    return _transform(m)


def _emitter(geometry: RigGeometry, pose: RigPose, light: LightSpec) -> dict[str, Any]:
    position = _vec3("light_position_m", pose.light_position_m)
    intensity = {"type": "rgb", "value": list(light.rgb())}
    if light.kind == "point":
        return {"type": "point", "position": position.tolist(), "intensity": intensity}
    forward = _unit(_vec3("sample_centre_m", pose.sample_centre_m) - position)
    left = _unit(np.cross(_up_for(forward), forward))
    beam, cutoff = light.cone_deg(geometry)
    return {
        "type": "spot",
        "to_world": _look_at(position, forward, left, np.cross(forward, left)),
        "intensity": intensity,
        "cutoff_angle": cutoff,
        "beam_width": beam,
    }


def sample_to_world(geometry: RigGeometry, pose: RigPose) -> FloatArray:
    """4x4 matrix taking Mitsuba's [-1, 1]^2 rectangle to the sample: x -> tangent, y -> bitangent, z -> normal."""
    m = np.eye(4)
    m[:3, 0] = 0.5 * geometry.sample_width_m * _vec3("sample_tangent", pose.sample_tangent)
    m[:3, 1] = 0.5 * geometry.sample_height_m * _vec3("sample_bitangent", pose.sample_bitangent)
    m[:3, 2] = _vec3("sample_normal", pose.sample_normal)
    m[:3, 3] = _vec3("sample_centre_m", pose.sample_centre_m)
    return m


def build_scene(
    geometry: RigGeometry,
    pose: RigPose,
    bsdf: BSDFLike,
    light: LightSpec,
    camera: CameraSpec,
    crop: Box | None = None,
) -> dict[str, Any]:
    """The Mitsuba scene dict of the rig at one pose (metres, W/sr); ``crop`` renders only that pixel box."""
    view = camera_view(geometry, pose, camera)
    distance = float(np.linalg.norm(view.origin - _vec3("sample_centre_m", pose.sample_centre_m)))
    half_diagonal = 0.5 * math.hypot(geometry.sample_width_m, geometry.sample_height_m)
    w, h = camera.resolution
    film: dict[str, Any] = {
        "type": "hdrfilm",
        "width": w,
        "height": h,
        "pixel_format": "rgb",
        "component_format": "float32",
        "rfilter": {"type": "box"},  # each pixel averages its own footprint only, so crops match the full frame
    }
    if crop is not None:
        x0, y0, x1, y1 = check_box(crop, camera.resolution, "crop")
        film.update(crop_offset_x=x0, crop_offset_y=y0, crop_width=x1 - x0, crop_height=y1 - y0)
    return {
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
        "sensor": {
            "type": "perspective",
            "fov": camera.fov(geometry),
            "fov_axis": camera.fov_axis,
            # Clip planes bracket the sample with margin whatever the arm radius.
            "near_clip": 0.5 * (distance - half_diagonal),
            "far_clip": 2.0 * (distance + half_diagonal),
            "to_world": _look_at(view.origin, view.forward, view.left, view.up),
            "film": film,
            "sampler": {"type": camera.sampler, "sample_count": camera.spp, "seed": camera.seed},
        },
        "sample": {
            "type": "rectangle",
            "to_world": _transform(sample_to_world(geometry, pose)),
            "bsdf": bsdf_dict(bsdf),
        },
        "light": _emitter(geometry, pose, light),
    }
