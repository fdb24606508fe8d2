"""How well a reading's directions are known: the joints' uncertainty and the calibration's, carried through.

A point's joints are known to the encoder's resolution (a uniform error of one count: variance
count^2 / 12) and to how far they moved while the frames were taken (read back before and after: the
difference as a uniform spread). The rig's geometry is known to the calibration's covariance (its fit
parameters, ``geometry_calibration.json``). Both are carried to the directions by the Jacobian of
``aligned_forward`` (central differences), into two covariances:

- of the BRDF angles (theta_i, phi_i, theta_o, phi_o) in deg^2, for people (phi is ill-defined at the pole,
  and its standard error grows like 1 / sin theta there);
- of the tangent components (wi_x, wi_y, wo_x, wo_y) of the local unit vectors (dimensionless, rad^2 for
  small angles), well defined everywhere above the horizon, which the analysis uses
  (``model.fit.angular``): a direction (x, y) stands for (x, y, sqrt(1 - x^2 - y^2)).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import numpy.typing as npt

from rig.instrument.alignment import Alignment, aligned_forward, alignment_of, parameters_of
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Joints
from rig.instrument.kinematics_types import Directions

FloatArray = npt.NDArray[np.float64]


def _features(
    geometry: RigGeometry, joints: Joints, alignment: Alignment, measured: Directions | None = None
) -> tuple[FloatArray, FloatArray]:
    d = measured if measured is not None else aligned_forward(geometry, joints, alignment)
    angles = np.array([d.theta_i, d.phi_i, d.theta_o, d.phi_o], dtype=np.float64)
    tangent = np.array([d.wi[0], d.wi[1], d.wo[0], d.wo[1]], dtype=np.float64)
    return angles, tangent


def _unwrap(delta: FloatArray) -> FloatArray:
    out = delta.copy()
    out[[1, 3]] = (out[[1, 3]] + 180.0) % 360.0 - 180.0
    return out


def _angle_slope(base: FloatArray, plus: FloatArray, minus: FloatArray, h: float) -> FloatArray:
    """Central differences of the angles; at a pole (theta ~ 0, where theta = |...| has a kink) the slope's size."""
    out = _unwrap(plus - minus) / (2 * h)
    for k in (0, 2):
        if base[k] < 1e3 * h:
            out[k] = max(abs(plus[k] - base[k]), abs(minus[k] - base[k])) / h
    return out


def direction_covariances(
    geometry: RigGeometry,
    joints: Joints,
    alignment: Alignment,
    joint_variance_deg2: Mapping[str, float],
    calibration_names: Sequence[str] = (),
    calibration_covariance: npt.ArrayLike | None = None,
    *,
    step_deg: float = 1e-4,
    measured: Directions | None = None,
) -> tuple[FloatArray, FloatArray]:
    """(angle covariance (4, 4) deg^2, tangent covariance (4, 4)) of one pose's measured directions.

    ``measured``: ``aligned_forward`` of these joints where the caller has it already (the runner does).
    """
    values = {k: float(v) for k, v in joints.as_dict().items()}
    names = tuple(calibration_names)
    moving = [(n, v) for n, v in joint_variance_deg2.items() if n in values and v > 0]
    if not moving and not (names and calibration_covariance is not None):
        return np.zeros((4, 4)), np.zeros((4, 4))  # nothing uncertain: no slope to take
    base = _features(geometry, joints, alignment, measured)[0]
    jac_a, jac_t, variances = [], [], []
    for name, var in moving:
        cols = []
        for sign in (1.0, -1.0):
            moved = Joints.from_dict({**values, name: values[name] + sign * step_deg})
            cols.append(_features(geometry, moved, alignment))
        jac_a.append(_angle_slope(base, cols[0][0], cols[1][0], step_deg))
        jac_t.append((cols[0][1] - cols[1][1]) / (2 * step_deg))
        variances.append(var)
    cov_a, cov_t = np.zeros((4, 4)), np.zeros((4, 4))
    if variances:
        ja, jt, v = np.array(jac_a).T, np.array(jac_t).T, np.diag(variances)
        cov_a, cov_t = ja @ v @ ja.T, jt @ v @ jt.T
    if names and calibration_covariance is not None:
        cov_p = np.asarray(calibration_covariance, dtype=np.float64)
        p0 = parameters_of(names, alignment)
        ja_p, jt_p = [], []
        for k in range(len(names)):
            h = 1e-4
            plus = _features(geometry, joints, alignment_of(names, p0 + h * np.eye(len(names))[k]))
            minus = _features(geometry, joints, alignment_of(names, p0 - h * np.eye(len(names))[k]))
            ja_p.append(_angle_slope(base, plus[0], minus[0], h))
            jt_p.append((plus[1] - minus[1]) / (2 * h))
        ja, jt = np.array(ja_p).T, np.array(jt_p).T
        cov_a, cov_t = cov_a + ja @ cov_p @ ja.T, cov_t + jt @ cov_p @ jt.T
    return cov_a, cov_t
