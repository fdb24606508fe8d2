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


def test_other_directions_get_their_own_covariances_from_the_same_propagation() -> None:
    # Directions given per item (an image's tiles: here the pose's own, and the pose's a joint further on) come
    # back with one covariance each, the one the pose's own directions at those joints would get.
    g = RigGeometry()
    alignment = Alignment(light_zero_deg=0.3)
    joints = Joints.from_dict({n: 12.0 + 7.0 * i for i, n in enumerate(g.joint_names)})
    variance = {"camera": 4e-4, "tilt": 1e-4}

    def shifted(j: Joints) -> Joints:
        return Joints.from_dict({**j.as_dict(), "camera": float(j.as_dict()["camera"]) + 5.0})

    def features(j: Joints, a: Alignment) -> tuple[np.ndarray, np.ndarray]:
        both = [aligned_forward(g, x, a) for x in (j, shifted(j))]
        angles = np.array([[d.theta_i, d.phi_i, d.theta_o, d.phi_o] for d in both], dtype=float)
        return angles, np.array([[d.wi[0], d.wi[1], d.wo[0], d.wo[1]] for d in both], dtype=float)

    cov_a, cov_t = direction_covariances(g, joints, alignment, variance, features=features)
    assert cov_a.shape == cov_t.shape == (2, 4, 4)
    for k, at in enumerate((joints, shifted(joints))):
        own_a, own_t = direction_covariances(g, at, alignment, variance)
        assert np.allclose(cov_a[k], own_a, rtol=1e-9, atol=1e-15) and np.allclose(cov_t[k], own_t, atol=1e-15)
    # The two directions move differently with the joints.
    assert not np.allclose(cov_t[0], cov_t[1], rtol=1e-2, atol=0.0)
