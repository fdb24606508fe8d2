"""Sweep plans: move times against the closed form and the virtual servo, reachability, ordering, estimates."""

import itertools
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from rig.instrument.axis import Axis
from rig.instrument.clock import ManualClock
from rig.instrument.geometry import JointLimits, RigGeometry
from rig.instrument.kinematics import Joints, Reason, forward, inverse
from rig.instrument.links.dynamixel_table import X_SERIES
from rig.run.config import sweeps
from rig.run.planning import order as plan_order
from rig.run.planning.order import order_path, trapezoid_time_s
from rig.run.planning.plan import Plan, format_duration, move_time_s, order_points, plan_sweep
from simulator.dynamixel import VirtualServo
from simulator.dynamixel import control_table as ct

#: A narrow beam, so reach is decided by separation, zenith and joint limits, not by the spot.
GEO = RigGeometry(beam_half_angle_deg=0.05)
SPEEDS = {"light": 60.0, "camera": 45.0, "tilt": 30.0, "roll": 90.0}
ACCELS = {"light": 120.0, "camera": 90.0, "tilt": 40.0, "roll": 200.0}


def make_axes(geometry=GEO, skip=(), **limits):
    out = []
    for i, name in enumerate(geometry.joint_names):
        if name in skip:
            continue
        lo, hi = limits.get(name, geometry.limits.of(name))
        out.append(Axis(name, i + 1, X_SERIES.ticks_per_degree, min_deg=lo, max_deg=hi,
                        max_speed_deg_s=SPEEDS[name], max_accel_deg_s2=ACCELS[name]))  # fmt: skip
    return out


def closed_form(d, v, a):
    return 2 * math.sqrt(d / a) if d * a <= v * v else d / v + v / a


def total_time(joints, axes, coordinated=False) -> float:
    """Summed move time in seconds along a list of joints."""
    return sum(move_time_s(a, b, axes, coordinated=coordinated) for a, b in itertools.pairwise(joints))


def path_time(plan: Plan, axes) -> float:
    return total_time([plan.start] + [p.joints for p in plan.points], axes)


# --- move times ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("distance", [0.0, 1e-9, 5.0, 30.0, 60.0, 200.0])
def test_single_axis_matches_closed_form(distance):
    axis = [Axis("light", 1, 10.0, max_speed_deg_s=60.0, max_accel_deg_s2=120.0)]
    # 60 deg/s at 120 deg/s^2: a triangle up to 30 deg, a trapezoid beyond.
    assert move_time_s(Joints(0.0), Joints(distance), axis) == pytest.approx(
        closed_form(distance, 60.0, 120.0), rel=1e-12
    )
    assert move_time_s(Joints(-distance), Joints(0.0), axis) == move_time_s(Joints(0.0), Joints(distance), axis)


def test_trapezoid_is_continuous_at_the_triangle_boundary():
    v, a = 60.0, 120.0
    d = v * v / a
    assert trapezoid_time_s(d * (1 - 1e-12), v, a) == pytest.approx(trapezoid_time_s(d * (1 + 1e-12), v, a))
    assert float(trapezoid_time_s(d, v, a)) == pytest.approx(2 * v / a)


def test_parallel_axes_take_the_slowest():
    axes = make_axes()
    a = Joints(0.0, 0.0, 0.0, 0.0)
    b = Joints(90.0, -20.0, 25.0, 170.0)
    expected = max(closed_form(abs(getattr(b, n) - getattr(a, n)), SPEEDS[n], ACCELS[n]) for n in SPEEDS)
    assert move_time_s(a, b, axes) == pytest.approx(expected, rel=1e-12)


def test_coordinated_moves_share_one_trapezoid():
    axes = [Axis("light", "X", 10.0, max_speed_deg_s=20.0, max_accel_deg_s2=40.0),
            Axis("camera", "Y", 10.0, max_speed_deg_s=45.0, max_accel_deg_s2=90.0)]  # fmt: skip
    a, b = Joints(0.0, 0.0), Joints(30.0, -90.0)
    # Unit path: speed min(20/30, 45/90) = 0.5/s, acceleration min(40/30, 90/90) = 1/s^2.
    assert move_time_s(a, b, axes, coordinated=True) == pytest.approx(closed_form(1.0, 0.5, 1.0), rel=1e-12)
    assert move_time_s(a, a, axes, coordinated=True) == 0.0


@given(st.lists(st.floats(-170, 170), min_size=8, max_size=8))
def test_coordinated_never_beats_independent(v):
    axes = make_axes()
    a, b = Joints(*v[:4]), Joints(*v[4:])
    assert move_time_s(a, b, axes, coordinated=True) >= move_time_s(a, b, axes) * (1 - 1e-12)


def test_a_joint_without_axis_must_not_move():
    axes = make_axes(skip=("roll",))
    assert move_time_s(Joints(0.0, 0.0, 0.0, 5.0), Joints(10.0, 0.0, 0.0, 5.0), axes) > 0
    with pytest.raises(ValueError, match="'roll'"):
        move_time_s(Joints(0.0, 0.0, 0.0, 5.0), Joints(10.0, 0.0, 0.0, 6.0), axes)


def test_estimate_matches_the_virtual_servo():
    """One move on the virtual XM430 (driven directly, on a ManualClock) ends when the estimate says."""
    clock = ManualClock()
    servo = VirtualServo(1, clock=clock, position_ticks=2048)
    nominal = Axis("light", 1, X_SERIES.ticks_per_degree, zero_offset_deg=-180.0)
    pv, pa = X_SERIES.velocity_units(nominal.max_speed_deg_s), X_SERIES.accel_units(nominal.max_accel_deg_s2)
    for name, value in (("profile_velocity", pv), ("profile_acceleration", pa), ("torque_enable", 1)):
        assert servo.write(ct.field(name).address, ct.field(name).encode(value)) == 0
    # The servo runs the register values, which quantise the axis's limits (0.229 rpm, 214.577 rpm^2).
    programmed = Axis("light", 1, X_SERIES.ticks_per_degree, max_speed_deg_s=pv * 0.229 * 6.0,
                      max_accel_deg_s2=pa * 214.577 / 10.0)  # fmt: skip
    target = 90.0  # 1024 ticks: no rounding of the goal
    expected = move_time_s(Joints(0.0), Joints(target), [programmed])
    goal = ct.field("goal_position")
    assert servo.write(goal.address, goal.encode(round(nominal.to_units(target)))) == 0
    clock.advance(expected - 1e-6)
    assert not servo.state().in_position
    clock.advance(2e-6)
    assert servo.state().in_position
    assert servo.present_position_ticks() == 2048 + 1024
    # The nominal limits give an estimate within the quantisation (a few per cent).
    assert move_time_s(Joints(0.0), Joints(target), [nominal]) == pytest.approx(expected, rel=0.05)


# --- reachability -------------------------------------------------------------------------------------


def test_every_row_is_planned_or_skipped_with_a_reason():
    rows = sweeps.grid([0, 10, 30, 60, 88], [0, 5, 10, 30, 60], [0, 20, 90, 180])
    plan = plan_sweep(rows, GEO, make_axes())
    assert len(plan.points) + len(plan.skipped) == len(rows)
    assert sorted([p.index for p in plan.points] + [s.index for s in plan.skipped]) == list(range(len(rows)))
    codes = {r.value for r in Reason}
    assert all(s.reason in codes and s.detail for s in plan.skipped)
    reasons = {s.reason for s in plan.skipped}
    assert {Reason.MIN_SEPARATION.value, Reason.MAX_ZENITH.value} <= reasons
    for s in plan.skipped:
        np.testing.assert_array_equal(s.directions_deg, rows[s.index])
        result = inverse(GEO, *s.directions_deg)
        assert getattr(result, "reason", None) == s.reason
    retro = [s for s in plan.skipped if s.reason == Reason.MIN_SEPARATION.value]
    assert any(s.directions_deg == (30.0, 0.0, 30.0, 0.0) for s in retro)
    for p in plan.points:
        np.testing.assert_array_equal(p.directions_deg, rows[p.index])
        d = forward(GEO, p.joints)
        np.testing.assert_allclose([d.theta_i, d.theta_o], [p.directions_deg[0], p.directions_deg[2]], atol=1e-9)


def test_non_finite_rows_are_skipped_not_dropped():
    rows = np.array([[30.0, 0.0, 30.0, 180.0], [np.nan, 0.0, 30.0, 180.0]])
    plan = plan_sweep(rows, GEO, make_axes())
    assert [p.index for p in plan.points] == [0]
    assert [(s.index, s.reason) for s in plan.skipped] == [(1, Reason.NOT_FINITE.value)]


def test_axis_travel_narrower_than_the_geometry_is_unreachable():
    rows = sweeps.grid([30], [30], np.arange(0, 360, 15))
    axes = make_axes(tilt=(-10.0, 10.0))
    plan = plan_sweep(rows, GEO, axes)
    wide = plan_sweep(rows, GEO, make_axes())
    tilt_skips = [s for s in plan.skipped if "axis 'tilt'" in s.detail]
    assert tilt_skips and all(s.reason == Reason.JOINT_LIMIT.value for s in tilt_skips)
    assert len(plan.skipped) > len(wide.skipped)
    assert all(-10.0 <= p.joints.tilt <= 10.0 for p in plan.points)


def test_whole_turn_equivalent_inside_the_axis_is_used():
    limits = JointLimits(roll=(-360.0, 360.0))
    geo = RigGeometry(beam_half_angle_deg=0.05, limits=limits)
    axes = make_axes(geo, roll=(0.0, 360.0))
    rows = sweeps.explicit([[30, 90, 30, 0]])  # needs a roll near -135 deg
    plan = plan_sweep(rows, geo, axes)
    assert len(plan.points) == 1 and 0.0 <= plan.points[0].joints.roll <= 360.0
    d = forward(geo, plan.points[0].joints)
    np.testing.assert_allclose([d.theta_i, d.phi_i, d.theta_o, d.phi_o], [30, 90, 30, 0], atol=1e-9)


def test_isotropic_plans_keep_roll_still():
    rows = sweeps.isotropic(sweeps.grid([10, 40, 70], [10, 40, 70], np.arange(0, 360, 45)))
    axes = make_axes(skip=("roll",))
    plain = plan_sweep(rows, GEO, axes)
    assert any("'roll' has no axis" in s.detail for s in plain.skipped)
    plan = plan_sweep(rows, GEO, axes, isotropic=True)
    assert {s.reason for s in plan.skipped} == {Reason.MIN_SEPARATION.value}
    for p in plan.points:
        assert p.joints.roll == pytest.approx(0.0, abs=1e-9)
        d = forward(GEO, p.joints)
        ti, _, to, rel = sweeps.isotropic(np.array([[d.theta_i, d.phi_i, d.theta_o, d.phi_o]]))[0]
        np.testing.assert_allclose([ti, to, rel], np.array(p.directions_deg)[[0, 2, 3]], atol=1e-7)


# --- ordering -----------------------------------------------------------------------------------------


def shuffled_grid(seed=3):
    rows = sweeps.grid([10, 30, 50, 70], [10, 30, 50, 70], np.arange(0, 360, 30), [0, 90])
    return rows[np.random.default_rng(seed).permutation(len(rows))]


def test_ordering_beats_a_shuffled_grid():
    rows, axes = shuffled_grid(), make_axes()
    ordered = plan_sweep(rows, GEO, axes)
    as_given = plan_sweep(rows, GEO, axes, order=False)
    assert [p.index for p in as_given.points] == sorted(p.index for p in as_given.points)
    assert sorted(p.index for p in ordered.points) == [p.index for p in as_given.points]
    assert ordered.estimate.motion_s < 0.5 * as_given.estimate.motion_s
    assert ordered.motion_as_generated_s == pytest.approx(as_given.estimate.motion_s, rel=1e-12)
    assert as_given.motion_as_generated_s is None
    assert f"{format_duration(as_given.estimate.motion_s)} as generated" in ordered.summary()
    assert ordered.estimate.motion_s == pytest.approx(path_time(ordered, axes), rel=1e-12)


@given(st.integers(0, 10_000), st.integers(1, 60), st.booleans())
def test_ordering_never_costs_more_than_the_given_order(seed, n, coordinated):
    x = np.random.default_rng(seed).uniform(-150, 150, size=(n, 4))
    start = np.zeros(4)
    speed, accel = np.array(list(SPEEDS.values())), np.array(list(ACCELS.values()))
    axes = make_axes()

    def cost(order):
        return total_time([Joints(*start)] + [Joints(*x[i]) for i in order], axes, coordinated)

    order = order_path(x, start, speed, accel, coordinated)
    assert sorted(order.tolist()) == list(range(n))
    assert cost(order) <= cost(range(n)) * (1 + 1e-12)


def test_order_points_is_a_deterministic_permutation_for_1000_points():
    x = np.random.default_rng(7).uniform(-150, 150, size=(1000, 4))
    joints = [Joints(*r) for r in x]
    axes = make_axes()
    start = Joints(0.0, 0.0, 0.0, 0.0)
    first = order_points(joints, axes, start)
    assert sorted(first) == list(range(1000))
    assert order_points(joints, axes, start) == first
    assert total_time([start] + [joints[i] for i in first], axes) < 0.5 * total_time([start, *joints], axes)


@given(st.integers(0, 10_000), st.integers(3, 30))
def test_local_search_moves_really_improve(seed, m):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 10, (m, 2))
    d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    p = np.concatenate([[0], rng.permutation(np.arange(1, m - 1)), [m - 1]]).astype(np.intp)
    rounds = [plan_order._two_opt] + [lambda d, q, n=n: plan_order._or_opt(d, q, n) for n in (1, 2, 3)]
    for step in rounds:
        q = p.copy()
        changed = step(d, q)
        assert sorted(q) == list(range(m)) and q[0] == 0 and q[-1] == m - 1
        before, after = plan_order.path_cost(d, p), plan_order.path_cost(d, q)
        assert after < before - 1e-9 if changed else after == before


def test_long_sweeps_are_ordered_in_windows(monkeypatch):
    monkeypatch.setattr(plan_order, "MATRIX_LIMIT", 50)
    monkeypatch.setattr(plan_order, "WINDOW", 40)
    x = np.random.default_rng(11).uniform(-150, 150, size=(300, 4))
    speed, accel = np.array(list(SPEEDS.values())), np.array(list(ACCELS.values()))
    order = order_path(x, np.zeros(4), speed, accel, False)
    assert sorted(order.tolist()) == list(range(300))
    nodes = np.vstack([np.zeros(4), x])

    def cost(o):
        path = np.concatenate([[0], np.asarray(o) + 1])
        return plan_order.step_times(nodes[path[:-1]], nodes[path[1:]], speed, accel, False).sum()

    assert cost(order) < 0.5 * cost(np.arange(300))


# --- estimates and summary ----------------------------------------------------------------------------


def test_estimate_adds_up():
    rows, axes = shuffled_grid(), make_axes()
    ref = Joints(0.0, -60.0, 0.0, 0.0)
    plan = plan_sweep(rows, GEO, axes, settle_s=0.5, exposure_s_per_point=2.0, overhead_s_per_point=0.1,
                      reference_every=25, reference_s=4.0, reference_joints=ref)  # fmt: skip
    e, n = plan.estimate, len(plan.points)
    assert e.total_s == pytest.approx(e.motion_s + e.settle_s + e.exposure_s + e.reference_s + e.overhead_s)
    assert (e.settle_s, e.exposure_s, e.overhead_s) == pytest.approx((0.5 * n, 2.0 * n, 0.1 * n))
    assert plan.reference_before == (0, *range(25, n, 25), n)
    assert e.reference_captures == len(plan.reference_before) == 1 + math.ceil(n / 25)
    assert e.motion_s == pytest.approx(path_time(plan, axes), rel=1e-12)
    nodes = [plan.start] + [p.joints for p in plan.points]
    detours = 0.0
    for k in plan.reference_before:
        detours += move_time_s(nodes[k], ref, axes) + 0.5
        if k < n:
            detours += move_time_s(ref, nodes[k + 1], axes) - move_time_s(nodes[k], nodes[k + 1], axes)
    assert e.reference_s == pytest.approx(4.0 * e.reference_captures + detours, rel=1e-12)


def test_references_default_to_start_and_end():
    plan = plan_sweep(sweeps.grid([30], [30, 60]), GEO, make_axes(), reference_s=3.0)
    assert plan.reference_before == (0, 2) and plan.estimate.reference_s == 6.0
    empty = plan_sweep(np.zeros((0, 4)), GEO, make_axes(), reference_s=3.0)
    assert empty.points == () and empty.skipped == () and empty.estimate.total_s == 0.0


def test_summary_reports_counts_reasons_and_time():
    rows = sweeps.grid([0, 10, 30, 60, 88], [0, 5, 10, 30, 60], [0, 20, 90, 180])
    plan = plan_sweep(rows, GEO, make_axes(), exposure_s_per_point=30.0)
    text = plan.summary(examples=2)
    assert f"Sweep of {len(rows)} points: {len(plan.points)} to measure, {len(plan.skipped)} unreachable" in text
    assert "min_separation" in text and "max_zenith" in text and "more" in text
    assert format_duration(plan.estimate.total_s) in text and "exposures" in text


@pytest.mark.parametrize(
    ("seconds", "text"),
    [(0.0, "0.0 s"), (4.24, "4.2 s"), (42.4, "42 s"), (59.6, "1 min 00 s"), (725.0, "12 min 05 s"),
     (3599.7, "1 h 00 min"), (3720.0, "1 h 02 min"), (90061.0, "25 h 01 min"), (math.inf, "unknown")],
)  # fmt: skip
def test_format_duration(seconds, text):
    assert format_duration(seconds) == text


def test_bad_inputs_are_refused():
    axes = make_axes()
    with pytest.raises(ValueError, match="shape"):
        plan_sweep(np.zeros((3, 3)), GEO, axes)
    with pytest.raises(ValueError, match="settle_s"):
        plan_sweep(np.zeros((0, 4)), GEO, axes, settle_s=-1.0)
    with pytest.raises(ValueError, match="yaw"):
        plan_sweep(np.zeros((0, 4)), GEO, [*axes, Axis("yaw", 9, 1.0)])
    with pytest.raises(ValueError, match="start"):
        plan_sweep(np.zeros((0, 4)), GEO, axes, start=Joints(0.0, 0.0))


def test_a_vanishing_coordinated_move_takes_vanishing_time_not_none():
    # Found by hypothesis: a 1e-310 deg move overflowed the unit path's limits to inf, read as "does not move".
    axes = make_axes()
    a, b = Joints(0.0, 0.0, 0.0, 0.0), Joints(1e-310, 0.0, 0.0, 0.0)
    independent = move_time_s(a, b, axes)
    assert independent > 0.0
    assert move_time_s(a, b, axes, coordinated=True) == pytest.approx(independent, rel=1e-9, abs=0.0)
