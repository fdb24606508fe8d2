"""What the simulated sensor hides from the controller beyond its noise: vignetting, pixel response, linearity.

A real camera's frames are not a uniform gain times the scene: the lens passes less light towards the
corners (vignetting), every pixel's sensitivity differs a little (photo-response non-uniformity, PRNU),
and the charge-to-count conversion compresses slightly near full well (non-linearity). The simulator
gives its camera all three, drawn from a seed, so that the calibrations (``gonio calibrate camera``:
photon transfer and flat field) are tested by recovering them, not by reading them back.

- ``vignetting``: the relative loss of light at the sensor's corner; the relative illumination is
  ``1 - vignetting * r^2`` with ``r`` the distance from the sensor centre over the half diagonal.
- ``prnu_rms``: the RMS of each pixel's relative sensitivity about 1 (Gaussian, drawn once from ``seed``).
- ``nonlinearity``: the collected charge ``e`` is read as ``e * (1 - nonlinearity * e / full_well_e)``,
  so the response bends by ``nonlinearity`` at full well and its linearity error grows with the signal.

Maps are defined over the whole sensor (``resolution``, width by height) and sliced at a frame's origin,
so a camera reading out a window (the simulated rig renders only around its ROI) sees the same pixels'
flaws wherever its window lies.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from acquisition.noise import SensorNoise

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class PixelResponse:
    """Vignetting (fraction lost at the corner), PRNU (relative RMS) and non-linearity (fraction at full well)."""

    vignetting: float = 0.0
    prnu_rms: float = 0.0
    nonlinearity: float = 0.0
    seed: int = 0
    _maps: dict[tuple[int, int], FloatArray] = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self) -> None:
        for key, hi in (("vignetting", 0.9), ("prnu_rms", 0.2), ("nonlinearity", 0.2)):
            value = getattr(self, key)
            if not (math.isfinite(value) and 0.0 <= value <= hi):
                raise ValueError(f"PixelResponse.{key} = {value!r}: expected a number in [0, {hi:g}]")

    @property
    def flat(self) -> bool:
        """True when every pixel has the same response (no vignetting, no PRNU)."""
        return self.vignetting == 0.0 and self.prnu_rms == 0.0

    def vignetting_map(self, resolution: tuple[int, int]) -> FloatArray:
        """Relative illumination of each pixel of a (width, height) sensor: (height, width), 1 at the centre."""
        w, h = resolution
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
        cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
        r2 = ((xx - cx) ** 2 + (yy - cy) ** 2) / max(cx**2 + cy**2, 1e-12)
        return 1.0 - self.vignetting * r2

    def gain_map(self, resolution: tuple[int, int]) -> FloatArray:
        """Each pixel's relative response (vignetting times PRNU) over the whole (width, height) sensor."""
        key = (int(resolution[0]), int(resolution[1]))
        cached = self._maps.get(key)
        if cached is None:
            prnu = 1.0 + self.prnu_rms * np.random.default_rng([self.seed, 1288]).standard_normal((key[1], key[0]))
            cached = self.vignetting_map(key) * np.maximum(prnu, 0.0)
            cached.setflags(write=False)
            self._maps[key] = cached
        return cached

    def window(self, resolution: tuple[int, int], origin_xy: tuple[int, int], shape: tuple[int, int]) -> FloatArray:
        """The gain map of a window of ``shape`` (height, width) whose pixel (0, 0) is sensor pixel ``origin_xy``."""
        x0, y0 = origin_xy
        h, w = shape
        full = self.gain_map(resolution)
        if not (0 <= x0 and 0 <= y0 and x0 + w <= full.shape[1] and y0 + h <= full.shape[0]):
            raise ValueError(
                f"window of {w}x{h} pixels at {origin_xy} does not fit a sensor of {resolution[0]}x{resolution[1]}"
            )
        return full[y0 : y0 + h, x0 : x0 + w]

    def compress(self, electrons: FloatArray, noise: SensorNoise) -> FloatArray:
        """Collected charge as the readout sees it: ``e * (1 - nonlinearity * e / full_well_e)``."""
        if self.nonlinearity == 0.0:
            return electrons
        return electrons * (1.0 - self.nonlinearity * electrons / noise.full_well_e)


@dataclass(frozen=True)
class SensorTruth:
    """A simulated sensor as it really is: its noise and range, and its pixels' response."""

    noise: SensorNoise = field(default_factory=SensorNoise)
    response: PixelResponse = field(default_factory=PixelResponse)

    @classmethod
    def random(cls, seed: int) -> SensorTruth:
        """A plausible scientific or machine-vision sensor drawn from ``seed`` (for recovery tests and benches)."""
        g = np.random.default_rng([seed, 1288])
        bits = int(g.choice([12, 14, 16]))
        e_per_dn = float(np.exp(g.uniform(np.log(0.5), np.log(8.0))))
        white = float(2**bits - 1)
        black = float(round(g.uniform(0.01, 0.06) * white))
        # Full well between half and twice the ADC's range in electrons, so either may clip first.
        full_well = float((white - black) * e_per_dn * g.uniform(0.5, 2.0))
        # Read noise of 0.7 to 4 counts: below about half a count quantisation is no longer the 1/12 count^2
        # a noise model may add, and no real camera is built that way.
        noise = SensorNoise(
            e_per_dn=e_per_dn, read_noise_e=float(g.uniform(0.7, 4.0) * e_per_dn),
            dark_current_e_per_s=float(np.exp(g.uniform(np.log(0.05), np.log(50.0)))),
            black_level_dn=black, white_level_dn=white, full_well_e=full_well,
        )  # fmt: skip
        response = PixelResponse(vignetting=float(g.uniform(0.0, 0.4)), prnu_rms=float(g.uniform(0.0, 0.02)),
                                 nonlinearity=float(g.uniform(0.0, 0.02)), seed=seed)  # fmt: skip
        return cls(noise, response)
