"""The camera of the rendered scene as a numpy pinhole model, and the region of interest it picks.

``camera_view`` reproduces the ``perspective`` sensor that ``simulator.render.scene.build_scene`` places (as
the controller's ``rig.instrument.camera_model``, which it builds on), so
world points can be projected to pixels (and pixels cast back onto the sample) without Mitsuba; the
default ROI is the largest centred box whose pixels all see the central part of the sample. On a curved
sample (``rig.instrument.sample_surface``) the central part is where the surface's normal lies within the
angle the flat sample's central part spans seen from the camera, around the normal the image centre sees:
the ROI's readings then mix as wide a range of directions as a flat sample's do.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from rig.instrument.camera_model import CameraView, aimed_camera, focal_length_px
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics_types import RigPose
from rig.instrument.sample_surface import FLAT, SampleShape, SurfaceHits, surface_hits
from simulator.render.spec import Box, CameraSpec, LightSpec

FloatArray = npt.NDArray[np.float64]

def _vec3(name: str, value: npt.ArrayLike) -> FloatArray:
    a = np.asarray(value, dtype=np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"pose.{name} = {value!r}, expected one finite 3-vector (a single pose, not a batch)")
    return a


def _unit(v: FloatArray) -> FloatArray:
    out: FloatArray = v / np.linalg.norm(v)
    return out


def camera_view(geometry: RigGeometry, pose: RigPose, camera: CameraSpec) -> CameraView:
    """The camera of ``build_scene`` as a numpy pinhole model: where world points land in the image."""
    w, h = camera.resolution
    focal = focal_length_px(camera.fov(geometry), w, h, camera.fov_axis)
    return aimed_camera(_vec3("camera_position_m", pose.camera_position_m), _vec3("aim_m", pose.aim()), focal, w, h)


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


def pixel_hits(view: CameraView, geometry: RigGeometry, pose: RigPose, shape: SampleShape,
               px: npt.ArrayLike, py: npt.ArrayLike) -> SurfaceHits:  # fmt: skip
    """Where pixel rays (continuous pixel coordinates, any shape) meet the sample's surface: hits (..., 3) in metres."""
    x, y = np.broadcast_arrays(np.asarray(px, dtype=np.float64), np.asarray(py, dtype=np.float64))
    hits = surface_hits(shape, geometry, pose, view.origin, view.ray(x, y).reshape(-1, 3))
    return SurfaceHits(hits.point_m.reshape(*x.shape, 3), hits.normal.reshape(*x.shape, 3),
                       hits.tangent.reshape(*x.shape, 3), hits.hit.reshape(x.shape))  # fmt: skip


def _curved_mask(geometry: RigGeometry, pose: RigPose, camera: CameraSpec,
                 shape: SampleShape) -> tuple[npt.NDArray[np.bool_], FloatArray, int, int]:  # fmt: skip
    """A curved sample's central region: pixels seeing normals within the flat region's angular span; points."""
    view = camera_view(geometry, pose, camera)
    k = math.sqrt(camera.roi_fraction)
    half = 0.5 * k * min(geometry.sample_width_m, geometry.sample_height_m)
    spread = math.atan2(half, float(np.linalg.norm(view.origin - pose.aim())))
    centre = pixel_hits(view, geometry, pose, shape, 0.5 * view.width, 0.5 * view.height)
    top = centre.point_m if bool(centre.hit) else _vec3("sample_centre_m", pose.sample_centre_m)
    normal = centre.normal if bool(centre.hit) else _vec3("sample_normal", pose.sample_normal)
    # The cap of normals within `spread` stays within the arc R * spread of the top: its box bounds the window.
    reach = 2.0 * shape.radius_m * spread + 1e-9
    axes = (_vec3("sample_tangent", pose.sample_tangent), _vec3("sample_bitangent", pose.sample_bitangent))
    corners = [top + su * reach * axes[0] + sv * reach * axes[1] for su in (-1.0, 1.0) for sv in (-1.0, 1.0)]
    x0, y0, x1, y1 = _window(view, np.array(corners))
    py, px = np.mgrid[y0:y1, x0:x1] + 0.5
    hits = pixel_hits(view, geometry, pose, shape, px, py)
    mask = hits.hit & (hits.normal @ normal >= math.cos(spread))
    return mask, hits.point_m, x0, y0


def _window(view: CameraView, corners: FloatArray) -> Box:
    """The pixel box around projected corners (one pixel's margin), always holding the image's central pixels."""
    pix = view.project(corners)
    x0 = max(0, min(int(np.floor(pix[:, 0].min())) - 1, (view.width - 1) // 2))
    x1 = min(view.width, max(int(np.ceil(pix[:, 0].max())) + 1, view.width // 2 + 1))
    y0 = max(0, min(int(np.floor(pix[:, 1].min())) - 1, (view.height - 1) // 2))
    y1 = min(view.height, max(int(np.ceil(pix[:, 1].max())) + 1, view.height // 2 + 1))
    return x0, y0, x1, y1


def sample_box(geometry: RigGeometry, pose: RigPose, camera: CameraSpec, shape: SampleShape = FLAT) -> Box:
    """The pixel box (x0, y0, x1, y1) holding everything of the sample the camera can see, with a pixel's margin.

    The projected corners of the box the sample fits in bound it: the flat square; a sphere's cube; a cylinder's
    box of its radius across and the sample's height along.
    """
    view = camera_view(geometry, pose, camera)
    c = _vec3("sample_centre_m", pose.sample_centre_m)
    t, b = _vec3("sample_tangent", pose.sample_tangent), _vec3("sample_bitangent", pose.sample_bitangent)
    n = _vec3("sample_normal", pose.sample_normal)
    r = shape.radius_m if shape.kind != "flat" else 0.0
    half_t = r if shape.kind != "flat" else 0.5 * geometry.sample_width_m
    half_b = r if shape.kind == "sphere" else 0.5 * geometry.sample_height_m
    corners = [c + su * half_t * t + sv * half_b * b - depth * n
               for su in (-1.0, 1.0) for sv in (-1.0, 1.0) for depth in (0.0, 2.0 * r)]  # fmt: skip
    return _window(view, np.array(corners))


def _roi_mask(
    geometry: RigGeometry, pose: RigPose, light: LightSpec, camera: CameraSpec, shape: SampleShape = FLAT
) -> tuple[npt.NDArray[np.bool_], int, int]:
    """Pixels whose centre sees the central ``roi_fraction`` of the sample (and of a spot); window origin.

    Only the window around the region's projection is computed (it is convex, so its image lies within
    the bounding box of its projected corners): a full frame at large resolutions would be slow.
    """
    view = camera_view(geometry, pose, camera)
    centre = _vec3("sample_centre_m", pose.sample_centre_m)
    k = math.sqrt(camera.roi_fraction)
    if shape.kind != "flat":
        mask, p, x0, y0 = _curved_mask(geometry, pose, camera, shape)
    else:
        half = (0.5 * k * geometry.sample_width_m, 0.5 * k * geometry.sample_height_m)
        corners = [centre + su * half[0] * _vec3("sample_tangent", pose.sample_tangent)
                   + sv * half[1] * _vec3("sample_bitangent", pose.sample_bitangent)
                   for su in (-1.0, 1.0) for sv in (-1.0, 1.0)]
        x0, y0, x1, y1 = _window(view, np.array(corners))
        py, px = np.mgrid[y0:y1, x0:x1] + 0.5
        p, uv = pixel_on_sample(view, pose, px, py)
        with np.errstate(invalid="ignore"):
            mask = (np.abs(uv[..., 0]) <= half[0]) & (np.abs(uv[..., 1]) <= half[1])
    with np.errstate(invalid="ignore"):
        if light.kind == "spot":
            src = _vec3("light_position_m", pose.light_position_m)
            axis = _unit(centre - src)
            to_p = p - src
            cos_off = (to_p @ axis) / np.linalg.norm(to_p, axis=-1)
            beam, _ = light.cone_deg(geometry)
            mask &= cos_off >= math.cos(math.radians(k * beam))
    return mask, x0, y0


def default_roi(
    geometry: RigGeometry, pose: RigPose, light: LightSpec, camera: CameraSpec, shape: SampleShape = FLAT
) -> Box:
    """The largest centred pixel box whose pixel centres all see the sample's central ``roi_fraction``.

    The box is grown about the image centre (where the sample centre projects) one pixel a side at a
    time, alternating x and y, while it stays inside the mask; it is at least the central 1-2 pixels
    even when those miss the region (a grazing view at low resolution).
    """
    mask, ox, oy = _roi_mask(geometry, pose, light, camera, shape)
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


def roi_box(
    geometry: RigGeometry, pose: RigPose, light: LightSpec, camera: CameraSpec, shape: SampleShape = FLAT
) -> Box:
    """The camera's ROI: ``camera.roi`` if given, else ``default_roi`` for this pose and sample shape."""
    return camera.roi if camera.roi is not None else default_roi(geometry, pose, light, camera, shape)
