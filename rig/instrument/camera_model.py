"""The camera as a pinhole model: where world points land in its image, and which ray a pixel sees.

A camera on its arm is aimed at the arms' axis (the world origin) with image up along world +z (the arm
axis), unless it looks nearly straight down the axis, when world +x serves. Its field of view spans the
image's smaller side (``camera_fov_deg`` of the rig). These are also the conventions of the simulated
camera (``simulator.render``, whose Mitsuba ``perspective`` sensor this model reproduces), so the
controller's model of an ideal camera and the simulator's camera agree exactly. Pixel coordinates are
continuous: the centre of pixel (i, j) (column, row) is (i + 0.5, j + 0.5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

#: Cosine of the angle between the view direction and world z above which world z cannot serve as up.
UP_DEGENERATE_COS = 0.999


def up_for(forward: FloatArray) -> FloatArray:
    """World z, the arm axis, unless the view is nearly vertical; then world x (a top-down view)."""
    z = np.array([0.0, 0.0, 1.0])
    return z if abs(float(forward @ z)) < UP_DEGENERATE_COS else np.array([1.0, 0.0, 0.0])


@dataclass(frozen=True)
class CameraView:
    """A pinhole camera in world metres and pixels (Mitsuba's ``perspective`` sensor).

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


def focal_length_px(fov_deg: float, width: int, height: int, fov_axis: str = "smaller") -> float:
    """Focal length in pixels of a camera whose field of view ``fov_deg`` spans the image along ``fov_axis``."""
    size = {"x": width, "y": height, "smaller": min(width, height), "larger": max(width, height),
            "diagonal": math.hypot(width, height)}[fov_axis]  # fmt: skip
    return 0.5 * size / math.tan(math.radians(0.5 * fov_deg))


def aimed_camera(origin_m: npt.ArrayLike, aim_m: npt.ArrayLike, focal_px: float, width: int, height: int) -> CameraView:
    """A camera at ``origin_m`` aimed at ``aim_m`` (metres), image up as the module says."""
    origin = np.asarray(origin_m, dtype=np.float64)
    forward = np.asarray(aim_m, dtype=np.float64) - origin
    forward = forward / np.linalg.norm(forward)
    left = np.cross(up_for(forward), forward)
    left = left / np.linalg.norm(left)
    return CameraView(origin, forward, left, np.cross(forward, left), focal_px, width, height)
