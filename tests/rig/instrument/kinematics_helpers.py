"""Strategies, tolerances and comparisons the kinematics tests share."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import strategies as st

from model.geometry import degrees_to_vector
from rig.instrument.kinematics import Joints, Reason, Unreachable, forward, inverse

#: A beam so narrow that the spot never limits reach below the default 85 deg maximum zenith.
PENCIL = 0.01


theta = st.floats(0.0, 85.0)


phi = st.floats(-360.0, 720.0)


def angle_between(a, b):
    """Angle in degrees between vectors, accurate for tiny angles."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1)))


def wrap(deg):
    return (np.asarray(deg) + 180.0) % 360.0 - 180.0


def separation(ti, pi, to, po):
    """Angle between the two directions, independently of the module under test (law of cosines on a sphere)."""
    ti, pi, to, po = map(math.radians, (ti, pi, to, po))
    c = math.cos(ti) * math.cos(to) + math.sin(ti) * math.sin(to) * math.cos(pi - po)
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def assert_round_trip(geometry, joints, ti, pi, to, po, tol=1e-9):
    d = forward(geometry, joints)
    assert angle_between(d.wi, degrees_to_vector(ti, pi)) < tol
    assert angle_between(d.wo, degrees_to_vector(to, po)) < tol
    assert abs(d.theta_i - ti) < tol and abs(d.theta_o - to) < tol
    # phi is undefined at the pole and ill-conditioned next to it: an error e on the sphere moves phi by
    # e / sin(theta), so compare phi as the arc along its parallel, and only where it carries digits (at
    # theta = 1e-4 deg a 1e-16 rounding of the vector is a 4e-9 deg error in phi).
    if math.sin(math.radians(ti)) > 1e-6:
        assert abs(wrap(d.phi_i - pi)) * math.sin(math.radians(ti)) < tol
    if math.sin(math.radians(to)) > 1e-6:
        assert abs(wrap(d.phi_o - po)) * math.sin(math.radians(to)) < tol


def joints_if_separated(geometry, ti, pi, to, po):
    """``inverse``'s joints for the directions, checked to be Joints; None where the directions are closer than
    the rig's minimum separation (checked to be refused for it) or within 1e-6 deg of it (rounding decides)."""
    sol = inverse(geometry, ti, pi, to, po)
    sep = separation(ti, pi, to, po)
    if abs(sep - geometry.min_separation_deg) < 1e-6:
        return None
    if sep < geometry.min_separation_deg:
        assert isinstance(sol, Unreachable) and sol.reason is Reason.MIN_SEPARATION
        return None
    assert isinstance(sol, Joints), sol
    return sol
