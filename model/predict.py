"""The reading the camera should see: model, light and geometry to reflected radiance.

This is what the acquisition planner and the simulator compare against: for a point or spot source
of intensity I at distance d, the sample radiance towards the camera is L = f_r(wi, wo) I cos_i / d^2.
The camera's distance does not enter (radiance is invariant along a ray); the detector's solid angle
and pixel area turn L into a pixel signal in the acquisition module.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from model.base import BRDF
from model.geometry import degrees_to_vector
from model.radiometry import PointLight

Array = npt.NDArray[np.floating]


def predict_radiance(
    model: BRDF, wi: npt.ArrayLike, wo: npt.ArrayLike, light: PointLight, off_axis: npt.ArrayLike = 0.0
) -> Array:
    """Radiance in W/(m^2 sr) towards wo from a sample lit from wi (local unit vectors, (..., 3))."""
    w_i = np.asarray(wi, dtype=float)
    f = np.asarray(model.eval(w_i, wo), dtype=float)
    e = light.irradiance(w_i[..., 2], off_axis)
    if f.ndim > e.ndim:
        e = e[..., None]
    elif e.ndim > f.ndim:
        f = f[..., None]
    return f * e


def predict_radiance_deg(
    model: BRDF,
    theta_i: npt.ArrayLike,
    phi_i: npt.ArrayLike,
    theta_o: npt.ArrayLike,
    phi_o: npt.ArrayLike,
    light: PointLight,
) -> Array:
    """predict_radiance with BRDF angles in degrees, the convention of sweep files and tables."""
    return predict_radiance(model, degrees_to_vector(theta_i, phi_i), degrees_to_vector(theta_o, phi_o), light)
