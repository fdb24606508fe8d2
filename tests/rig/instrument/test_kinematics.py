"""Rig kinematics: round trips on the three layouts, the solution choice, world poses."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from model.geometry import degrees_to_vector
from rig.instrument.geometry import JointLimits, RigGeometry
from rig.instrument.kinematics import (
    Joints,
    Reason,
    Unreachable,
    forward,
    inverse,
    require,
    solve_degrees,
    world_pose,
)
from tests.rig.instrument.kinematics_helpers import (
    PENCIL,
    angle_between,
    assert_round_trip,
    joints_if_separated,
    phi,
    separation,
    theta,
    wrap,
)


@given(theta, phi, theta, phi)
@example(0.0, 0.0, 40.0, 90.0)
@example(0.0, 123.0, 0.0, -45.0)
@example(30.0, 0.0, 30.0, 180.0)
@example(85.0, 10.0, 85.0, 190.0)
@example(20.0, 0.0, 20.0, 20.0)
def test_four_axis_round_trip_wherever_reachable(ti, pi, to, po):
    g = RigGeometry(beam_half_angle_deg=PENCIL)
    sol = joints_if_separated(g, ti, pi, to, po)
    if sol is None:
        return
    assert sol.yaw is None and all(-180.0 <= v <= 180.0 for v in sol.as_dict().values())
    assert_round_trip(g, sol, ti, pi, to, po)


@given(st.floats(-180.0, 180.0), theta, st.booleans(), theta, st.booleans())
@example(0.0, 0.0, False, 0.0, True)
@example(37.0, 60.0, True, 60.0, False)
def test_in_plane_round_trip(psi, ti, i_back, to, same_side):
    g = RigGeometry(layout="in_plane", plane_azimuth_deg=psi, min_separation_deg=0.0, beam_half_angle_deg=PENCIL)
    pi = psi + (180.0 if i_back else 0.0)
    po = pi if same_side else pi + 180.0
    sol = inverse(g, ti, pi, to, po)
    assert isinstance(sol, Joints), sol
    assert set(sol.as_dict()) == {"light", "camera"}
    assert_round_trip(g, sol, ti, pi, to, po)


@given(st.floats(-180.0, 180.0), st.floats(1.0, 85.0), st.floats(1.0, 85.0), st.floats(0.01, 179.99))
def test_in_plane_rejects_every_other_azimuth(psi, ti, to, delta):
    g = RigGeometry(layout="in_plane", plane_azimuth_deg=psi, min_separation_deg=0.0, beam_half_angle_deg=PENCIL)
    # Light in the plane, camera turned off it by delta: coplanar with the normal only at delta = 0 or 180.
    pi = psi
    sol = inverse(g, ti, pi, to, pi + 180.0 + delta)
    assert isinstance(sol, Unreachable) and sol.reason is Reason.OUT_OF_PLANE
    expected = math.degrees(math.asin(math.sin(math.radians(to)) * abs(math.sin(math.radians(delta)))))
    assert sol.value == pytest.approx(expected, abs=1e-9)
    assert "camera direction" in sol.message and "out of the in-plane rig's measurement plane" in sol.message


@given(st.floats(-180.0, 180.0), theta, phi, theta, phi)
@example(20.0, 0.0, 0.0, 40.0, 90.0)
def test_fixed_camera_round_trip(cam, ti, pi, to, po):
    g = RigGeometry(layout="fixed_camera", camera_azimuth_deg=cam, beam_half_angle_deg=PENCIL)
    sol = joints_if_separated(g, ti, pi, to, po)
    if sol is None:
        return
    assert sol.camera is None and set(sol.as_dict()) == {"light", "yaw", "tilt", "roll"}
    assert_round_trip(g, sol, ti, pi, to, po)
    # The camera never moves; it sits clockwise of the light, so the light is the separation counter-clockwise.
    pose = world_pose(g, sol)
    cam_dir = pose.camera_position_m / g.camera_radius_m
    assert np.allclose(cam_dir, [math.cos(math.radians(cam)), math.sin(math.radians(cam)), 0.0], atol=1e-12)
    assert wrap(sol.light - cam) == pytest.approx(separation(ti, pi, to, po), abs=1e-7)


def test_vectorised_solve_matches_scalar_inverse_and_forward():
    g = RigGeometry(layout="four_axis", limits=JointLimits(tilt=(-30.0, 30.0)))
    rng = np.random.default_rng(7)
    ti, to = rng.uniform(0, 89, (2, 6, 5))
    pi, po = rng.uniform(-180, 180, (2, 6, 5))
    sol = solve_degrees(g, ti, pi, to, po)
    assert sol.shape == (6, 5) and sol.joints.light.shape == (6, 5)
    codes = set(sol.reason.ravel())
    assert "" in codes and len(codes) > 2  # a mix of reachable and several failures
    for idx in np.ndindex(6, 5):
        one = inverse(g, ti[idx], pi[idx], to[idx], po[idx])
        if isinstance(one, Unreachable):
            assert sol.reason[idx] == one.reason.value
            assert sol.at(idx) == one
        else:
            assert sol.reason[idx] == ""
            assert one == sol.at(idx)
    ok = sol.reachable
    d = forward(g, Joints(**{k: v[ok] for k, v in sol.joints.as_dict().items()}))
    assert np.all(angle_between(d.wi, degrees_to_vector(ti[ok], pi[ok])) < 1e-9)
    assert np.all(angle_between(d.wo, degrees_to_vector(to[ok], po[ok])) < 1e-9)


def test_documented_rest_solution_for_the_forward_scattering_plane():
    sol = require(inverse(RigGeometry(), 30.0, 0.0, 45.0, 180.0))
    assert (sol.light, sol.camera) == pytest.approx((30.0, -45.0), abs=1e-12)
    assert (sol.tilt, sol.roll) == pytest.approx((0.0, 0.0), abs=1e-12)


@given(theta, phi, theta, phi)
def test_branches_are_mirror_images_and_keep_arm_order(ti, pi, to, po):
    g = RigGeometry(beam_half_angle_deg=PENCIL)
    sep = separation(ti, pi, to, po)
    if sep < g.min_separation_deg + 1e-6:
        return
    cw = require(inverse(g, ti, pi, to, po))
    ccw = require(inverse(g, ti, pi, to, po, branch="camera_ccw"))
    assert inverse(g, ti, pi, to, po) == cw  # deterministic, and camera_cw is the default
    # Seen from above the camera sits clockwise (cw) or counter-clockwise (ccw) of the light, by the separation.
    assert wrap(cw.camera - cw.light) == pytest.approx(-sep, abs=1e-7)
    assert wrap(ccw.camera - ccw.light) == pytest.approx(sep, abs=1e-7)
    assert ccw.tilt == pytest.approx(-cw.tilt, abs=1e-9)
    assert abs(wrap(ccw.roll - cw.roll - 180.0)) < 1e-7
    assert_round_trip(g, ccw, ti, pi, to, po)


def test_solution_is_continuous_along_an_azimuth_sweep():
    wide = JointLimits(light=(-720.0, 720.0), camera=(-720.0, 720.0), roll=(-720.0, 720.0))
    g = RigGeometry(limits=wide)
    phi_o = np.linspace(0.0, 720.0, 2881)  # two turns in 0.25 deg steps
    prev = None
    steps = []
    for po in phi_o:
        sol = require(inverse(g, 40.0, 0.0, 50.0, float(po), near=prev))
        if prev is not None:
            steps.append(max(abs(a - b) for a, b in zip(sol.as_dict().values(), prev.as_dict().values(), strict=True)))
        prev = sol
    assert max(steps) < 1.0
    # Two turns of the camera's azimuth wind the roll two turns, carried past +-180 by `near`.
    assert abs(prev.roll - require(inverse(g, 40.0, 0.0, 50.0, 0.0)).roll) == pytest.approx(720.0, abs=1e-6)


@pytest.mark.parametrize("step", [0.5, 0.1])
def test_without_near_the_sweep_only_jumps_by_whole_turns(step):
    g = RigGeometry()
    sols = [require(inverse(g, 40.0, 0.0, 50.0, float(po))) for po in np.arange(0.0, 360.0 + step / 2, step)]
    joints = np.array([list(s.as_dict().values()) for s in sols])
    jumps = np.abs(wrap(np.diff(joints, axis=0)))
    # Joint speed per degree of phi_o stays bounded (about 3.4 here): a real jump would not shrink with the step.
    assert jumps.max() < 4.0 * step


def test_joint_limits_pick_the_whole_turn_that_fits_and_near_breaks_ties():
    g = RigGeometry(limits=JointLimits(light=(0.0, 360.0), roll=(-540.0, 540.0)))
    sol = require(inverse(g, 30.0, 0.0, 45.0, 120.0))
    base = require(inverse(RigGeometry(), 30.0, 0.0, 45.0, 120.0))
    assert 0.0 <= sol.light <= 360.0 and abs(wrap(sol.light - base.light)) < 1e-12
    assert sol.roll == pytest.approx(base.roll, abs=1e-12)
    near = Joints(light=0.0, camera=0.0, tilt=0.0, roll=base.roll + 350.0)
    shifted = require(inverse(g, 30.0, 0.0, 45.0, 120.0, near=near))
    assert shifted.roll == pytest.approx(base.roll + 360.0, abs=1e-9)
    assert_round_trip(g, shifted, 30.0, 0.0, 45.0, 120.0)


def test_retroreflection_without_minimum_separation_has_tilt_zero():
    g = RigGeometry(min_separation_deg=0.0, beam_half_angle_deg=PENCIL)
    for ti, pi in [(35.0, 70.0), (0.0, 0.0), (80.0, -120.0)]:
        sol = require(inverse(g, ti, pi, ti, pi))
        assert sol.tilt == 0.0 and sol.light == pytest.approx(sol.camera, abs=1e-12)
        assert_round_trip(g, sol, ti, pi, ti, pi)


joint_deg = st.floats(-180.0, 180.0)


tilt_deg = st.floats(-89.0, 89.0)


@given(st.sampled_from(["four_axis", "in_plane", "fixed_camera"]), joint_deg, joint_deg, tilt_deg, joint_deg)
@example("four_axis", 0.0, 0.0, 0.0, 0.0)
def test_world_positions_agree_with_forward(layout, a, b, t, r):
    g = RigGeometry(layout=layout, light_radius_m=0.6, camera_radius_m=0.45, camera_azimuth_deg=33.0,
                    plane_azimuth_deg=-20.0)
    joints = {
        "four_axis": Joints(light=a, camera=b, tilt=t, roll=r),
        "in_plane": Joints(light=a, camera=b),
        "fixed_camera": Joints(light=a, yaw=b, tilt=t, roll=r),
    }[layout]
    pose = world_pose(g, joints)
    frame = np.stack([pose.sample_tangent, pose.sample_bitangent, pose.sample_normal])
    assert np.allclose(frame @ frame.T, np.eye(3), atol=1e-12) and np.linalg.det(frame) == pytest.approx(1.0)
    to_light = pose.light_position_m - pose.sample_centre_m
    to_camera = pose.camera_position_m - pose.sample_centre_m
    assert np.linalg.norm(to_light) == pytest.approx(0.6) and np.linalg.norm(to_camera) == pytest.approx(0.45)
    assert to_light[2] == 0.0 and to_camera[2] == 0.0  # both on the horizontal arm plane
    d = forward(g, joints)
    assert np.allclose(frame @ to_light / 0.6, d.wi, atol=1e-12)
    assert np.allclose(frame @ to_camera / 0.45, d.wo, atol=1e-12)
    local_i = degrees_to_vector(d.theta_i, d.phi_i)
    assert angle_between(local_i, d.wi) < 1e-9


def test_documented_world_frame():
    g = RigGeometry()
    rest = world_pose(g, Joints(light=0.0, camera=90.0, tilt=0.0, roll=0.0))
    assert np.allclose(rest.sample_normal, [1, 0, 0]) and np.allclose(rest.sample_tangent, [0, 1, 0])
    assert np.allclose(rest.sample_bitangent, [0, 0, 1])
    assert np.allclose(rest.light_position_m, [0.5, 0, 0]) and np.allclose(rest.camera_position_m, [0, 0.5, 0])
    tilted = world_pose(g, Joints(light=0.0, camera=0.0, tilt=30.0, roll=0.0))
    assert np.allclose(tilted.sample_normal, [math.cos(math.radians(30)), 0, 0.5])
    # Roll r shows the arm plane at local azimuth -r.
    d = forward(g, Joints(light=30.0, camera=-30.0, tilt=0.0, roll=10.0))
    assert (d.theta_i, d.phi_i, d.phi_o) == pytest.approx((30.0, -10.0, 170.0))


def test_forward_and_pose_broadcast_over_arrays():
    g = RigGeometry()
    light = np.linspace(-60, 60, 7)
    joints = Joints(light=light, camera=-20.0, tilt=np.array([[5.0], [-5.0]]), roll=15.0)
    d = forward(g, joints)
    pose = world_pose(g, joints)
    assert d.wi.shape == (2, 7, 3) and np.shape(d.theta_i) == (2, 7) and pose.light_position_m.shape == (2, 7, 3)
    one = forward(g, Joints(light=float(light[3]), camera=-20.0, tilt=-5.0, roll=15.0))
    assert np.allclose(d.wi[1, 3], one.wi, atol=1e-15) and d.theta_o[1, 3] == pytest.approx(one.theta_o)


def test_forward_reports_zero_azimuth_at_the_pole():
    d = forward(RigGeometry(), Joints(light=0.0, camera=40.0, tilt=0.0, roll=123.0))
    assert d.theta_i == 0.0 and d.phi_i == 0.0


def test_forward_rejects_joints_of_another_layout():
    with pytest.raises(ValueError, match="four_axis rig has joints light, camera, tilt, roll; got camera, light"):
        forward(RigGeometry(), Joints(light=0.0, camera=0.0))
    with pytest.raises(ValueError, match="fixed_camera"):
        forward(RigGeometry(layout="fixed_camera"), Joints(light=0.0, camera=0.0, tilt=0.0, roll=0.0))
    with pytest.raises(ValueError, match="unknown joint name"):
        Joints.from_dict({"light": 0.0, "elbow": 1.0})


def test_joints_from_dict_knows_its_names() -> None:
    import dataclasses

    from rig.instrument.kinematics_types import Joints

    assert Joints.from_dict({"light": 1.0, "roll": 2.0}) == Joints(1.0, roll=2.0)
    known = r"\['camera', 'light', 'roll', 'tilt', 'yaw'\]"
    with pytest.raises(ValueError, match=r"unknown joint name\(s\) \['pan'\]; joints are " + known):
        Joints.from_dict({"light": 1.0, "pan": 2.0})

    @dataclasses.dataclass(frozen=True)
    class More(Joints):
        pan: float | None = None

    assert More.from_dict({"light": 1.0, "pan": 2.0}) == More(1.0, pan=2.0)
