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

The same propagation serves any directions that follow from the joints, not only the pose's: ``features`` gives
them for a joint set (image mode's tiles, each with its own directions: ``rig.run.measuring.tiles``), as arrays
(..., 4) whose covariances come back (..., 4, 4).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np
import numpy.typing as npt

from rig.instrument.alignment import Alignment, aligned_forward, alignment_of, parameters_of
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Joints
from rig.instrument.kinematics_types import Angle, Directions

FloatArray = npt.NDArray[np.float64]
#: Directions that follow from joints (deg) and an alignment: (angles (..., 4) in deg, tangent components (..., 4)).
Features = Callable[[Joints, Alignment], tuple[FloatArray, FloatArray]]


def _features(
    geometry: RigGeometry, joints: Joints, alignment: Alignment, measured: Directions | None = None
) -> tuple[FloatArray, FloatArray]:
    d = measured if measured is not None else aligned_forward(geometry, joints, alignment)
    angles = np.array([d.theta_i, d.phi_i, d.theta_o, d.phi_o], dtype=np.float64)
    tangent = np.array([d.wi[0], d.wi[1], d.wo[0], d.wo[1]], dtype=np.float64)
    return angles, tangent


def travel_variance_deg2(before: Mapping[str, Angle], after: Mapping[str, float]) -> dict[str, float]:
    """Per joint, the variance (deg^2) of uniform motion from ``before`` to ``after`` (deg): the travel^2 / 12."""
    out = {}
    for name, value in before.items():
        moved = float(after.get(name, value)) - float(value)
        out[name] = moved * moved / 12.0
    return out


def _unwrap(delta: FloatArray) -> FloatArray:
    out = delta.copy()
    out[..., [1, 3]] = (out[..., [1, 3]] + 180.0) % 360.0 - 180.0
    return out


def _angle_slope(base: FloatArray, plus: FloatArray, minus: FloatArray, h: float) -> FloatArray:
    """Central differences of the angles; at a pole (theta ~ 0, where theta = |...| has a kink) the slope's size."""
    out = _unwrap(plus - minus) / (2 * h)
    for k in (0, 2):
        pole = base[..., k] < 1e3 * h
        if np.any(pole):
            size = np.maximum(np.abs(plus[..., k] - base[..., k]), np.abs(minus[..., k] - base[..., k])) / h
            out[..., k] = np.where(pole, size, out[..., k])
    return out


def _propagated(jacobians: list[FloatArray], cov: FloatArray) -> FloatArray:
    """J cov J^T for slopes (..., 4) per parameter, a covariance (4, 4) per leading index (deg^2 or unitless)."""
    j = np.moveaxis(np.array(jacobians), 0, -1)
    out: FloatArray = j @ cov @ np.swapaxes(j, -1, -2)
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
    features: Features | None = None,
) -> tuple[FloatArray, FloatArray]:
    """(angle covariance deg^2, tangent covariance) of one pose's measured directions, (4, 4) each.

    ``measured``: ``aligned_forward`` of these joints where the caller has it already (the runner does).
    ``features``: other directions to carry the errors to (see the module docstring); covariances (..., 4, 4).
    """
    values = {k: float(v) for k, v in joints.as_dict().items()}
    names = tuple(calibration_names)
    moving = [(n, v) for n, v in joint_variance_deg2.items() if n in values and v > 0]

    def of(j: Joints, a: Alignment) -> tuple[FloatArray, FloatArray]:
        return _features(geometry, j, a) if features is None else features(j, a)

    uncertain = bool(moving) or bool(names and calibration_covariance is not None)
    if not uncertain and features is None:
        return np.zeros((4, 4)), np.zeros((4, 4))  # nothing uncertain: no slope to take
    base = _features(geometry, joints, alignment, measured)[0] if features is None else features(joints, alignment)[0]
    zero = np.zeros((*base.shape[:-1], 4, 4))
    if not uncertain:
        return zero, zero.copy()
    jac_a, jac_t, variances = [], [], []
    for name, var in moving:
        cols = []
        for sign in (1.0, -1.0):
            moved = Joints.from_dict({**values, name: values[name] + sign * step_deg})
            cols.append(of(moved, alignment))
        jac_a.append(_angle_slope(base, cols[0][0], cols[1][0], step_deg))
        jac_t.append((cols[0][1] - cols[1][1]) / (2 * step_deg))
        variances.append(var)
    cov_a, cov_t = zero, zero.copy()
    if variances:
        v = np.diag(variances)
        cov_a, cov_t = _propagated(jac_a, v), _propagated(jac_t, v)
    if names and calibration_covariance is not None:
        cov_p = np.asarray(calibration_covariance, dtype=np.float64)
        p0 = parameters_of(names, alignment)
        ja_p, jt_p = [], []
        for k in range(len(names)):
            h = 1e-4
            plus = of(joints, alignment_of(names, p0 + h * np.eye(len(names))[k]))
            minus = of(joints, alignment_of(names, p0 - h * np.eye(len(names))[k]))
            ja_p.append(_angle_slope(base, plus[0], minus[0], h))
            jt_p.append((plus[1] - minus[1]) / (2 * h))
        cov_a, cov_t = cov_a + _propagated(ja_p, cov_p), cov_t + _propagated(jt_p, cov_p)
    return cov_a, cov_t
