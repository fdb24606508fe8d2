"""Image mode's geometry: which k x k pixel tiles of the sensor see the sample, and each tile's directions.

The calibrated camera model (``rig.instrument.camera_model``) casts a ray through every pixel; the sample's
surface (``rig.instrument.sample_surface``) says where each meets it, and the local angles there. A tile is a
sample when every ray of it meets the sample on its lit side within the grazing limit: a tile straddling the
sample's edge would average the background into its mean, and one partly beyond the limit would hold pixels
whose reading the cosine turns into noise. Rays go through ``SUBPIXELS`` x ``SUBPIXELS`` points of every pixel,
so the tile's footprint is the whole area its pixels see (a 1 x 1 tile too), not only their centres.

A tile's directions are the mean of its points' local unit vectors; its footprint covariance is their
spread (population covariance), of the angles in deg^2 (phi differences wrapped) and of the tangent
components (wi_x, wi_y, wo_x, wo_y) that ``model.fit.angular`` reads. The reading averages the BRDF over that
spread, so where the BRDF curves within a tile (a highlight crossing it) the spread is the error the
directions carry.

A frame taken while a joint moves (a continuous scan) sees each tile's directions sweep along the motion: uniform
motion over the exposure is a spread too, the joint's travel^2 / 12 carried to each tile's own directions by their
slope in that joint (``motion_covariance``, through ``rig.instrument.direction_uncertainty`` as a pose's are), and
added to the tile's footprint covariance.

Tiles lie on a grid fixed to the sensor (tile (col, row) covers pixels [col k, (col + 1) k) x [row k, ...)),
so a tile's number (``row * columns + col``) names the same pixels at every pose.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from model.geometry import degrees_to_vector
from rig.instrument.alignment import Alignment, aligned_pose
from rig.instrument.camera_model import CameraView, aimed_camera, focal_length_px
from rig.instrument.direction_uncertainty import direction_covariances
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics_types import Joints, RigPose
from rig.instrument.sample_surface import SampleShape, local_angles, surface_hits

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
Box = tuple[int, int, int, int]

#: Rays per pixel side: the tile's footprint is sampled over its pixels' area, not only their centres.
SUBPIXELS = 2
#: The default tile side (pixels) where the sweep file gives none.
DEFAULT_TILE_PX = 8


@dataclass(frozen=True)
class ImageSettings:
    """Image mode: tile side (pixels), the sensor (width, height) in pixels, the sample's shape, grazing limit (deg).

    ``grazing_limit_deg``: tiles with any ray whose theta_i or theta_o exceeds it are left out (None: the rig's
    ``max_zenith_deg``).
    """

    tile_px: int = DEFAULT_TILE_PX
    resolution: tuple[int, int] = (32, 32)
    shape: SampleShape = field(default_factory=SampleShape)
    grazing_limit_deg: float | None = None

    def __post_init__(self) -> None:
        if not (isinstance(self.tile_px, int) and self.tile_px >= 1):
            raise ValueError(f"ImageSettings.tile_px = {self.tile_px!r}: expected a whole number of pixels >= 1")
        w, h = self.resolution
        if not (w >= self.tile_px and h >= self.tile_px):
            raise ValueError(f"ImageSettings.resolution = {self.resolution!r}: smaller than one {self.tile_px}-px tile")


@dataclass(frozen=True)
class TileGeometry:
    """The tiles that see the sample at one pose: sensor window (pixels), and per tile (T of them) its box in
    the window, number, mean angles (deg), effective light distance (m: the footprint's mean irradiance at the
    mean direction), footprint covariances (T, 4, 4)."""

    window: Box
    boxes: tuple[Box, ...]
    tile: IntArray
    angles_deg: FloatArray  # (T, 4): theta_i, phi_i, theta_o, phi_o
    light_distance_m: FloatArray
    angle_cov_deg2: FloatArray
    direction_cov: FloatArray
    grazing: int  # tiles on the sample left out beyond the grazing limit

    @property
    def count(self) -> int:
        """The number of tiles that are samples."""
        return len(self.boxes)


def camera_of(geometry: RigGeometry, pose: RigPose, resolution: tuple[int, int]) -> CameraView:
    """The calibrated pinhole camera at a pose, for a (width, height) sensor in pixels."""
    w, h = resolution
    focal = focal_length_px(geometry.camera_fov_deg, w, h)
    return aimed_camera(np.asarray(pose.camera_position_m, dtype=np.float64), pose.aim(), focal, w, h)


def _grid(x0: int, y0: int, x1: int, y1: int, sub: int) -> tuple[FloatArray, FloatArray]:
    """Ray points (pixels) over a pixel box: ``sub`` x ``sub`` per pixel, (H sub, W sub) each."""
    xs = x0 + (np.arange((x1 - x0) * sub) + 0.5) / sub
    ys = y0 + (np.arange((y1 - y0) * sub) + 0.5) / sub
    gx, gy = np.meshgrid(xs, ys)
    return gx, gy


def tile_geometry(geometry: RigGeometry, pose: RigPose, image: ImageSettings) -> TileGeometry:
    """The tiles of the sensor that see the sample at ``pose`` (see the module docstring)."""
    k = image.tile_px
    w, h = image.resolution
    view = camera_of(geometry, pose, image.resolution)
    origin = view.origin
    limit = geometry.max_zenith_deg if image.grazing_limit_deg is None else image.grazing_limit_deg
    cols, rows = w // k, h // k
    # Pixel centres first, to find the tiles worth sampling finely.
    cx, cy = _grid(0, 0, cols * k, rows * k, 1)
    seen = surface_hits(image.shape, geometry, pose, origin, view.ray(cx, cy).reshape(-1, 3)).hit
    touched = seen.reshape(rows, k, cols, k).any(axis=(1, 3))
    if not touched.any():
        return _empty()
    r_idx, c_idx = np.nonzero(touched)
    r0, r1, c0, c1 = int(r_idx.min()), int(r_idx.max()) + 1, int(c_idx.min()), int(c_idx.max()) + 1
    s = SUBPIXELS
    gx, gy = _grid(c0 * k, r0 * k, c1 * k, r1 * k, s)
    hits = surface_hits(image.shape, geometry, pose, origin, view.ray(gx, gy).reshape(-1, 3))
    ang = local_angles(hits, np.asarray(pose.light_position_m, dtype=np.float64), origin)
    nr, nc, side = r1 - r0, c1 - c0, k * s

    def per_tile(a: npt.ArrayLike) -> npt.NDArray[np.generic]:
        """(rows, cols, side * side) of a per-ray array."""
        return np.asarray(a).reshape(nr, side, nc, side).transpose(0, 2, 1, 3).reshape(nr, nc, side * side)

    with np.errstate(invalid="ignore"):
        steep = np.maximum(ang.theta_i_deg, ang.theta_o_deg)
        ok_ray = hits.hit & np.isfinite(steep) & (steep <= limit)
    on = per_tile(hits.hit).all(axis=-1)
    good = per_tile(ok_ray).all(axis=-1)
    theta_i, phi_i, theta_o, phi_o = (per_tile(a) for a in (ang.theta_i_deg, ang.phi_i_deg, ang.theta_o_deg,
                                                            ang.phi_o_deg))  # fmt: skip
    dist = per_tile(ang.light_distance_m)
    window = (c0 * k, r0 * k, c1 * k, r1 * k)
    boxes, numbers, angles, distances, cov_a, cov_t = [], [], [], [], [], []
    for i, j in zip(*np.nonzero(good), strict=True):
        wi = degrees_to_vector(theta_i[i, j], phi_i[i, j])
        wo = degrees_to_vector(theta_o[i, j], phi_o[i, j])
        mean_wi, mean_wo = _unit(wi.mean(axis=0)), _unit(wo.mean(axis=0))
        mean = np.array([*_degrees(mean_wi), *_degrees(mean_wo)])
        each = np.stack([theta_i[i, j], phi_i[i, j], theta_o[i, j], phi_o[i, j]], axis=-1).astype(np.float64)
        delta = each - mean
        delta[:, [1, 3]] = (delta[:, [1, 3]] + 180.0) % 360.0 - 180.0
        tangent = np.concatenate([wi[:, :2], wo[:, :2]], axis=-1)
        tangent = tangent - tangent.mean(axis=0)
        boxes.append((j * k, i * k, (j + 1) * k, (i + 1) * k))
        numbers.append((r0 + i) * cols + (c0 + j))
        angles.append(mean)
        # The tile reads the mean of cos(theta_i) / d^2 over its footprint, not its value at the mean direction
        # (on a curved sample the two differ by far more than the noise): the distance recorded is the one that
        # gives that mean irradiance at the mean direction, so calibration divides by what the tile really saw.
        irradiance = float(np.mean(wi[:, 2] / np.asarray(dist[i, j], dtype=np.float64) ** 2))
        distances.append(math.sqrt(float(mean_wi[2]) / irradiance))
        cov_a.append(delta.T @ delta / len(delta))
        cov_t.append(tangent.T @ tangent / len(tangent))
    return TileGeometry(
        window, tuple(boxes), np.asarray(numbers, dtype=np.int64), np.asarray(angles).reshape(-1, 4),
        np.asarray(distances, dtype=np.float64), np.asarray(cov_a).reshape(-1, 4, 4),
        np.asarray(cov_t).reshape(-1, 4, 4), int(np.count_nonzero(on & ~good)),
    )  # fmt: skip


def tile_directions(geometry: RigGeometry, pose: RigPose, image: ImageSettings,
                    tiles: TileGeometry) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """The mean angles (T, 4) in deg and tangent components (T, 4) of ``tiles``' pixels seen from ``pose``."""
    if tiles.count == 0:
        return np.zeros((0, 4)), np.zeros((0, 4))
    k, s = image.tile_px, SUBPIXELS
    x0, y0, x1, y1 = tiles.window
    view = camera_of(geometry, pose, image.resolution)
    gx, gy = _grid(x0, y0, x1, y1, s)
    hits = surface_hits(image.shape, geometry, pose, view.origin, view.ray(gx, gy).reshape(-1, 3))
    ang = local_angles(hits, np.asarray(pose.light_position_m, dtype=np.float64), view.origin)
    nr, nc, side = (y1 - y0) // k, (x1 - x0) // k, k * s
    rows = np.array([b[1] // k for b in tiles.boxes])
    cols = np.array([b[0] // k for b in tiles.boxes])

    def per_tile(a: npt.ArrayLike) -> FloatArray:
        """(T, side * side) of a per-ray array, for the tiles asked about."""
        grid = np.asarray(a, dtype=np.float64).reshape(nr, side, nc, side).transpose(0, 2, 1, 3)
        return grid.reshape(nr, nc, side * side)[rows, cols]

    # A ray the motion takes off the sample has no direction on it: the tile's mean is over the rest.
    on = per_tile(hits.hit)[..., None]
    wi = degrees_to_vector(per_tile(ang.theta_i_deg), per_tile(ang.phi_i_deg))
    wo = degrees_to_vector(per_tile(ang.theta_o_deg), per_tile(ang.phi_o_deg))
    mean_wi, mean_wo = _unit_rows((wi * on).sum(axis=1)), _unit_rows((wo * on).sum(axis=1))
    angles = np.concatenate([_degrees_rows(mean_wi), _degrees_rows(mean_wo)], axis=-1)
    return angles, np.concatenate([mean_wi[:, :2], mean_wo[:, :2]], axis=-1)


def motion_covariance(
    geometry: RigGeometry, joints: Joints, alignment: Alignment, image: ImageSettings, tiles: TileGeometry,
    variance_deg2: Mapping[str, float],
) -> tuple[FloatArray, FloatArray]:
    """Each tile's (angle (T, 4, 4) deg^2, tangent (T, 4, 4)) covariance from the joints' variances (deg^2)."""

    def features(j: Joints, a: Alignment) -> tuple[FloatArray, FloatArray]:
        return tile_directions(geometry, aligned_pose(geometry, j, a), image, tiles)

    return direction_covariances(geometry, joints, alignment, variance_deg2, features=features)


def with_spread(tiles: TileGeometry, angle_cov_deg2: FloatArray, direction_cov: FloatArray) -> TileGeometry:
    """``tiles`` with more spread (T, 4, 4) added to each tile's covariances (deg^2; tangent components)."""
    return dataclasses.replace(tiles, angle_cov_deg2=tiles.angle_cov_deg2 + angle_cov_deg2,
                               direction_cov=tiles.direction_cov + direction_cov)  # fmt: skip


def tiles_within(tiles: TileGeometry, window: Box) -> TileGeometry:
    """The tiles whose pixels all lie in the sensor ``window`` (x0, y0, x1, y1), the others left out."""
    x0, y0, x1, y1 = window
    ox, oy = tiles.window[:2]
    keep = [i for i, b in enumerate(tiles.boxes)
            if x0 <= b[0] + ox and y0 <= b[1] + oy and b[2] + ox <= x1 and b[3] + oy <= y1]  # fmt: skip
    if len(keep) == tiles.count:
        return tiles
    return dataclasses.replace(
        tiles, boxes=tuple(tiles.boxes[i] for i in keep), tile=tiles.tile[keep], angles_deg=tiles.angles_deg[keep],
        light_distance_m=tiles.light_distance_m[keep], angle_cov_deg2=tiles.angle_cov_deg2[keep],
        direction_cov=tiles.direction_cov[keep],
    )  # fmt: skip


def _empty() -> TileGeometry:
    z = np.zeros((0, 4))
    return TileGeometry((0, 0, 0, 0), (), np.zeros(0, dtype=np.int64), z, np.zeros(0), np.zeros((0, 4, 4)),
                        np.zeros((0, 4, 4)), 0)  # fmt: skip


def _unit(v: FloatArray) -> FloatArray:
    out: FloatArray = v / np.linalg.norm(v)
    return out


def _degrees(v: FloatArray) -> tuple[float, float]:
    """Zenith and azimuth (deg) of a unit vector; azimuth 0 at the pole, as the kinematics' angles."""
    s = math.hypot(float(v[0]), float(v[1]))
    theta = math.degrees(math.atan2(s, float(v[2])))
    return theta, (0.0 if s < 1e-12 else math.degrees(math.atan2(float(v[1]), float(v[0]))))


def _unit_rows(v: FloatArray) -> FloatArray:
    out: FloatArray = v / np.linalg.norm(v, axis=-1, keepdims=True)
    return out


def _degrees_rows(v: FloatArray) -> FloatArray:
    """Zenith and azimuth (N, 2) in deg of unit vectors (N, 3), as ``_degrees`` of each."""
    s = np.hypot(v[:, 0], v[:, 1])
    theta = np.degrees(np.arctan2(s, v[:, 2]))
    phi = np.where(s < 1e-12, 0.0, np.degrees(np.arctan2(v[:, 1], v[:, 0])))
    return np.stack([theta, phi], axis=-1)
