"""Image mode's capture of one point: the whole sample's footprint read, and every k x k tile on it a sample.

The tiles that see the sample (``rig.run.measuring.tiles``) give the sensor window to read: the camera
delivers whole frames for the point (the simulated camera is asked for them; a real camera delivers them
anyway) and each frame is cut to that window before the merge, so the merge and the exposure plan see the
footprint and nothing else. The exposure is planned as a point's (``rig.run.measuring.measure``: the
brightest pixel of the window not clipped in the bracket's shortest frames, the merge flagging what still
clips), with the SNR goal raised so that a tile of the window's mean level reaches ``target_snr``: the goal
is each tile's, not the window's.

Each tile's reading is the mean of its pixels with the standard error propagated from the merge's
per-pixel variances (``error_model="propagated"``: the BRDF's change across a tile is no noise, its
directions' footprint covariance carries it). A tile with pixels saturated in every frame keeps their
clipped values and is a lower bound (``on_flagged="lower_bound"``), as a point reading with clipped pixels
would be in the table. The tiles go into the point's journal record as one table of columns
(``TILE_KEYS``), which ``rig.run.tables.samples`` expands into one row per tile.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from acquisition.cfa import reduce_mosaic_roi
from acquisition.frame import Camera, ExposureSettings, Frame
from acquisition.hdr.merge import HdrFlag, HdrImage
from acquisition.roi import RoiReading, channel_list, reduce_roi
from model.errors import InputError
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics_types import RigPose
from rig.run.measuring.measure import CaptureSettings, Level, Reading, level_of
from rig.run.measuring.tiles import Box, TileGeometry, tile_geometry, tiles_within

#: The columns of a point record's ``tiles`` table (each a list, one entry per tile).
TILE_KEYS = ("tile", "theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg", "light_distance_m", "reading",
             "reading_std_error", "lower_bound", "dark", "n_pixels", "angle_cov_deg2", "direction_cov")  # fmt: skip
#: The window-mean SNR goal is capped here (the sweep file's own bound on ``target_snr``).
MAX_WINDOW_SNR = 1e5


class ImageModeError(InputError, ValueError):
    """Image mode cannot read this camera's frames as tiles (a frame not covering the window, a raw odd tile)."""


class WindowCamera:
    """A camera whose frames (and dark frames) are cut to a sensor window (x0, y0, x1, y1) in pixels."""

    def __init__(self, camera: Camera, window: Box) -> None:
        self._camera = camera
        self.window = window

    @property
    def identity(self) -> str:
        """The camera's identity."""
        return self._camera.identity

    def set_exposure(self, exposure_s: float, gain: float | None = None) -> ExposureSettings:
        """Pass through (seconds)."""
        return self._camera.set_exposure(exposure_s, gain)

    def capture(self) -> Frame:
        """One frame, cut to the window."""
        return self._cut(self._camera.capture())

    def __getattr__(self, name: str) -> Any:
        # capture_dark exists only where the wrapped camera has one (measure asks with getattr).
        if name == "capture_dark":
            take = self._camera.capture_dark  # type: ignore[attr-defined]
            return lambda: self._cut(take())
        raise AttributeError(name)

    def close(self) -> None:
        """Nothing to close: the wrapped camera is the runner's."""

    def _cut(self, frame: Frame) -> Frame:
        x0, y0, x1, y1 = self.window
        ox, oy = frame.origin_xy
        h, w = frame.data.shape[:2]
        if not (ox <= x0 and oy <= y0 and x1 <= ox + w and y1 <= oy + h):
            raise ImageModeError(
                f"{self.identity}: image mode reads the sensor window {self.window} but the camera delivered a "
                f"{w}x{h} frame at {frame.origin_xy}: is [camera] resolution the sensor's size?"
            )
        data = frame.data[y0 - oy : y1 - oy, x0 - ox : x1 - ox]
        return dataclasses.replace(frame, data=data, origin_xy=(x0, y0))


@contextlib.contextmanager
def whole_frames(camera: Camera) -> Iterator[None]:
    """Within the block a camera that can deliver either (the simulated one) delivers whole frames."""
    inner = getattr(camera, "wrapped", camera)
    if not hasattr(inner, "full_frame"):
        yield
        return
    inner.full_frame = True
    try:
        yield
    finally:
        inner.full_frame = False


@dataclass(frozen=True)
class ImageShot:
    """One point's image capture: its tiles, the windowed camera, and the settings the reading is taken with."""

    tiles: TileGeometry
    camera: WindowCamera
    capture: CaptureSettings
    #: Sensor pixel of the window's (0, 0) (even, so a mosaic keeps its colour phase).
    origin_xy: tuple[int, int]

    def frame_boxes(self) -> list[Box]:
        """Each tile's pixel box in the frames read (the window's coordinates)."""
        wx, wy = self.tiles.window[0] - self.origin_xy[0], self.tiles.window[1] - self.origin_xy[1]
        return [(b[0] + wx, b[1] + wy, b[2] + wx, b[3] + wy) for b in self.tiles.boxes]

    def record(self, reading: Reading) -> dict[str, Any]:
        """The journal's ``tiles`` table (``TILE_KEYS``) of this reading, and the count left out at grazing."""
        hdr = reading.hdr
        boxes = self.frame_boxes()
        raw = hdr.metadata.get("kind") == "raw" and isinstance(hdr.metadata.get("cfa_pattern"), str)
        if raw and any(b[0] % 2 or b[1] % 2 or (b[2] - b[0]) % 2 for b in boxes):
            raise ImageModeError("image mode on a raw (mosaic) camera needs an even tile_px: a tile must hold "
                                 "whole 2x2 colour cells")  # fmt: skip
        readings = [tile_reading(hdr, b) for b in boxes]
        t = self.tiles
        columns: dict[str, Any] = {
            "tile": t.tile.tolist(),
            "theta_i_deg": _rounded(t.angles_deg[:, 0]), "phi_i_deg": _rounded(t.angles_deg[:, 1]),
            "theta_o_deg": _rounded(t.angles_deg[:, 2]), "phi_o_deg": _rounded(t.angles_deg[:, 3]),
            "light_distance_m": _rounded(t.light_distance_m),
            "reading": [channel_list(r.mean) for r in readings],
            "reading_std_error": [channel_list(r.std_error) for r in readings],
            "lower_bound": [bool(r.lower_bound) for r in readings],
            "dark": [bool(r.dark) for r in readings],
            "n_pixels": [int(r.n_pixels) for r in readings],
            "angle_cov_deg2": np.round(t.angle_cov_deg2.reshape(-1, 16), 12).tolist(),
            "direction_cov": np.round(t.direction_cov.reshape(-1, 16), 15).tolist(),
        }  # fmt: skip
        return {"tiles": columns, "tile_px": self.tile_px, "tiles_grazing": t.grazing}

    def brightest_level(self, reading: Reading) -> Level:
        """The level (counts/s) of the tile holding the brightest pixel: a scan plans its next frame from it."""
        levels = [level_of(reading.hdr, b) for b in self.frame_boxes()]
        return max(levels, key=lambda lv: lv.peak) if levels else reading.level

    def seen_from(self, geometry: RigGeometry, pose: RigPose) -> ImageShot:
        """The same frames' tiles seen from ``pose`` (a scan's mid-exposure): those lying in the window read."""
        assert self.capture.image is not None
        tiles = tile_geometry(geometry, pose, self.capture.image)
        return dataclasses.replace(self, tiles=tiles_within(tiles, self.camera.window))

    @property
    def tile_px(self) -> int:
        """The tile side in pixels."""
        assert self.capture.image is not None
        return self.capture.image.tile_px


def _rounded(a: np.ndarray) -> list[float]:
    return [float(v) + 0.0 for v in np.round(np.asarray(a, dtype=np.float64), 9)]


def plan_shot(camera: Camera, capture: CaptureSettings, geometry: RigGeometry, pose: RigPose,
              margin_px: int = 0) -> ImageShot | None:  # fmt: skip
    """The image capture of the pose ``pose`` (the calibrated rig's), or None where no tile sees the sample.

    ``margin_px``: pixels read beyond the tiles on every side (a scan's frame is seen from a pose near ``pose``).
    """
    image = capture.image
    if image is None:
        raise ValueError("plan_shot needs CaptureSettings.image (image mode)")
    tiles = tile_geometry(geometry, pose, image)
    if tiles.count == 0:
        return None
    x0, y0, x1, y1 = tiles.window
    w, h = image.resolution
    x0, y0, x1, y1 = max(x0 - margin_px, 0), max(y0 - margin_px, 0), x1 + margin_px, y1 + margin_px
    window = (x0 - x0 % 2, y0 - y0 % 2, min(x1 + x1 % 2, w), min(y1 + y1 % 2, h))
    # The goal is each tile's: a tile at the window's mean level has 1/n of its pixels, 1/sqrt(n) of its SNR.
    n = (window[2] - window[0]) * (window[3] - window[1]) / image.tile_px**2
    goal = min(capture.target_snr * math.sqrt(max(n, 1.0)), MAX_WINDOW_SNR)
    settings = dataclasses.replace(capture, roi=None, target_snr=goal)
    return ImageShot(tiles, WindowCamera(camera, window), settings, (window[0], window[1]))


_SATURATED = int(HdrFlag.SATURATED)
_DARK = int(HdrFlag.DARK | HdrFlag.BELOW_BLACK)


def tile_reading(hdr: HdrImage, box: Box) -> RoiReading:
    """One tile's reading (counts/s): the mean of its pixels, its error propagated from their variances."""
    pattern = hdr.metadata.get("cfa_pattern")
    saturated, dark = (hdr.flags & _SATURATED) != 0, (hdr.flags & _DARK) != 0
    if hdr.metadata.get("kind") == "raw" and isinstance(pattern, str):
        return reduce_mosaic_roi(hdr.radiance, hdr.variance, box, pattern, flags=saturated, on_flagged="lower_bound",
                                 error_model="propagated", dark=dark)  # fmt: skip
    return reduce_roi(hdr.radiance, hdr.variance, box, flags=saturated, on_flagged="lower_bound",
                      error_model="propagated", dark=dark)  # fmt: skip
