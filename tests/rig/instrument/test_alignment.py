"""A rig as it is built (rig/instrument/alignment.py): zero offsets, a wedge under the sample, an off-centre sample."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from model.geometry import degrees_to_vector
from rig.instrument.alignment import Alignment, aligned_forward, aligned_inverse, aligned_pose, viewed_point
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Joints, forward, inverse, require, world_pose

LAYOUTS = ("four_axis", "in_plane", "fixed_camera")
angle = st.floats(-80.0, 80.0)
small = st.floats(-1.0, 1.0)


def _angle(u: np.ndarray, v: np.ndarray) -> float:
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v)), np.dot(u, v))))


def _joints(geometry: RigGeometry, values: tuple[float, ...]) -> Joints:
    return Joints.from_dict(dict(zip(geometry.joint_names, values, strict=False)))


@given(st.sampled_from(LAYOUTS), st.tuples(angle, angle, angle, angle))
def test_a_perfect_rig_is_the_drawn_kinematics_exactly(layout: str, values: tuple[float, ...]) -> None:
    g = RigGeometry(layout=layout)  # type: ignore[arg-type]
    j = _joints(g, values)
    a, b = forward(g, j), aligned_forward(g, j, Alignment())
    np.testing.assert_array_equal(a.wi, b.wi)
    np.testing.assert_array_equal(a.wo, b.wo)
    pose, drawn = aligned_pose(g, j, Alignment()), world_pose(g, j)
    for field in ("sample_normal", "sample_tangent", "sample_bitangent", "light_position_m", "camera_position_m"):
        np.testing.assert_array_equal(getattr(pose, field), getattr(drawn, field))


JOINTS = st.sampled_from(("light", "camera", "tilt", "roll"))


@given(JOINTS, st.floats(-2.0, 2.0), st.tuples(angle, angle, angle, angle))
def test_a_zero_offset_means_the_joint_stands_at_reported_minus_zero(joint: str, zero: float, values: tuple) -> None:
    g = RigGeometry()
    j = _joints(g, values)
    shifted = Joints.from_dict({**j.as_dict(), joint: j.as_dict()[joint] - zero})
    got = aligned_forward(g, j, Alignment(**{f"{joint}_zero_deg": zero}))
    want = forward(g, shifted)
    np.testing.assert_allclose(got.wi, want.wi, atol=1e-14)
    np.testing.assert_allclose(got.wo, want.wo, atol=1e-14)


@given(st.floats(0.0, 2.0), st.floats(-180.0, 180.0), st.tuples(angle, angle, angle, angle))
def test_the_wedge_tips_the_normal_by_its_angle_towards_its_azimuth(tau: float, psi: float, values: tuple) -> None:
    g = RigGeometry()
    j = _joints(g, values)
    drawn, real = world_pose(g, j), aligned_pose(g, j, Alignment(sample_tilt_deg=tau, sample_tilt_azimuth_deg=psi))
    assert _angle(drawn.sample_normal, real.sample_normal) == pytest.approx(tau, abs=1e-9)
    if tau > 1e-3:  # the tip points along the stage's local direction at azimuth psi
        tip = real.sample_normal - math.cos(math.radians(tau)) * drawn.sample_normal
        want = math.cos(math.radians(psi)) * drawn.sample_tangent + math.sin(math.radians(psi)) * drawn.sample_bitangent
        assert _angle(tip, want) < 1e-6
    for axis in ("sample_normal", "sample_tangent", "sample_bitangent"):
        assert np.linalg.norm(getattr(real, axis)) == pytest.approx(1.0)
    assert abs(np.dot(real.sample_normal, real.sample_tangent)) < 1e-12


@given(st.tuples(st.floats(-3, 3), st.floats(-3, 3), st.floats(-3, 3)), st.tuples(angle, angle, angle, angle))
def test_the_viewed_point_is_on_the_sample_plane_and_on_the_cameras_axis(offset: tuple, values: tuple) -> None:
    g = RigGeometry()
    j = _joints(g, (values[0], values[1], values[2] / 2, values[3]))
    pose = aligned_pose(g, j, Alignment(sample_offset_mm=offset))
    p = viewed_point(pose)
    n, c = pose.sample_normal, pose.camera_position_m
    if abs(np.dot(n, c)) / np.linalg.norm(c) > 0.1:  # not grazing
        assert abs(np.dot(p - pose.sample_centre_m, n)) < 1e-12
        assert np.linalg.norm(np.cross(p, c)) < 1e-12  # on the line through the camera and the arms' axis
    assert np.linalg.norm(pose.sample_centre_m) == pytest.approx(np.linalg.norm(offset) * 1e-3)


def test_an_offset_along_the_normal_moves_the_directions_by_the_parallax() -> None:
    g = RigGeometry()
    j = require(inverse(g, 30.0, 0.0, 30.0, 180.0))
    d = aligned_forward(g, j, Alignment(sample_offset_mm=(0.0, 0.0, 2.0)))
    # The viewed point moves 2 mm towards the camera along its ray... and off the light's line by
    # about 2 mm * sin(60 deg) / 0.5 m in angle.
    assert d.theta_i == pytest.approx(30.0 + math.degrees(2e-3 * math.sin(math.radians(60.0)) / 0.5), rel=2e-3)
    assert d.theta_o == pytest.approx(30.0, abs=1e-12)


@given(
    st.tuples(st.floats(0.0, 60.0), st.floats(-180.0, 180.0), st.floats(0.0, 60.0), st.floats(-180.0, 180.0)),
    st.tuples(small, small, small, small, st.floats(0.0, 1.0), st.floats(-180.0, 180.0)),
    st.tuples(st.floats(-2, 2), st.floats(-2, 2), st.floats(-2, 2)),
)
def test_the_inverse_reaches_wanted_directions_on_a_real_rig(target: tuple, zeros: tuple, offset: tuple) -> None:
    g = RigGeometry(min_separation_deg=8.0)
    wi, wo = degrees_to_vector(target[0], target[1]), degrees_to_vector(target[2], target[3])
    if _angle(wi, wo) < 10.0:
        return  # near retroreflection the arms collide: the planner refuses such points anyway
    a = Alignment(*zeros[:4], 0.0, zeros[4], zeros[5], offset)
    joints, miss = aligned_inverse(g, wi, wo, a)
    d = aligned_forward(g, joints, a)
    assert float(miss) < 1e-8
    assert _angle(d.wi, wi) < 1e-8 and _angle(d.wo, wo) < 1e-8


def test_the_inverse_is_vectorised_and_says_what_an_in_plane_rig_cannot_reach() -> None:
    g = RigGeometry(layout="in_plane")
    wi = degrees_to_vector(np.array([20.0, 40.0]), np.array([0.0, 0.0]))
    wo = degrees_to_vector(np.array([30.0, 50.0]), np.array([180.0, 180.0]))
    joints, miss = aligned_inverse(g, wi, wo, Alignment(light_zero_deg=0.5))
    assert np.all(miss < 1e-8) and np.shape(joints.light) == (2,)
    _, miss = aligned_inverse(g, wi, wo, Alignment(sample_tilt_deg=0.5, sample_tilt_azimuth_deg=90.0))
    assert np.all(miss > 0.1)  # a wedge lifts the in-plane directions out of the arms' plane


def test_bad_values_are_named() -> None:
    with pytest.raises(ValueError, match=r"Alignment\.light_zero_deg = nan"):
        Alignment(light_zero_deg=float("nan"))
    with pytest.raises(ValueError, match=r"sample_offset_mm"):
        Alignment(sample_offset_mm=(1.0, 2.0))  # type: ignore[arg-type]
