"""Gear play the encoders cannot see, on both links of the simulated rig: the fault, and the one-sided approach.

The simulated joints have ``backlash_deg`` of play (``[simulation.misalignment]``): the load lags the motor by
half of it behind the last direction of motion, while the encoder (or GRBL's step count) reads the motor. The
controller knows the play (``[link] backlash_deg``); with ``[link] backlash_approach_deg`` it reaches every pose
from one side, so the load rests on a known flank (``rig.run.measuring.backlash``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rig.run.session import start_run
from rig.run.storage.store import RunStore
from simulator.from_config import rig_from
from tests.run_helpers import GOLD, LINKS, in_plane_sweep, open_link, read_rows, sim_rig, truth_and_measured

pytestmark = pytest.mark.mitsuba

PLAY_DEG = 2.0


@pytest.fixture(params=LINKS)
def link(request: pytest.FixtureRequest) -> str:
    """What moves the simulated joints: virtual Dynamixel servos or a virtual GRBL controller."""
    return str(request.param)


def _rig(on: str, approach_deg: float, material: dict[str, Any] | None = None) -> Any:
    return sim_rig(material or GOLD, on=on, simulation={"misalignment": {"backlash_deg": PLAY_DEG}},
                   link={"backlash_deg": PLAY_DEG, "backlash_approach_deg": approach_deg})  # fmt: skip


def test_the_simulated_load_lags_its_motor_by_half_the_play(link: str) -> None:
    rig = _rig(link, 0.0)
    with rig_from(rig) as sim:
        light = next(a for a in sim.axes if a.name == "light")
        motion = open_link(sim, rig)
        try:
            for start, sign in ((10.0, -1.0), (50.0, 1.0)):
                motion.move_to({"light": start})
                motion.wait_in_position(30.0)
                motion.move_to({"light": 30.0})
                read = motion.wait_in_position(30.0)["light"]
                load = light.to_degrees(sim.physical_units(light))
                # Driven up from 10 the load trails below the reading, driven down from 50 above it.
                assert load - read == pytest.approx(sign * PLAY_DEG / 2, abs=0.02), (start, load, read)
        finally:
            motion.shutdown()


def _z(tmp_path: Path, on: str, approach_deg: float) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """z-scores (points, channels) of a gold sweep's readings against the truth, and its point records."""
    rig = _rig(on, approach_deg)
    # Both arms swept up and down through the gold's lobe: each point's joints arrive from either side.
    sweep = in_plane_sweep([40.0, 20.0], [-60.0, -40.0, -25.0, 10.0, 30.0])
    summary = start_run(rig, sweep, tmp_path / f"run-{approach_deg:g}", progress=False)
    truth, got, se = truth_and_measured(read_rows(summary.table), rig)
    points = [r for r in RunStore.read(tmp_path / f"run-{approach_deg:g}").records() if r["kind"] == "point"]
    return (got - truth) / se, points


def test_a_one_sided_approach_takes_the_play_out_of_the_readings(tmp_path: Path, link: str) -> None:
    z, points = _z(tmp_path, link, approach_deg=2.0 * PLAY_DEG)
    assert np.all(np.abs(z) < 4.5), z
    events = [r for r in RunStore.read(tmp_path / "run-4").records() if r["kind"] == "event"]
    assert not events, events  # every overshoot leg passed the motion guard's separation check
    # The load's side is known: nothing of the play is left in the angles' variance (the encoder's count only).
    assert max(r["angle_cov_deg2"][0][0] for r in points) < PLAY_DEG**2 / 12 / 10


def test_without_the_approach_the_play_moves_the_readings_beyond_their_errors(tmp_path: Path, link: str) -> None:
    z, points = _z(tmp_path, link, approach_deg=0.0)
    assert np.max(np.abs(z)) > 6.0, z  # the fault is real: the joints read exact, the loads are half the play off
    # ... and the journal says the angles are that uncertain: a band of width b, variance b^2 / 12 per joint.
    assert min(r["angle_cov_deg2"][0][0] for r in points) >= PLAY_DEG**2 / 12 * 0.99


def test_the_approach_overshoots_within_the_limits_and_knows_which_flank_it_left_the_load_on() -> None:
    from rig.instrument.axis import Axis
    from rig.run.measuring.backlash import Backlash

    axes = [Axis("light", 1, 4096 / 360, min_deg=-90.0, max_deg=90.0, backlash_deg=1.0),
            Axis("camera", 2, 4096 / 360, min_deg=-90.0, max_deg=90.0, backlash_deg=0.5)]  # fmt: skip
    play = Backlash(axes, approach_deg=3.0)
    target = {"light": 40.0, "camera": -89.0, "tilt": 5.0}
    below = play.pre_pose(target, 1)
    assert below == {"light": 37.0, "camera": -90.0, "tilt": 5.0}  # clamped at the limit; no axis: stays
    sides = play.sides(below, target)
    assert sides == {"light": 1, "camera": 1}  # camera came up 1 deg: more than its 0.5 deg of play
    assert play.load_angles({"light": 40.0, "camera": -89.0}, sides) == {"light": 39.5, "camera": -89.25}
    assert play.variance_deg2("light", sides) == 0.0
    # From above the camera has room; a joint whose final leg is shorter than its play keeps a band of it.
    short = Backlash(axes, approach_deg=0.8)
    sides = short.sides(short.pre_pose(target, -1), target)
    assert sides == {"camera": -1}
    assert short.variance_deg2("light", sides) == pytest.approx(1.0 / 12)
    with pytest.raises(ValueError, match="backlash_approach_deg = -1"):
        Backlash(axes, -1.0)


def test_a_rig_file_states_each_joints_play_and_the_approach() -> None:
    from rig.run.config.files import ConfigError
    from rig.run.session import options_for

    rig = sim_rig(link={"backlash_deg": 0.5, "backlash_approach_deg": 1.5},
                  axes={"light": {"id": 1, "backlash_deg": 1.2}})  # fmt: skip
    assert {a.name: a.backlash_deg for a in rig.axes} == {"light": 1.2, "camera": 0.5, "tilt": 0.5, "roll": 0.5}
    assert options_for(rig, in_plane_sweep([30.0], [0.0]), False).backlash_approach_deg == 1.5
    with pytest.raises(ConfigError, match=r"link\.backlash_approach_deg = -1"):
        sim_rig(link={"backlash_approach_deg": -1})


def test_an_overshoot_the_guard_refuses_is_tried_from_the_other_side_then_skipped_with_an_event() -> None:
    from types import SimpleNamespace

    from rig.instrument.axis import Axis
    from rig.run.measuring.backlash import Backlash
    from rig.run.measuring.motion_guard import UnsafeMove
    from rig.run.measuring.runner import Runner

    play = Backlash([Axis("light", 1, 4096 / 360, backlash_deg=1.0)], approach_deg=2.0)
    target = {"light": 30.0}

    def approach(refused: set[float]) -> tuple[Any, list[float], list[str]]:
        moves: list[float] = []
        events: list[str] = []

        def legs(pose: dict[str, float]) -> dict[str, float]:
            if pose["light"] in refused:  # the guard refuses before anything moves
                raise UnsafeMove(f"refused a move to {pose}")
            moves.append(pose["light"])
            return dict(pose)

        runner = SimpleNamespace(backlash=play, _legs=legs, _sides={},
                                 _event=lambda kind, message, **_: events.append(kind))  # fmt: skip
        Runner._approach(runner, target)  # type: ignore[arg-type]
        return runner, moves, events

    runner, moves, events = approach({28.0})  # no room below: from above
    assert moves == [32.0, 30.0] and runner._sides == {"light": -1} and not events
    runner, moves, events = approach({28.0, 32.0})  # no room on either side: straight there, play uncertain
    assert moves == [30.0] and runner._sides == {} and events == ["approach_skipped"]


def test_the_plan_counts_the_approach_in_its_time_estimate() -> None:
    from rig.run.planning.order import trapezoid_time_s
    from rig.run.session import make_plan

    sweep = in_plane_sweep([30.0], [-30.0, 0.0, 30.0])
    straight, approached = make_plan(_rig("dynamixel", 0.0), sweep), make_plan(_rig("dynamixel", 3.0), sweep)
    n = len(approached.points)
    # Out past each pose and back: two 3 deg trapezoids of the default axes (60 deg/s, 120 deg/s^2) a point.
    per_point = 2.0 * float(trapezoid_time_s(3.0, 60.0, 120.0))
    assert approached.estimate.overhead_s == pytest.approx(straight.estimate.overhead_s + n * per_point)
    assert approached.estimate.total_s > straight.estimate.total_s
