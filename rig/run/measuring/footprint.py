"""A capture's footprint in tiles, cheaply: how many tiles a pose would give, and where they look.

Image mode's own geometry (``rig.run.measuring.tiles``) traces ``SUBPIXELS``^2 rays through every pixel and
loops over the tiles in Python: right for the one pose being measured, too slow for choosing among thousands
of candidate poses or for deciding a mode. Here the sensor is seen through a stand-in camera of the same field
of view whose pixels are *cells* of s x s tiles (s chosen so the stand-in has at most ``GRID`` cells a side;
s = 1, the tiles themselves, on a small sensor), and ``tile_geometry`` runs on that with one-pixel tiles. Each
cell stands for s^2 tiles at its mean directions. The count it gives is an estimate: a cell on the sample's
edge passes or fails whole, so it is exact only to a few cells (``tests/rig/run/measuring/test_footprint.py``
compares it with image mode's own count); the directions are those of the tiles' centres to a cell's size.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics_types import RigPose
from rig.run.measuring.tiles import ImageSettings, tile_geometry

FloatArray = npt.NDArray[np.float64]

#: Most cells a side of the stand-in sensor: at most GRID^2 rays' worth of work per pose.
GRID = 12


@dataclass(frozen=True)
class Cells:
    """A pose's footprint as D cells: mean angles (D, 4) in degrees and the tiles each stands for (D,)."""

    angles_deg: FloatArray
    tiles: FloatArray

    @property
    def count(self) -> float:
        """The estimated number of tiles (samples) the pose gives."""
        return float(self.tiles.sum())


def cell_side(image: ImageSettings, grid: int = GRID) -> int:
    """Tiles per cell side (s) for a sensor of image.resolution pixels in tiles of image.tile_px."""
    cols, rows = image.resolution[0] // image.tile_px, image.resolution[1] // image.tile_px
    return max(1, math.ceil(max(cols, rows) / grid))


def footprint_cells(geometry: RigGeometry, pose: RigPose, image: ImageSettings, grid: int = GRID) -> Cells:
    """The cells of the sample's footprint at ``pose`` (the rig's pose, metres) for image mode's ``image``."""
    s = cell_side(image, grid)
    cols, rows = image.resolution[0] // image.tile_px, image.resolution[1] // image.tile_px
    coarse = dataclasses.replace(image, tile_px=1, resolution=(max(cols // s, 1), max(rows // s, 1)))
    t = tile_geometry(geometry, pose, coarse)
    return Cells(np.asarray(t.angles_deg, dtype=np.float64).reshape(-1, 4), np.full(t.count, float(s * s)))
