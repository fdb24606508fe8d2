"""A reading's direction covariances: the same numbers whether or not the caller passes the directions it has."""

from __future__ import annotations

import numpy as np

from rig.instrument.alignment import Alignment, aligned_forward
from rig.instrument.direction_uncertainty import direction_covariances
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Joints


def test_passing_the_measured_directions_changes_no_number_and_no_uncertainty_gives_zeros() -> None:
    g = RigGeometry()
    alignment = Alignment(light_zero_deg=0.3, tilt_zero_deg=-0.2)
    joints = Joints.from_dict({n: 12.0 + 7.0 * i for i, n in enumerate(g.joint_names)})
    measured = aligned_forward(g, joints, alignment)
    variance = {"light": 1e-4, "camera": 4e-4, "tilt": 0.0}
    plain = direction_covariances(g, joints, alignment, variance)
    given = direction_covariances(g, joints, alignment, variance, measured=measured)
    for a, b in zip(plain, given, strict=True):
        assert np.array_equal(a, b)
    assert plain[0][0, 0] > 0 and np.all(np.linalg.eigvalsh(plain[1]) > -1e-18)
    # Nothing uncertain (a simulated rig without encoder counts, nothing moved, no calibration): zeros.
    still = direction_covariances(g, joints, alignment, {"light": 0.0}, measured=measured)
    assert all(np.array_equal(c, np.zeros((4, 4))) for c in still)
