"""The rig, materials and independent references (point-source law per pixel, texture conventions) the
render tests share."""

from __future__ import annotations

from typing import Any

import drjit as dr
import mitsuba as mi
import mitsuba.scalar_rgb as mis
import numpy as np

from model.mitsuba import variant as mv
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import RigPose, inverse, require, world_pose
from simulator.render.spec import CameraSpec, LightSpec
from simulator.render.view import camera_view, pixel_on_sample
from tests.mitsuba_helpers import rgb

GEOMETRY = RigGeometry()


ALBEDO = 0.5


INTENSITY = 2.0  # W/sr


DIFFUSE = {"type": "diffuse", "reflectance": rgb([ALBEDO] * 3)}


CAMERA = CameraSpec(resolution=(64, 64), spp=4)


POINT = LightSpec(intensity=INTENSITY)


#: (theta_i, phi_i, theta_o, phi_o) in degrees, spanning theta_i 0/30/60, theta_o 0/45/70 and several phi.
ANGLES = [
    (0.0, 0.0, 45.0, 180.0),
    (30.0, 0.0, 0.0, 0.0),
    (30.0, 40.0, 70.0, 250.0),
    (60.0, 0.0, 45.0, 90.0),
    (60.0, 300.0, 70.0, 135.0),
    (0.0, 0.0, 70.0, 30.0),
]


def pose_at(theta_i: float, phi_i: float, theta_o: float, phi_o: float, geometry: RigGeometry = GEOMETRY) -> RigPose:
    return world_pose(geometry, require(inverse(geometry, theta_i, phi_i, theta_o, phi_o)))


def lambert_per_pixel(pose: RigPose, camera: CameraSpec, box: tuple[int, int, int, int]) -> np.ndarray:
    """albedo/pi * I * cos(theta_i') / d^2 at each pixel centre of the box, from numpy geometry alone."""
    view = camera_view(GEOMETRY, pose, camera)
    x0, y0, x1, y1 = box
    py, px = np.mgrid[y0:y1, x0:x1] + 0.5
    p, _ = pixel_on_sample(view, pose, px, py)
    to_light = pose.light_position_m - p
    d = np.linalg.norm(to_light, axis=-1)
    cos_i = (to_light @ pose.sample_normal) / d
    return ALBEDO / np.pi * INTENSITY * cos_i / d**2


def half_space_texture(axis: int) -> dict[str, Any]:
    """Diffuse reflectance whose checkerboard colour depends on the sign of local x (axis 0) or y (axis 1) only.

    Scaling the other uv coordinate by 1/2 keeps its frac() below 1/2, so the board splits at u (or v) = 1/2,
    i.e. at local x (or y) = 0 on Mitsuba's rectangle.
    """
    scale = [0.5, 1.0, 1.0] if axis == 1 else [1.0, 0.5, 1.0]
    return {
        "type": "diffuse",
        "reflectance": {
            "type": "checkerboard",
            "color0": rgb([0.9, 0.05, 0.05]),
            "color1": rgb([0.05, 0.05, 0.9]),
            "to_uv": mis.ScalarTransform4f().scale(scale),
        },
    }


def texture_at_local(spec: dict[str, Any], x: float, y: float) -> np.ndarray:
    """The reflectance texture's colour at local (x, y) in [-1, 1]^2, via the rectangle's uv = (x + 1, y + 1) / 2."""
    with mv.use_variant("scalar_rgb"):
        texture = mi.load_dict(spec["reflectance"])
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.uv = mi.Point2f(0.5 * x + 0.5, 0.5 * y + 0.5)
        return np.array(texture.eval(si), dtype=np.float64)


def mirrored_through_sample(pose: RigPose, point: np.ndarray) -> np.ndarray:
    n = pose.sample_normal
    return point - 2.0 * ((point - pose.sample_centre_m) @ n) * n
