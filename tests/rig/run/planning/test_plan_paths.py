"""Moves that cannot collide: the swept path of every planned move keeps the arms apart, under each link's profile."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.instrument.axis import Axis
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Joints
from rig.run.planning.paths import ArmPaths
from rig.run.planning.plan import ARMS_CROSS, plan_sweep


def _axes(names: tuple[str, ...], speeds: dict[str, float]) -> list[Axis]:
    return [Axis(name=n, address=i + 1, units_per_degree=4096 / 360, min_deg=-180.0, max_deg=180.0,
                 max_speed_deg_s=speeds.get(n, 60.0), max_accel_deg_s2=120.0) for i, n in enumerate(names)]  # fmt: skip


def _positions(t: np.ndarray, a: float, b: float, v: float, acc: float) -> np.ndarray:
    """An independent trapezoid (deg at times t), for checking the planner against its own model."""
    d = abs(b - a)
    if d == 0:
        return np.full_like(t, a)
    if d * acc <= v * v:
        total = 2 * np.sqrt(d / acc)
        x = np.where(t < total / 2, 0.5 * acc * t**2, d - 0.5 * acc * np.clip(total - t, 0, None) ** 2)
    else:
        ta, total = v / acc, d / v + v / acc
        braking = d - 0.5 * acc * np.clip(total - t, 0, None) ** 2
        x = np.where(t < ta, 0.5 * acc * t**2, np.where(t < total - ta, 0.5 * acc * ta**2 + v * (t - ta), braking))
    return a + np.sign(b - a) * np.minimum(x, d)


def _closest_deg(geometry: RigGeometry, axes: list[Axis], a: Joints, b: Joints, coordinated: bool) -> float:
    """Least arm separation (deg) over the move a -> b, sampled densely (1e-4 of the move)."""
    by = {x.name: x for x in axes}
    da, db = a.as_dict(), b.as_dict()
    if coordinated:  # one straight line in joint space
        s = np.linspace(0.0, 1.0, 10001)
        light = da["light"] + s * (db["light"] - da["light"])
        camera = da["camera"] + s * (db["camera"] - da["camera"])
    else:
        times = []
        for n in ("light", "camera"):
            d, v, acc = abs(db[n] - da[n]), by[n].max_speed_deg_s, by[n].max_accel_deg_s2
            times.append(2 * np.sqrt(d / acc) if d * acc <= v * v else d / v + v / acc)
        t = np.linspace(0.0, max(times), 10001)
        light = _positions(t, da["light"], db["light"], by["light"].max_speed_deg_s, by["light"].max_accel_deg_s2)
        camera = _positions(t, da["camera"], db["camera"], by["camera"].max_speed_deg_s, by["camera"].max_accel_deg_s2)
    diff = light - camera
    return float(np.min(np.abs((diff + 180.0) % 360.0 - 180.0)))


def test_arms_that_would_pass_through_each_other_are_refused() -> None:
    # The case: light 20 / camera 60, then light 60 / camera 20 (in-plane rig, 8 deg apart at least).
    g = RigGeometry(layout="in_plane")
    paths = ArmPaths(g, ["light", "camera"], np.array([60.0, 60.0]), np.array([120.0, 120.0]), coordinated=False)
    assert not paths.safe(np.array([20.0, 60.0]), np.array([60.0, 20.0]))[0]
    assert paths.legs(np.array([20.0, 60.0]), np.array([60.0, 20.0])) is None
    coordinated = ArmPaths(g, ["light", "camera"], np.array([60.0, 60.0]), np.array([120.0, 120.0]), True)
    assert not coordinated.safe(np.array([20.0, 60.0]), np.array([60.0, 20.0]))[0]


def test_a_fast_arm_catching_a_slow_one_is_split_into_legs() -> None:
    # Light 0 -> 60 slowly, camera -20 -> 40 quickly: both ends 20 deg apart, but the camera catches the light.
    g = RigGeometry(layout="in_plane")
    paths = ArmPaths(g, ["light", "camera"], np.array([10.0, 90.0]), np.array([500.0, 500.0]), coordinated=False)
    src, dst = np.array([0.0, -20.0]), np.array([60.0, 40.0])
    assert not paths.safe(src, dst)[0]
    legs = paths.legs(src, dst)
    assert legs is not None and len(legs) == 2 and np.allclose(legs[0], [60.0, -20.0])  # the light goes first
    assert all(paths.safe(a, b)[0] for a, b in zip([src, legs[0]], legs, strict=True))


def test_in_plane_points_on_the_far_side_of_the_other_arm_are_skipped_with_the_reason() -> None:
    g = RigGeometry(layout="in_plane")
    axes = _axes(("light", "camera"), {})
    rows = np.array([[20.0, 0.0, 60.0, 0.0], [60.0, 0.0, 20.0, 0.0], [30.0, 0.0, 50.0, 180.0]])
    plan = plan_sweep(rows, g, axes, order=False)
    skipped = {s.index: s.reason for s in plan.skipped}
    assert skipped == {0: ARMS_CROSS}, plan.summary()  # light 20 / camera 60: the others have camera below light
    assert "arms_cross: 1 point" in plan.summary() and "Moves split into safe legs" in plan.summary()


@settings(max_examples=60)
@given(
    layout=st.sampled_from(["in_plane", "four_axis"]),
    coordinated=st.booleans(),
    light_speed=st.floats(5.0, 120.0),
    camera_speed=st.floats(5.0, 120.0),
    rows=st.lists(
        st.tuples(st.floats(0.0, 80.0), st.floats(-180.0, 180.0), st.floats(0.0, 80.0), st.floats(-180.0, 180.0)),
        min_size=1, max_size=12,
    ),
    order=st.booleans(),
)
def test_no_planned_move_ever_brings_the_arms_closer_than_the_minimum(
    layout: str, coordinated: bool, light_speed: float, camera_speed: float, rows: list[tuple[float, ...]],
    order: bool,
) -> None:
    g = RigGeometry(layout=layout)
    axes = _axes(g.joint_names, {"light": light_speed, "camera": camera_speed})
    plan = plan_sweep(np.array(rows), g, axes, coordinated=coordinated, order=order)
    here = plan.start
    start_sep = _closest_deg(g, axes, here, here, coordinated)
    for p in plan.points:
        for target in (*p.via, p.joints):
            need = min(g.min_separation_deg, _closest_deg(g, axes, here, here, coordinated))
            assert _closest_deg(g, axes, here, target, coordinated) >= need - 1e-6, (here, target, start_sep)
            here = target


@pytest.mark.parametrize("coordinated", [False, True])
def test_split_moves_count_in_the_time_estimate(coordinated: bool) -> None:
    g = RigGeometry(layout="in_plane")
    axes = _axes(("light", "camera"), {"light": 10.0, "camera": 90.0})
    rows = np.array([[20.0, 0.0, 10.0, 180.0], [60.0, 0.0, 40.0, 0.0]])  # light 20/cam -10, then light 60/cam 40
    plan = plan_sweep(rows, g, axes, order=False, coordinated=coordinated)
    assert not plan.skipped
    if not coordinated:
        assert plan.split_moves == 1 and len(plan.points[1].via) == 1
        direct = plan_sweep(rows[1:], g, axes, order=False, start=plan.points[0].joints)
        assert plan.estimate.motion_s > direct.estimate.motion_s


class _StandingLink:
    """A link whose arms stand at given angles (degrees): enough for the guard, which only reads them back."""

    def __init__(self, positions: dict[str, float]) -> None:
        self.positions = positions

    def read_positions(self) -> dict[str, float]:
        return dict(self.positions)


def test_the_runtime_guard_refuses_unchecked_targets_and_unsafe_paths_from_where_the_arms_are() -> None:
    from rig.run.measuring.motion_guard import MotionGuard, UnsafeMove

    g = RigGeometry(layout="in_plane")
    axes = _axes(("light", "camera"), {})
    plan = plan_sweep(np.array([[20.0, 0.0, 40.0, 180.0]]), g, axes)  # light 20, camera -40
    guard = MotionGuard(plan.paths, [p.joints for p in plan.points])
    target = {"light": 20.0, "camera": -40.0}
    assert guard.legs(_StandingLink({"light": 0.0, "camera": -50.0}), target) == [target]  # type: ignore[arg-type]
    with pytest.raises(UnsafeMove, match="not a pose the plan checked"):
        guard.legs(_StandingLink({"light": 0.0, "camera": -50.0}), {"light": 25.0, "camera": -40.0})  # type: ignore[arg-type]
    # A resumed run whose arms stand the other way round: the planned move would pass them through each other.
    with pytest.raises(UnsafeMove, match="would pass closer than 8 deg"):
        guard.legs(_StandingLink({"light": -30.0, "camera": 30.0}), target)  # type: ignore[arg-type]


def test_large_sweeps_are_ordered_through_the_tree_without_the_full_matrix(monkeypatch: pytest.MonkeyPatch) -> None:
    import rig.run.planning.order as po

    rng = np.random.default_rng(4)
    pts = rng.uniform(-90, 90, size=(1000, 4))
    speed, accel = np.array([60.0, 60.0, 30.0, 90.0]), np.array([120.0] * 4)
    start = np.zeros(4)
    monkeypatch.setattr(po, "MATRIX_LIMIT", 100)  # 1000 points take the n log n path
    monkeypatch.setattr(po, "pairwise_times", _no_full_matrix(po.pairwise_times, 1000))
    order = po.order_path(pts, start, speed, accel, False)
    assert sorted(order.tolist()) == list(range(1000))

    def cost(o: np.ndarray) -> float:
        path = np.vstack([start, pts[o]])
        return float(po.step_times(path[:-1], path[1:], speed, accel, False).sum())

    assert cost(order) < 0.5 * cost(np.arange(1000))


def _no_full_matrix(real, n):  # type: ignore[no-untyped-def]
    def call(src, dst, *args):  # type: ignore[no-untyped-def]
        assert len(src) * len(dst) < n * n // 4, "a full move-time matrix was built"
        return real(src, dst, *args)

    return call


def _oracle_legs(paths: ArmPaths, src: np.ndarray, dst: np.ndarray) -> list[list[np.ndarray] | None]:
    """``ArmPaths.legs`` of every move src[i] -> dst[i] as it was before the one-move arithmetic: each check
    through the vectorised ``safe``, all moves at once (one arm first, then the other, where the direct move
    is unsafe)."""
    direct = paths.safe(src, dst)
    arms = [i for i in (paths.light, paths.camera) if i is not None]
    splits = []
    for first in arms:
        mid = dst.copy()
        for other in arms:
            if other != first:
                mid[:, other] = src[:, other]
        splits.append((mid, paths.safe(src, mid) & paths.safe(mid, dst)))
    out: list[list[np.ndarray] | None] = []
    for i in range(len(src)):
        if direct[i]:
            out.append([dst[i]])
            continue
        out.append(next(([mid[i], dst[i]] for mid, ok in splits if ok[i]), None))
    return out


@pytest.mark.parametrize("layout", ["in_plane", "four_axis", "fixed_camera"])
@pytest.mark.parametrize("coordinated", [False, True])
def test_the_one_move_check_gives_the_vectorised_checks_numbers_and_decisions(layout: str, coordinated: bool) -> None:
    # The runtime guard checks one move at a time on Python floats; the planner checks batches with numpy.
    # Same clearance to the last bit, same decision, same legs, over random moves, short moves, one arm still,
    # and moves that run exactly at the minimum separation (both arms in step) or start parked inside it.
    g = RigGeometry(layout=layout)
    rng = np.random.default_rng(7)
    sets = [["light", "camera"], ["light", "camera", "stage"], ["stage", "light"], ["camera"], ["light"]]
    for names in sets:
        if layout == "fixed_camera" and "camera" in names:
            continue
        k = len(names)
        paths = ArmPaths(g, names, rng.uniform(5.0, 200.0, k), rng.uniform(10.0, 800.0, k), coordinated,
                         held={"light": 30.0, "camera": -20.0})  # fmt: skip
        src = rng.uniform(-200.0, 200.0, (400, k))
        dst = rng.uniform(-200.0, 200.0, (400, k))
        dst[::4] = src[::4] + rng.normal(0.0, 5.0, (100, k))  # short moves
        dst[1::5, 0] = src[1::5, 0]  # one joint still
        if paths.light is not None and paths.camera is not None:
            li, ci = paths.light, paths.camera
            src[2::6, ci] = src[2::6, li] - g.min_separation_deg  # exactly at the minimum ...
            dst[2::6, li] = src[2::6, li] + 30.0
            dst[2::6, ci] = src[2::6, ci] + 30.0  # ... all the way, when both arms move alike
            src[3::6, ci] = src[3::6, li] - 0.5 * g.min_separation_deg  # parked inside the minimum
        clearance, safe, oracle = paths.clearance(src, dst), paths.safe(src, dst), _oracle_legs(paths, src, dst)
        for i in range(len(src)):
            assert paths.clearance_one(src[i], dst[i]) == clearance[i], (names, src[i], dst[i])
            assert paths.safe_one(src[i], dst[i]) == bool(safe[i]), (names, src[i], dst[i])
            got, want = paths.legs(src[i], dst[i]), oracle[i]
            assert (got is None) == (want is None) and (
                got is None or all(np.array_equal(a, b) for a, b in zip(got, want or [], strict=True))
            ), (names, src[i], dst[i])
        assert 0 < np.count_nonzero(safe) < len(safe)  # both decisions were exercised
