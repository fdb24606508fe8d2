"""Where a rig with given imperfections would show the board's corners and the lamp's highlight.

The fitted parameters of each layout are the imperfections its captures can tell apart:

- four-axis: the four joint zeros, the wedge as a vector (x, y: ``sample_tilt_deg`` times the cosine and
  sine of its azimuth, degrees; smooth where the tilt is 0 and its azimuth undefined), and the offset (mm);
- in-plane: the stage does not move, so a wedge cannot be told from the fixed stage's own tilt and roll
  errors; both are fitted as tilt and roll zeros (the wedge reported as 0), and the normal's turn about
  the arms' axis is one with a common shift of both arm zeros;
- fixed-camera: a turn of everything about the arms' axis is invisible, so the camera's zero is held at 0
  and the light, yaw, tilt and roll zeros are fitted against it.

The camera is the controller's ideal pinhole (``rig.instrument.camera_model``) on its arm, aimed at the
arms' axis; corners sit on the sample's face (``ChArUcoBoard.corners_local_m``); the highlight is where the
camera sees the lamp's mirror image in the sample's plane.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from model.cook_torrance import CookTorrance
from rig.instrument.alignment import Alignment, aligned_pose
from rig.instrument.camera_model import aimed_camera
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Joints

FloatArray = npt.NDArray[np.float64]


def coat_peak(
    geometry: RigGeometry, joints: Joints, alignment: Alignment, focal_px: float, size: tuple[int, int], alpha: float,
    ior: float = 1.5,
) -> FloatArray:
    """Where the coat's highlight peaks (px, the estimator of ``observe.peak_of``), not just the mirror point.

    The spot's brightness across the image is the coat's GGX lobe times Fresnel, masking and the lamp's
    irradiance (cos / r^2), which all vary across it: their slopes pull the peak off the mirror point by
    about alpha^2 R / pixel size (a tenth of a pixel at alpha 0.01 and 640 pixels). The spot is evaluated
    on the pixel grid around the mirror point and its peak found as the observation finds it.
    """
    from rig.alignment.observe import peak_of

    pose = aligned_pose(geometry, joints, alignment)
    camera = aimed_camera(pose.camera_position_m, pose.aim(), focal_px, size[0], size[1])
    c, n = np.asarray(pose.sample_centre_m), np.asarray(pose.sample_normal)
    t, b = np.asarray(pose.sample_tangent), np.asarray(pose.sample_bitangent)
    lamp = np.asarray(pose.light_position_m)
    mirror = camera.project(lamp - 2.0 * float((lamp - c) @ n) * n)
    coat = CookTorrance(alpha=alpha, fresnel="dielectric", eta=ior, distribution="ggx", masking="smith")
    k = 6
    while True:
        ix, iy = int(np.floor(mirror[0])), int(np.floor(mirror[1]))
        gy, gx = np.mgrid[iy - k : iy + k + 1, ix - k : ix + k + 1] + 0.5
        ray = camera.ray(gx, gy)
        with np.errstate(divide="ignore", invalid="ignore"):
            dist = ((c - camera.origin) @ n) / (ray @ n)
        p = camera.origin + dist[..., None] * ray
        to_lamp = lamp - p
        r2 = np.sum(to_lamp * to_lamp, axis=-1)
        wi, wo = to_lamp / np.sqrt(r2)[..., None], -ray
        local = np.stack([t, b, n])
        f = np.asarray(coat.eval(wi @ local.T, wo @ local.T), dtype=np.float64)
        radiance = np.where(np.isfinite(f), f * np.maximum(wi @ n, 0.0) / r2, 0.0)
        peak = float(radiance[k, k])
        j, i = (int(v) for v in np.unravel_index(int(np.argmax(radiance)), radiance.shape))
        found, _ = peak_of(radiance, radiance * max(peak, 1e-30), j, i, peak)
        if found is not None or k >= 256:
            break
        k *= 2
    if found is None:
        return np.asarray(mirror, dtype=np.float64)
    return np.array([found.x - 0.5 - k + ix + 0.5, found.y - 0.5 - k + iy + 0.5])


def predict(
    geometry: RigGeometry,
    joints: Joints,
    alignment: Alignment,
    corners_local_m: FloatArray,
    focal_px: float,
    size: tuple[int, int],
) -> tuple[FloatArray, FloatArray]:
    """Pixels of the board's corners (N, 2) and of the lamp's mirror highlight (2,) for one capture."""
    pose = aligned_pose(geometry, joints, alignment)
    camera = aimed_camera(pose.camera_position_m, pose.aim(), focal_px, size[0], size[1])
    c, n = np.asarray(pose.sample_centre_m), np.asarray(pose.sample_normal)
    local = np.asarray(corners_local_m, dtype=np.float64)
    world = c + local[:, :1] * pose.sample_tangent + local[:, 1:2] * pose.sample_bitangent + local[:, 2:3] * n
    lamp = np.asarray(pose.light_position_m)
    mirrored = lamp - 2.0 * float((lamp - c) @ n) * n
    return camera.project(world), camera.project(mirrored)
