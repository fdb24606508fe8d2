"""What the simulated rig's camera looks at: the rendered ROI window, or the uniform light of a flat-field source.

The rig renders only around its ROI; :func:`roi_patch` turns that render into the :class:`SensorPatch` the
camera exposes (a window of at least ``DNG_MIN_SIDE`` pixels when frames go through DNG files, because
LibRaw refuses smaller ones). :class:`SimulatedFlatSource` stands in for what a camera calibration puts in
front of the lens (an integrating sphere, a diffuser on a lamp), and for the lens cap of its dark frames:
the whole sensor sees one uniform radiance, or nothing. Its level is set from the sensor's hidden truth so
the brightest exposure of a photon-transfer series saturates in ``saturate_s`` seconds.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import numpy as np
import numpy.typing as npt

from acquisition.noise import SensorNoise
from simulator.camera.simulated import DNG_MIN_SIDE, CameraOptics, SensorPatch, window_around

Box = tuple[int, int, int, int]
FlatState = Literal["off", "light", "dark"]

#: The flat-field source's colour (relative R, G, B): a warm lamp behind a diffuser, not a perfect white.
FLAT_COLOUR = (1.0, 0.85, 0.6)


def roi_patch(
    render: Callable[[Box], npt.NDArray[np.float64]], roi: Box, resolution: tuple[int, int], through_dng: bool
) -> SensorPatch:
    """The patch the camera exposes for an ROI box of a (width, height) sensor; ``render(box)`` renders a box."""
    window = window_around(roi, resolution, DNG_MIN_SIDE) if through_dng else roi
    x0, y0 = window[0], window[1]
    inner = (roi[0] - x0, roi[1] - y0, roi[2] - x0, roi[3] - y0)
    box = (window[0], window[1], window[2], window[3])
    return SensorPatch(render(box), origin_xy=(x0, y0), roi=inner, sensor=resolution)


class SimulatedFlatSource:
    """A uniform light over the whole sensor (``illuminate``), a capped lens (``darken``), or neither (``restore``).

    Satisfies ``rig.run.calibrate.FlatSource``; the simulated rig's camera sees it in place of the scene.
    """

    def __init__(self, resolution: tuple[int, int], noise: SensorNoise, optics: CameraOptics,
                 saturate_s: float = 0.05) -> None:  # fmt: skip
        if not saturate_s > 0:
            raise ValueError(f"SimulatedFlatSource.saturate_s = {saturate_s!r}: expected a positive time in seconds")
        self.resolution = resolution
        self.state: FlatState = "off"
        # Radiance (W/(m^2 sr)) of the brightest channel that fills the sensor's range in saturate_s.
        self.radiance_w_m2_sr = noise.saturation_dn() / saturate_s / optics.counts_per_radiance(noise)

    @property
    def description(self) -> str:
        """What the source is."""
        return f"simulated flat-field source, {self.radiance_w_m2_sr:.4g} W/(m^2 sr), colour {FLAT_COLOUR}"

    def illuminate(self) -> None:
        """Uniform light on the whole sensor."""
        self.state = "light"

    def darken(self) -> None:
        """No light on the sensor (the lens capped)."""
        self.state = "dark"

    def restore(self) -> None:
        """The rig's own scene again."""
        self.state = "off"

    def patch(self) -> SensorPatch:
        """The whole sensor's radiance under the source (zero when dark)."""
        w, h = self.resolution
        level = self.radiance_w_m2_sr if self.state == "light" else 0.0
        image = np.empty((h, w, 3))
        image[...] = level * np.asarray(FLAT_COLOUR)
        return SensorPatch(image, origin_xy=(0, 0), roi=None, sensor=self.resolution)
