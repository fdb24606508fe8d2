"""Forward kinematics of one pose in Python floats: ``kinematics.forward``'s numbers to the bit, without numpy.

The runner turns every read-back into directions once a point, where numpy's per-call overhead on 3-vectors is
most of the work. The operations here are numpy's, in numpy's order: products and sums as ``_sample_axes`` and
``_to_local`` do them (numpy's sum of three starts from +0.0 and adds left to right), degrees and radians
as the one multiplication both libraries make, and sin, cos, arctan2 and hypot from numpy on a float (its
SIMD versions may differ from ``math``'s in the last bit: arctan2 and hypot do on an AVX-512 host).
tests/rig/instrument/test_kinematics_scalar.py compares them with the numpy path on random and special poses.
"""

from __future__ import annotations

import math

import numpy as np

from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics_types import Directions, Joints

Vec = tuple[float, float, float]


def _cos(x: float) -> float:
    return float(np.cos(x))


def _sin(x: float) -> float:
    return float(np.sin(x))


def _dot(d: Vec, a: Vec) -> float:
    return 0.0 + d[0] * a[0] + d[1] * a[1] + d[2] * a[2]


def _angles(w: Vec) -> tuple[float, float]:
    """Zenith and azimuth in degrees as ``kinematics._angles`` (azimuth 0 where sin(theta) < 1e-12)."""
    s = float(np.hypot(w[0], w[1]))
    theta = math.degrees(float(np.arctan2(s, w[2])))
    phi = 0.0 if s < 1e-12 else math.degrees(float(np.arctan2(w[1], w[0])))
    return theta, phi


def forward_one(geometry: RigGeometry, joints: Joints) -> Directions | None:
    """The directions (degrees, unit vectors) of one pose of plain float joint angles in degrees; None otherwise.

    None (for numpy's path, which also explains a wrong set of joints) where a joint is not a float or the
    joints are not the layout's.
    """
    values = joints.as_dict()
    if set(values) != set(geometry.joint_names) or any(type(v) is not float for v in values.values()):
        return None
    light = math.radians(values["light"])
    if geometry.layout == "in_plane":
        tilt, roll, yaw = 0.0, math.radians(-geometry.plane_azimuth_deg), 0.0
        camera = math.radians(values["camera"])
    elif geometry.layout == "fixed_camera":
        tilt, roll, yaw = math.radians(values["tilt"]), math.radians(values["roll"]), math.radians(values["yaw"])
        camera = math.radians(float(geometry.camera_azimuth_deg))
    else:
        tilt, roll, yaw = math.radians(values["tilt"]), math.radians(values["roll"]), 0.0
        camera = math.radians(values["camera"])
    ct, st = _cos(tilt), _sin(tilt)
    cr, sr = _cos(roll), _sin(roll)
    cy, sy = _cos(yaw), _sin(yaw)
    zero = 0.0
    axes = []
    for vx, vy, vz in ((-sr * st, cr + zero, sr * ct), (-cr * st, -sr + zero, cr * ct), (ct + zero, zero, st + zero)):
        axes.append((cy * vx - sy * vy, sy * vx + cy * vy, vz + zero))
    x, y, z = axes
    d_light = (_cos(light), _sin(light), 0.0)
    d_camera = (_cos(camera), _sin(camera), 0.0)
    wi = (_dot(d_light, x), _dot(d_light, y), _dot(d_light, z))
    wo = (_dot(d_camera, x), _dot(d_camera, y), _dot(d_camera, z))
    theta_i, phi_i = _angles(wi)
    theta_o, phi_o = _angles(wo)
    return Directions(theta_i, phi_i, theta_o, phi_o, np.array(wi), np.array(wo))
