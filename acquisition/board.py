"""The reference board: a ChArUco board (opencv-contrib's aruco module) under a glossy clear coat.

The board's printed pattern gives its pose in each camera image (its inner chessboard corners, each
identified by the ArUco markers around it); the coat reflects the lamp as a mirror highlight. A lab
prints it with ``ChArUcoBoard.image`` at the stated size (check the printed square size with a caliper:
the calibration scales with it) and mounts it where the sample goes.

Frames: board coordinates are OpenCV's (metres, origin at the pattern's top-left corner, x to the right,
y down the printed image); on the sample the pattern is centred, its x along the sample's local x (the
tangent) and its y along the local -y, so the printed image reads upright when the sample is seen from
its front with local y up. Pixel coordinates are continuous (pixel centres at i + 0.5), one half pixel
off OpenCV's integer-centred convention, which ``detect`` converts.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from model.errors import InputError

FloatArray = npt.NDArray[np.float64]


class BoardError(InputError, ValueError):
    """The board's specification is impossible, or its image cannot be used."""


@dataclass(frozen=True)
class ChArUcoBoard:
    """A square ChArUco board: ``squares`` x ``squares`` squares of ``square_mm``, markers of ``marker_mm``.

    ``dictionary`` is an OpenCV predefined ArUco dictionary name; ``margin_mm`` the white border printed
    around the pattern (the board's total width is squares * square_mm + 2 margin_mm). ``blank_mm`` is the
    radius of a plain white disc printed over the pattern's centre, where the lamp's mirror highlight
    lands: a marker's bits under the highlight would pull its fitted peak towards the white ones, always
    the same way in the board's frame, which a fit reads as a tilt of the sample.
    """

    squares: int = 7
    square_mm: float = 6.0
    marker_mm: float = 4.5
    dictionary: str = "DICT_4X4_50"
    margin_mm: float = 4.0
    blank_mm: float = 9.0

    def __post_init__(self) -> None:
        if not 3 <= self.squares <= 20:
            raise BoardError(f"ChArUcoBoard.squares = {self.squares!r}: expected 3..20")
        if not 0 < self.marker_mm < self.square_mm:
            raise BoardError(f"ChArUcoBoard.marker_mm = {self.marker_mm!r}: expected 0 < marker < square_mm")
        if self.margin_mm < 0:
            raise BoardError(f"ChArUcoBoard.margin_mm = {self.margin_mm!r}: expected >= 0")
        if not 0 <= self.blank_mm < 0.35 * self.squares * self.square_mm:
            most = 0.35 * self.squares * self.square_mm
            raise BoardError(f"ChArUcoBoard.blank_mm = {self.blank_mm!r}: expected a radius in [0, {most:g}) mm "
                             "(the pattern must keep its rim)")  # fmt: skip

    @property
    def width_mm(self) -> float:
        """The printed board's width (and height) in millimetres, margins included."""
        return self.squares * self.square_mm + 2 * self.margin_mm

    def cv_board(self) -> Any:
        """The OpenCV ``CharucoBoard`` (lengths in metres)."""
        return _cv_board(self.squares, self.square_mm, self.marker_mm, self.dictionary)

    def corners_local_m(self) -> FloatArray:
        """The inner corners in the sample's local frame (m), (N, 3), row k is corner id k."""
        obj = np.asarray(self.cv_board().getChessboardCorners(), dtype=np.float64).reshape(-1, 3)
        half = 0.5 * self.squares * self.square_mm * 1e-3
        return np.stack([obj[:, 0] - half, half - obj[:, 1], np.zeros(len(obj))], axis=-1)

    def image(self, px_per_mm: float) -> npt.NDArray[np.uint8]:
        """The board as printed, margins included: an 8-bit grey image, top row first."""
        side = round(self.squares * self.square_mm * px_per_mm)
        margin = round(self.margin_mm * px_per_mm)
        pattern = self.cv_board().generateImage((side, side), marginSize=0, borderBits=1)
        out = np.full((side + 2 * margin, side + 2 * margin), 255, dtype=np.uint8)
        out[margin : margin + side, margin : margin + side] = pattern
        if self.blank_mm > 0:
            c = 0.5 * (out.shape[0] - 1)
            y, x = np.mgrid[0 : out.shape[0], 0 : out.shape[1]]
            out[np.hypot(x - c, y - c) <= self.blank_mm * px_per_mm] = 255
        return out

    def detect(self, gray: npt.ArrayLike) -> tuple[npt.NDArray[np.int64], FloatArray]:
        """Corner ids (K,) and continuous pixel coordinates (K, 2) found in an 8-bit grey image."""
        import cv2

        img = np.ascontiguousarray(np.asarray(gray, dtype=np.uint8))
        if img.ndim != 2:
            raise BoardError(f"board detection needs a grey image (H, W), got shape {img.shape}")
        corners, ids, _, _ = cv2.aruco.CharucoDetector(self.cv_board()).detectBoard(img)
        if corners is None or ids is None:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 2))
        return ids.reshape(-1).astype(np.int64), corners.reshape(-1, 2).astype(np.float64) + 0.5


@functools.cache
def _cv_board(squares: int, square_mm: float, marker_mm: float, dictionary: str) -> Any:
    import cv2

    name = getattr(cv2.aruco, dictionary, None)
    if not isinstance(name, int):
        raise BoardError(f"ChArUcoBoard.dictionary = {dictionary!r}: not an OpenCV ArUco dictionary (e.g. DICT_4X4_50)")
    d = cv2.aruco.getPredefinedDictionary(name)
    return cv2.aruco.CharucoBoard((squares, squares), square_mm * 1e-3, marker_mm * 1e-3, d)
