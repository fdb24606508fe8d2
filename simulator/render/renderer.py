"""Render the rig's scene to linear radiance with Mitsuba 3, and cache renders by pose and material.

Units: with emitter intensities in W/sr and lengths in metres, Mitsuba's rgb film holds radiance in
W/(m^2 sr) per channel. The simulated camera (``simulator.camera.simulated``, ``.sensor``) turns radiance
into exposures; one render per pose serves every exposure of a bracket, which is why renders are cached.

Variants: ``llvm_ad_rgb`` where libLLVM >= 16 loads, else ``scalar_rgb`` (see
``model.mitsuba.variant``; $GONIO_MITSUBA_VARIANT overrides that choice). An explicit ``variant=``
forces one, over the environment too. The previously active variant is restored after each render (with
none active before, the render's stays: Mitsuba cannot unset one). Switching costs many ROI renders each
way, so a sweep should keep one variant active. Mitsuba's active variant is process-global, so renders are
serialised by a lock.

Speed: an ROI crop renders in a small fraction of a full frame's time under either variant, whatever the frame
size (bench/simulator). Render the ROI.
"""

from __future__ import annotations

import contextlib
import json
import threading
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np
import numpy.typing as npt

from model.mitsuba.variant import VariantUnavailable, pick_variant, unavailable_reason, use_variant
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics_types import RigPose
from rig.instrument.sample_surface import FLAT, SampleShape
from simulator.render.scene import build_scene
from simulator.render.spec import Box, BSDFLike, CameraSpec, LightSpec, bsdf_dict, check_box
from simulator.render.view import _unit, _vec3, camera_view, pixel_hits, pixel_on_sample, roi_box

FloatArray = npt.NDArray[np.float64]

_render_lock = threading.RLock()


def resolve_variant(variant: str | None = None, prefer: str | None = None) -> str:
    """The rgb variant to render with: ``variant`` if given (must load), else ``pick_variant(prefer=...)``."""
    if variant is not None:
        # The probe is cached per process; switching to the variant just to check would cost a switch each way.
        reason = unavailable_reason(variant)
        if reason is not None:
            raise VariantUnavailable(f"Mitsuba variant {variant!r} (requested) does not load: {reason}")
        return variant
    return pick_variant("rgb", prefer=prefer)


def needs_evaluated_calls(bsdf: BSDFLike) -> bool:
    """Whether a material asks for evaluated (non-symbolic) drjit calls: a BSDF written in Python with numpy."""
    return bool(getattr(bsdf, "needs_evaluated_calls", False))


def render_radiance(
    scene_dict: Mapping[str, Any], variant: str | None = None, seed: int = 0, *, evaluated_calls: bool = False
) -> FloatArray:
    """Render a scene dict to radiance in W/(m^2 sr), shape (H, W, 3) float64 (the crop's size if cropped).

    ``evaluated_calls`` turns drjit's symbolic calls and loops off, which a BSDF plugin written in Python
    with numpy (``model.mitsuba.plugin``) needs under llvm; it slows large llvm frames, so it is
    off unless asked for (``RadianceRenderer`` asks when the material says ``needs_evaluated_calls``).
    """
    name = resolve_variant(variant)
    with _render_lock, use_variant(name), contextlib.ExitStack() as stack:
        if evaluated_calls:
            stack.enter_context(dr.scoped_set_flag(dr.JitFlag.SymbolicCalls, False))
            stack.enter_context(dr.scoped_set_flag(dr.JitFlag.SymbolicLoops, False))
        scene = mi.load_dict(dict(scene_dict))
        image = mi.render(scene, seed=mi.UInt32(seed))
        out = np.array(image, dtype=np.float64)
    if out.ndim != 3 or out.shape[-1] != 3:
        raise RuntimeError(f"expected an (H, W, 3) rgb film from Mitsuba, got shape {out.shape}")
    return out


def roi_mean(image: npt.ArrayLike, roi: Box, origin: tuple[int, int] = (0, 0)) -> FloatArray:
    """Mean radiance (3,) in W/(m^2 sr) over an ROI box of an image whose pixel (0, 0) is at ``origin``."""
    img = np.asarray(image, dtype=np.float64)
    x0, y0, x1, y1 = roi
    ox, oy = origin
    h, w = img.shape[:2]
    if not (0 <= x0 - ox < x1 - ox <= w and 0 <= y0 - oy < y1 - oy <= h):
        raise ValueError(f"ROI {roi!r} is not inside the image of shape {img.shape[:2]} at origin {origin}")
    out: FloatArray = img[y0 - oy : y1 - oy, x0 - ox : x1 - ox].reshape(-1, img.shape[-1]).mean(axis=0)
    return out


def roi_radiance(
    geometry: RigGeometry,
    pose: RigPose,
    bsdf: BSDFLike,
    light: LightSpec,
    camera: CameraSpec,
    *,
    variant: str | None = None,
    seed: int = 0,
    shape: SampleShape = FLAT,
) -> FloatArray:
    """Mean radiance (3,) in W/(m^2 sr) over the camera's ROI, rendering only the ROI's pixels."""
    roi = roi_box(geometry, pose, light, camera, shape)
    image = render_radiance(
        build_scene(geometry, pose, bsdf, light, camera, crop=roi, shape=shape),
        variant or resolve_variant(None, camera.variant),
        seed,
        evaluated_calls=needs_evaluated_calls(bsdf),
    )
    return roi_mean(image, roi, (roi[0], roi[1]))


def beam_profile(
    geometry: RigGeometry, pose: RigPose, light: LightSpec, camera: CameraSpec, crop: Box | None = None,
    shape: SampleShape = FLAT,
) -> FloatArray:
    """The lamp's relative irradiance on the sample point each pixel sees, (H, W) (the crop's size if cropped).

    1 - falloff (a / a_edge)^2 at the angle a off the beam's axis (light to aim point), a_edge the edge of
    the lit spot (``LightSpec.edge_deg``); a delta or disk light's rendered radiance scales with it pixel by
    pixel.
    """
    x0, y0, x1, y1 = crop if crop is not None else (0, 0, *camera.resolution)
    py, px = np.mgrid[y0:y1, x0:x1] + 0.5
    view = camera_view(geometry, pose, camera)
    if shape.kind == "flat":  # the plane beyond the square too: an edge pixel's centre may lie just off it
        p, _ = pixel_on_sample(view, pose, px, py)
    else:  # a pixel that misses renders black whatever this factor says (its filler point is the centre)
        p = pixel_hits(view, geometry, pose, shape, px, py).point_m
    src = _vec3("light_position_m", pose.light_position_m)
    axis = _unit(_vec3("aim_m", pose.aim()) - src)
    to_p = p - src
    with np.errstate(invalid="ignore"):
        off = np.degrees(np.arccos(np.clip((to_p @ axis) / np.linalg.norm(to_p, axis=-1), -1.0, 1.0)))
    factor = 1.0 - light.falloff * (off / light.edge_deg(geometry)) ** 2
    out: FloatArray = np.where(np.isfinite(factor), np.maximum(factor, 0.0), 1.0)
    return out


def material_key(bsdf: BSDFLike) -> str:
    """A canonical text key of a BSDF dict (sorted JSON; non-JSON values by repr) for caching."""
    return json.dumps(bsdf_dict(bsdf), sort_keys=True, default=repr)


def pose_key(pose: RigPose, decimals: int = 6) -> tuple[float, ...]:
    """The pose's seven vectors (with the aim point) rounded to ``decimals`` (metres, unit vectors), flattened."""
    parts = (pose.sample_centre_m, pose.sample_normal, pose.sample_tangent, pose.sample_bitangent,
             pose.light_position_m, pose.camera_position_m, pose.aim())
    # + 0.0 folds -0.0 into 0.0 so mirrored rounding does not split one pose into two keys.
    return tuple(float(v) for p in parts for v in np.round(np.asarray(p, dtype=np.float64).reshape(3), decimals) + 0.0)


@dataclass(frozen=True)
class CacheStats:
    """Render cache counters: hits, misses, entries held, the bound, and the bytes held."""

    hits: int
    misses: int
    size: int
    maxsize: int
    nbytes: int = 0


class RadianceRenderer:
    """Renders radiance images of the rig, cached (LRU) by pose, material, light, camera, crop and variant.

    The cache holds at most ``maxsize`` renders and ``max_bytes`` of them (a 1024 x 1024 float64 frame is
    25 MB; an ROI crop a few kB), least recently used first out. Poses are keyed after rounding to
    ``decimals`` (default 6: micrometres and microradians), so servo read-backs that agree to that
    precision share a render. Returned images are read-only views of the cache; copy before writing.
    ``variant`` forces a Mitsuba variant, else ``camera.variant`` is preferred. ``shape`` is the sample's
    surface: it places the default ROI, and a render draws it unless told another (a flat reference tile).
    """

    def __init__(
        self,
        geometry: RigGeometry,
        light: LightSpec | None = None,
        camera: CameraSpec | None = None,
        *,
        variant: str | None = None,
        maxsize: int = 64,
        max_bytes: int = 256 * 2**20,
        decimals: int = 6,
        shape: SampleShape = FLAT,
    ) -> None:
        if maxsize < 1:
            raise ValueError(f"maxsize = {maxsize!r}, expected at least 1 render")
        if max_bytes < 1:
            raise ValueError(f"max_bytes = {max_bytes!r}, expected a positive number of bytes")
        self.geometry = geometry
        self.light = light if light is not None else LightSpec()
        self.camera = camera if camera is not None else CameraSpec()
        self.variant = variant
        self.maxsize = maxsize
        self.max_bytes = max_bytes
        self.decimals = decimals
        self.shape = shape
        self._bytes = 0
        self._cache: OrderedDict[tuple[Any, ...], FloatArray] = OrderedDict()
        self._rois: OrderedDict[tuple[Any, ...], Box] = OrderedDict()
        self._lock = threading.RLock()
        self.hits = 0
        self.misses = 0

    @property
    def stats(self) -> CacheStats:
        """Hit/miss counters and cache size."""
        with self._lock:
            return CacheStats(self.hits, self.misses, len(self._cache), self.maxsize, self._bytes)

    def clear(self) -> None:
        """Drop every cached render and reset the counters."""
        with self._lock:
            self._cache.clear()
            self._rois.clear()
            self._bytes = 0
            self.hits = self.misses = 0

    def render(
        self,
        pose: RigPose,
        bsdf: BSDFLike,
        *,
        crop: Box | None = None,
        light: LightSpec | None = None,
        camera: CameraSpec | None = None,
        key: str | None = None,
        seed: int = 0,
        shape: SampleShape | None = None,
    ) -> FloatArray:
        """Radiance image in W/(m^2 sr), (H, W, 3) or the crop's size; ``key`` names the material for the cache.

        ``shape`` draws another surface than the renderer's own (a flat reference tile in front of a sphere).
        """
        light = light if light is not None else self.light
        camera = camera if camera is not None else self.camera
        shape = shape if shape is not None else self.shape
        if crop is not None:
            crop = check_box(crop, camera.resolution, "crop")
        variant = resolve_variant(self.variant, camera.variant)
        cache_key = (pose_key(pose, self.decimals), key if key is not None else material_key(bsdf),
                     light, camera, crop, camera.spp, variant, seed, shape)
        with self._lock:
            cached = self._cache.get(cache_key)
            if cached is not None:
                self._cache.move_to_end(cache_key)
                self.hits += 1
                return cached
            self.misses += 1
        scene = build_scene(self.geometry, pose, bsdf, light, camera, crop, shape)
        image = render_radiance(scene, variant, seed, evaluated_calls=needs_evaluated_calls(bsdf))
        if light.falloff > 0:
            image = image * beam_profile(self.geometry, pose, light, camera, crop, shape)[..., None]
        image.setflags(write=False)
        with self._lock:
            if cache_key not in self._cache:
                self._bytes += image.nbytes
            self._cache[cache_key] = image
            self._cache.move_to_end(cache_key)
            # The newest render always stays, even when it alone exceeds max_bytes.
            while len(self._cache) > 1 and (len(self._cache) > self.maxsize or self._bytes > self.max_bytes):
                self._bytes -= self._cache.popitem(last=False)[1].nbytes
        return image

    def roi(self, pose: RigPose, light: LightSpec | None = None, camera: CameraSpec | None = None) -> Box:
        """The ROI pixel box for a pose (the camera's, or the default one for this pose, remembered)."""
        light = light if light is not None else self.light
        camera = camera if camera is not None else self.camera
        if camera.roi is not None:
            return camera.roi
        # The default ROI is worked out from the geometry, costly at large resolutions: keep it as long as renders.
        key = (pose_key(pose, self.decimals), light, camera)
        with self._lock:
            box = self._rois.get(key)
            if box is not None:
                self._rois.move_to_end(key)
                return box
        box = roi_box(self.geometry, pose, light, camera, self.shape)
        with self._lock:
            self._rois[key] = box
            while len(self._rois) > self.maxsize:
                self._rois.popitem(last=False)
        return box

    def roi_radiance(
        self,
        pose: RigPose,
        bsdf: BSDFLike,
        *,
        light: LightSpec | None = None,
        camera: CameraSpec | None = None,
        key: str | None = None,
        seed: int = 0,
    ) -> FloatArray:
        """Mean radiance (3,) in W/(m^2 sr) over the ROI, rendering (and caching) only the ROI's pixels."""
        roi = self.roi(pose, light, camera)
        image = self.render(pose, bsdf, crop=roi, light=light, camera=camera, key=key, seed=seed)
        return roi_mean(image, roi, (roi[0], roi[1]))
