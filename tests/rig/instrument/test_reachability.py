"""Rig geometry and reachability: every reason a point is unreachable, in order, and geometry validation."""

from __future__ import annotations

import math

import pytest

from model.geometry import degrees_to_vector
from rig.instrument.geometry import GeometryError, JointLimits, RigGeometry
from rig.instrument.kinematics import (
    Joints,
    Reason,
    Unreachable,
    UnreachableError,
    inverse,
    require,
    solve,
    solve_degrees,
    spot_ellipse,
)
from tests.rig.instrument.kinematics_helpers import PENCIL


def test_below_horizon():
    g = RigGeometry()
    sol = inverse(g, 100.0, 0.0, 30.0, 180.0)
    assert isinstance(sol, Unreachable) and sol.reason is Reason.BELOW_HORIZON
    assert "light direction is below the sample's horizon: theta_i = 100 deg > 90 deg" == sol.message
    vec = solve(g, degrees_to_vector(30.0, 0.0), [0.3, 0.0, -0.2]).at()
    assert isinstance(vec, Unreachable) and vec.reason is Reason.BELOW_HORIZON and "camera direction" in vec.message
    assert vec.value == pytest.approx(90.0 + math.degrees(math.atan2(0.2, 0.3)))


def test_max_zenith():
    sol = inverse(RigGeometry(), 30.0, 0.0, 87.0, 180.0)
    assert isinstance(sol, Unreachable) and sol.reason is Reason.MAX_ZENITH
    assert (sol.value, sol.limit) == pytest.approx((87.0, 85.0))
    assert "camera direction theta_o = 87 deg is beyond the rig's maximum zenith 85 deg" in sol.message
    assert isinstance(inverse(RigGeometry(beam_half_angle_deg=PENCIL), 30.0, 0.0, 85.0, 180.0), Joints)


def test_min_separation():
    sol = inverse(RigGeometry(), 30.0, 0.0, 35.0, 0.0)
    assert isinstance(sol, Unreachable) and sol.reason is Reason.MIN_SEPARATION
    assert (sol.value, sol.limit) == pytest.approx((5.0, 8.0))
    assert "light and camera are 5 deg apart, closer than the minimum arm separation 8 deg" in sol.message
    assert isinstance(inverse(RigGeometry(), 30.0, 0.0, 38.5, 0.0), Joints)


def test_spot_overfills_sample_at_grazing_incidence():
    g = RigGeometry()
    beta = math.radians(g.beam_half_angle_deg)
    # Along the incidence plane the far edge of the spot lies R sin(beta) / cos(theta_i + beta) from the centre.
    far = g.light_radius_m * math.sin(beta) / math.cos(math.radians(85.0) + beta)
    assert far > 0.025 > g.light_radius_m * math.sin(beta) / math.cos(math.radians(84.0) + beta)
    sol = inverse(g, 85.0, 0.0, 30.0, 180.0)
    assert isinstance(sol, Unreachable) and sol.reason is Reason.SPOT_OVERFILLS_SAMPLE
    assert (sol.value, sol.limit) == pytest.approx((far, 0.025), rel=1e-12)
    assert "illuminated spot at theta_i = 85 deg" in sol.message and "past its half-width 25 mm" in sol.message
    assert isinstance(inverse(g, 84.0, 0.0, 30.0, 180.0), Joints)
    # Incidence along the sample's y axis: the long axis now runs along the height.
    tall = inverse(RigGeometry(sample_height_m=0.04), 84.0, 90.0, 30.0, 270.0)
    assert isinstance(tall, Unreachable) and "along the sample's y axis, past its half-height 20 mm" in tall.message


def test_spot_unbounded_when_the_beam_reaches_the_horizon():
    g = RigGeometry(beam_half_angle_deg=10.0)
    sol = inverse(g, 82.0, 0.0, 10.0, 180.0)
    assert isinstance(sol, Unreachable) and sol.reason is Reason.SPOT_OVERFILLS_SAMPLE
    assert sol.value == math.inf and "reaches unbounded" in sol.message
    assert spot_ellipse(g, 82.0).semi_along_m == math.inf


def test_spot_ellipse_matches_the_cone_section():
    g = RigGeometry(beam_half_angle_deg=3.0, light_radius_m=0.4)
    r, beta = 0.4, math.radians(3.0)
    for t in (0.0, 40.0, 80.0):
        e = spot_ellipse(g, t)
        tr = math.radians(t)
        assert e.centre_m + e.semi_along_m == pytest.approx(r * math.sin(beta) / math.cos(tr - beta))
        assert e.semi_along_m - e.centre_m == pytest.approx(r * math.sin(beta) / math.cos(tr + beta))
    assert spot_ellipse(g, 0.0).semi_across_m == pytest.approx(g.spot_radius_m)


def test_spot_overfills_camera_view():
    g = RigGeometry(camera_fov_deg=1.0)
    assert g.view_radius_m == pytest.approx(0.5 * math.tan(math.radians(0.5)))
    beta = math.radians(g.beam_half_angle_deg)
    # Camera at the normal sees the footprint undistorted: its reach from the axis is the far edge.
    far = g.light_radius_m * math.sin(beta) / math.cos(math.radians(60.0) + beta)
    assert far > g.view_radius_m
    sol = inverse(g, 60.0, 0.0, 0.0, 0.0)
    assert isinstance(sol, Unreachable) and sol.reason is Reason.SPOT_OVERFILLS_VIEW
    assert (sol.value, sol.limit) == pytest.approx((far, g.view_radius_m), rel=1e-12)
    assert "seen from the camera at theta_o = 0 deg" in sol.message and "past the camera's view radius" in sol.message
    assert isinstance(inverse(g, 40.0, 0.0, 0.0, 0.0), Joints)
    # A grazing camera foreshortens the same spot back inside its view.
    assert isinstance(inverse(g, 60.0, 0.0, 80.0, 0.0), Joints)


def test_joint_limit_names_joint_value_and_limit():
    g = RigGeometry(limits=JointLimits(tilt=(-10.0, 10.0)))
    free = require(inverse(RigGeometry(), 30.0, 0.0, 45.0, 120.0))
    assert free.tilt < -10.0
    sol = inverse(g, 30.0, 0.0, 45.0, 120.0)
    assert isinstance(sol, Unreachable) and sol.reason is Reason.JOINT_LIMIT
    assert sol.joint == "tilt" and sol.value == pytest.approx(free.tilt) and sol.limit == -10.0
    assert f"joint 'tilt' would need {free.tilt:.6g} deg" in sol.message and "[-10, 10] deg" in sol.message
    assert sol.joints == free
    other = inverse(g, 30.0, 0.0, 45.0, 120.0, branch="camera_ccw")
    assert isinstance(other, Unreachable) and other.limit == 10.0
    with pytest.raises(UnreachableError, match="joint_limit: joint 'tilt'") as info:
        require(sol)
    assert info.value.unreachable is sol


def test_fixed_camera_light_arm_limit():
    g = RigGeometry(layout="fixed_camera", limits=JointLimits(light=(-90.0, 90.0)))
    sol = inverse(g, 30.0, 0.0, 70.0, 180.0)  # light 100 deg counter-clockwise of the camera at 0
    assert isinstance(sol, Unreachable) and sol.joint == "light" and sol.value == pytest.approx(100.0)
    assert sol.limit == 90.0 and "joint 'light' would need 100 deg" in sol.message


def test_not_finite_and_bad_arguments():
    sol = inverse(RigGeometry(), math.nan, 0.0, 30.0, 180.0)
    assert isinstance(sol, Unreachable) and sol.reason is Reason.NOT_FINITE
    batch = solve(RigGeometry(), [[0, 0, 0], [0, 0, 1]], degrees_to_vector(40.0, 0.0))
    assert list(batch.reason) == ["not_finite", ""] and math.isnan(batch.joints.light[0])
    with pytest.raises(ValueError, match="branch = 'left'"):
        inverse(RigGeometry(), 30.0, 0.0, 30.0, 180.0, branch="left")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3\)"):
        solve(RigGeometry(), [0.0, 1.0], [0.0, 1.0])


def test_reasons_are_checked_in_documented_order():
    g = RigGeometry(limits=JointLimits(tilt=(-1.0, 1.0)))
    codes = solve_degrees(
        g,
        [95.0, 88.0, 30.0, 85.0, 30.0],
        [0.0, 0.0, 0.0, 0.0, 0.0],
        [95.0, 30.0, 32.0, 60.0, 45.0],
        [0.0, 0.0, 0.0, 180.0, 120.0],
    ).reason
    assert list(codes) == ["below_horizon", "max_zenith", "min_separation", "spot_overfills_sample", "joint_limit"]


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({"layout": "sideways"}, r"RigGeometry\.layout = 'sideways', expected one of 'four_axis'"),
        ({"light_radius_m": 0.0}, r"RigGeometry\.light_radius_m = 0\.0 m, expected a value in \(0, inf\)"),
        ({"camera_radius_m": math.nan}, r"RigGeometry\.camera_radius_m = nan, expected a finite number"),
        ({"camera_radius_m": 0.03}, r"camera_radius_m = 0\.03 m, expected more than the sample's half-diagonal"),
        ({"sample_width_m": -0.05}, r"sample_width_m = -0\.05 m"),
        ({"min_separation_deg": 180.0}, r"min_separation_deg = 180\.0 deg, expected a value in \[0, 180\)"),
        ({"min_separation_deg": -1.0}, r"min_separation_deg = -1\.0 deg"),
        ({"max_zenith_deg": 90.0}, r"max_zenith_deg = 90\.0 deg, expected a value in \(0, 90\)"),
        ({"camera_fov_deg": 0.0}, r"camera_fov_deg = 0\.0 deg, expected a value in \(0, 180\)"),
        ({"beam_half_angle_deg": 90.0}, r"beam_half_angle_deg = 90\.0 deg"),
        ({"camera_azimuth_deg": math.inf}, r"camera_azimuth_deg = inf, expected a finite number"),
        ({"plane_azimuth_deg": "0"}, r"plane_azimuth_deg = '0', expected a finite number"),
        ({"limits": {"tilt": (0, 1)}}, r"RigGeometry\.limits = .*expected a JointLimits"),
    ],
)
def test_bad_geometry_names_field_value_and_range(kwargs, pattern):
    with pytest.raises(GeometryError, match=pattern):
        RigGeometry(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({"tilt": (10.0, -10.0)}, r"JointLimits\.tilt = \(10\.0, -10\.0\) deg, expected min_deg < max_deg"),
        ({"roll": (0.0, 1000.0)}, r"JointLimits\.roll = \(0\.0, 1000\.0\) deg, expected limits within \[-720, 720\]"),
        ({"light": (0.0,)}, r"JointLimits\.light = \(0\.0,\), expected a pair"),
        ({"yaw": (math.nan, 1.0)}, r"JointLimits\.yaw\[0\] = nan, expected a finite number"),
    ],
)
def test_bad_joint_limits(kwargs, pattern):
    with pytest.raises(GeometryError, match=pattern):
        JointLimits(**kwargs)


def test_geometry_errors_are_value_errors_and_defaults_are_a_tabletop_rig():
    assert issubclass(GeometryError, ValueError)
    g = RigGeometry()
    assert (g.layout, g.light_radius_m, g.sample_width_m, g.min_separation_deg, g.max_zenith_deg) == (
        "four_axis", 0.5, 0.05, 8.0, 85.0)
    assert g.joint_names == ("light", "camera", "tilt", "roll")
    assert RigGeometry(layout="fixed_camera").joint_names == ("light", "yaw", "tilt", "roll")
    assert hash(g) == hash(RigGeometry())
    with pytest.raises(KeyError, match="elbow"):
        g.limits.of("elbow")
