"""From photons on a sensor to a calibrated reading.

Frames and the camera interface (frame.py), camera backends (cameras/), image files (files/), exposure
planning (exposure/), the HDR merge (hdr/), the sensor's noise (noise.py), ROI reduction (roi.py) and
calibration against a reference target (calibration.py). Imports model only.
"""

import model.runtime  # noqa: F401 (the thread pools' policy, before the HDR merge's numba pool starts)
