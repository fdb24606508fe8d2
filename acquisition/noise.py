"""The noise of a linear sensor, in the camera's own units: what the HDR merge and the exposure planner assume.

A pixel that collects ``N`` photo-electrons reports ``black + N / e_per_dn`` counts plus noise; its
variance in counts^2 is shot noise ``N / e_per_dn^2``, read noise ``(read_noise_e / e_per_dn)^2``, dark
current shot noise ``dark_e_per_s * t / e_per_dn^2`` and quantisation ``1/12``. The simulator's sensor
model uses the same parameters to generate frames, so the planner and the merge are tested against the
model they assume, and the real camera's figures come from a calibration (photon transfer) run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True)
class SensorNoise:
    """Noise and range of a linear sensor.

    Parameters
    ----------
    e_per_dn:
        Conversion gain in electrons per count (digital number) at gain 1.
    read_noise_e:
        Read noise in electrons RMS per frame.
    dark_current_e_per_s:
        Dark current in electrons per second per pixel.
    black_level_dn:
        Count reported for zero light.
    white_level_dn:
        Highest count the ADC delivers.
    full_well_e:
        Electrons at which the pixel saturates (may clip before the ADC does).
    """

    e_per_dn: float = 4.0
    read_noise_e: float = 3.0
    dark_current_e_per_s: float = 0.5
    black_level_dn: float = 512.0
    white_level_dn: float = 16383.0
    full_well_e: float = 60000.0

    def __post_init__(self) -> None:
        for key in ("e_per_dn", "full_well_e", "white_level_dn"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"SensorNoise.{key} = {value!r}: expected a positive finite number")
        for key in ("read_noise_e", "dark_current_e_per_s", "black_level_dn"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"SensorNoise.{key} = {value!r}: expected a finite number >= 0")
        if not self.black_level_dn < self.white_level_dn:
            raise ValueError(
                f"SensorNoise: black_level_dn {self.black_level_dn!r} must be below white_level_dn "
                f"{self.white_level_dn!r}"
            )

    def saturation_dn(self, gain: float = 1.0) -> float:
        """Highest usable count above black (counts) at ``gain``: full well or ADC range, whichever is lower."""
        return min(self.white_level_dn - self.black_level_dn, self.full_well_e * gain / self.e_per_dn)

    def variance_dn2(
        self, signal_dn: npt.ArrayLike, exposure_s: float, gain: float = 1.0
    ) -> npt.NDArray[np.float64]:
        """Variance in counts^2 of a reading with ``signal_dn`` photo-signal counts above black.

        Pass the photo-signal only: the dark current's shot noise over ``exposure_s`` is added here.
        """
        s = np.maximum(np.asarray(signal_dn, dtype=np.float64), 0.0)
        g = self.e_per_dn / gain  # electrons per count at this gain
        dark_e = self.dark_current_e_per_s * exposure_s
        return s / g + (self.read_noise_e**2 + dark_e) / g**2 + 1.0 / 12.0

    def snr(self, rate_dn_per_s: npt.ArrayLike, exposure_s: float, gain: float = 1.0) -> npt.NDArray[np.float64]:
        """Single-frame signal-to-noise ratio of a pixel receiving ``rate_dn_per_s`` counts per second."""
        signal = np.asarray(rate_dn_per_s, dtype=np.float64) * exposure_s
        return signal / np.sqrt(self.variance_dn2(signal, exposure_s, gain))
