"""The simulated GRBL rig: a virtual GRBL moves the joints, the rendered camera watches where they physically are."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from rig.instrument.geometry import JointLimits, RigGeometry
from rig.instrument.kinematics import Joints, inverse, require
from rig.instrument.links.grbl_protocol import GrblError
from rig.run.config.files import GRBL_PULLOFF_DEG, default_axes, default_grbl_axes
from rig.run.measuring.motion_guard import MotionGuard
from rig.run.session import make_plan
from simulator.from_config import spec_from
from simulator.grbl_rig import SimulatedGrblRig, grbl_settings
from simulator.rig import SimRigSpec, SimulatedRigError
from tests.run_helpers import in_plane_sweep, sim_rig
from tests.simulator.test_sim_rig import measure, predicted_counts

pytestmark = pytest.mark.mitsuba

# Where a run stopped: the last point's joints, as a resumed run's journal gives them to the backend.
STOPPED = {"light": 45.0, "camera": -15.0, "tilt": 0.0, "roll": 0.0}


def test_readings_match_the_model_at_the_pose_the_steppers_hold() -> None:
    with SimulatedGrblRig(SimRigSpec(seed=2)) as rig, rig.open_link() as link:
        target = require(inverse(rig.spec.geometry, 30.0, 0.0, 45.0, 180.0))
        link.move_to(target.as_dict())  # homes first: the port was just opened
        held = Joints.from_dict(link.wait_in_position(timeout_s=30.0))
        assert link.last_alarm is None and not link.position_lost
        physical = rig.joints_now()
        for name in ("light", "camera", "tilt", "roll"):  # whole steps of 0.1125 deg, reported to 0.001 deg
            assert getattr(physical, name) == pytest.approx(getattr(held, name), abs=5e-4 + 1e-9)
            assert getattr(physical, name) == pytest.approx(getattr(target, name), abs=0.5 * 360 / 3200 + 1e-9)
        np.testing.assert_allclose(measure(rig, (0.02, 0.02)), predicted_counts(rig, physical), rtol=0.01)


def test_a_reopened_port_reports_zero_wherever_the_axes_stand_and_the_camera_sees_where() -> None:
    with SimulatedGrblRig(SimRigSpec(seed=2), start=STOPPED) as rig:
        assert rig.joints_now().light == pytest.approx(45.0, abs=0.06)
        assert rig.joints_now().camera == pytest.approx(-15.0, abs=0.06)
        with rig.open_link(require_home=False) as link:
            # Opening the port reset GRBL: it counts from 0, which the axes map to their homing switches.
            reported = link.read_positions()
            assert reported["light"] == pytest.approx(rig.axes[0].zero_offset_deg)
            assert reported["camera"] == pytest.approx(rig.axes[1].zero_offset_deg)
        assert rig.joints_now().light == pytest.approx(45.0, abs=0.06)  # the machine did not move


@pytest.mark.parametrize("homes", [True, False])
def test_a_resumed_rig_measures_at_the_right_angles_only_after_homing(homes: bool) -> None:
    target = {"light": 30.0, "camera": -40.0, "tilt": 0.0, "roll": 0.0}
    with SimulatedGrblRig(SimRigSpec(seed=2), start=STOPPED) as rig:
        with rig.open_link(require_home=homes) as link:
            if not homes:
                link.unlock()  # $X: what a link that assumes its position does to get past GRBL's homing lock
            link.move_to(target)
            held = link.wait_in_position(timeout_s=60.0)
            physical = rig.joints_now()
        # The link believes it reached the target either way: only homing makes that true.
        assert held["light"] == pytest.approx(30.0, abs=0.06) and held["camera"] == pytest.approx(-40.0, abs=0.06)
        off = abs(physical.light - 30.0) + abs(physical.camera + 40.0)
        if homes:
            assert off < 0.12
        else:  # counted from the switch pose while it stood at STOPPED: off by the difference, as in the field
            assert off > 50.0, physical


def test_a_controller_without_homing_refuses_to_move_saying_why() -> None:
    with SimulatedGrblRig(SimRigSpec(seed=2), start=STOPPED) as rig:
        rig.controller.settings.values[22] = 0.0  # as if the lab never fitted homing switches
        with rig.open_link() as link:
            with pytest.raises(GrblError, match=r"homing is disabled \(\$22=0\)"):
                link.move_to({"light": 30.0})
        assert rig.joints_now().light == pytest.approx(45.0, abs=0.06)


@pytest.mark.parametrize("layout", ["four_axis", "in_plane", "fixed_camera"])
def test_default_axes_home_the_arms_apart_and_fit_grbl_machine_space(layout: str) -> None:
    geometry = RigGeometry(layout=layout)  # type: ignore[arg-type]
    axes = {a.name: a for a in default_grbl_axes(geometry)}
    assert [a.address for a in axes.values()] == list("XYZA"[: len(axes)])
    settings = grbl_settings(tuple(axes.values()))
    assert settings[20] == 1.0 and settings[22] == 1.0  # soft limits hold: every range maps into [-$130, 0]
    for a in axes.values():
        # Homed, each joint stands at one end of its range, one pull-off inside its switch.
        home = a.to_degrees(-GRBL_PULLOFF_DEG * a.units_per_degree)
        assert home == pytest.approx(a.min_deg if a.name == "camera" else a.max_deg)
    if "camera" in axes:
        light, camera = axes["light"], axes["camera"]
        # Homing raises light - camera from wherever a plan left it (light above camera) to its home value,
        # which stays min_separation_deg short of the arms meeting round the back.
        assert light.max_deg - camera.min_deg <= 360.0 - geometry.min_separation_deg
        narrow = RigGeometry(layout=layout, limits=JointLimits(light=(-90.0, 90.0), camera=(-90.0, 90.0)))  # type: ignore[arg-type]
        assert {a.name: (a.min_deg, a.max_deg) for a in default_grbl_axes(narrow)}["light"] == (-90.0, 90.0)


def test_axes_that_are_not_grbl_letters_are_refused() -> None:
    with pytest.raises(SimulatedRigError, match="axis 'light': address 1 is not a GRBL axis letter"):
        SimulatedGrblRig(SimRigSpec(axes=default_axes(RigGeometry())))  # Dynamixel ids


def test_the_runtime_guard_plans_a_move_from_where_the_arms_really_are() -> None:
    # A resumed GRBL run: the arms stand at STOPPED, the reopened port reports the switch pose. The guard must
    # not check the path from there: it reads the joints back only once the link has homed.
    rig_config = sim_rig(on="grbl")
    plan = make_plan(rig_config, in_plane_sweep([30.0], [-40.0, 40.0]))
    guard = MotionGuard(plan.paths, [p.joints for p in plan.points])
    with SimulatedGrblRig(spec_from(rig_config), start=STOPPED) as rig, rig.open_link() as link:
        seen: list[tuple[dict[str, float], Joints]] = []
        read = link.read_positions

        def spied() -> dict[str, float]:
            got = read()
            seen.append((got, rig.joints_now()))
            return got

        link.read_positions = spied  # type: ignore[method-assign]
        target = {k: float(v) for k, v in plan.points[0].joints.as_dict().items() if k in plan.paths.names}  # type: ignore[union-attr]
        legs = guard.legs(link, target)
        assert seen and legs[-1] == target
        for reported, physical in seen:  # every read-back the guard used is where the machine is
            assert reported["light"] == pytest.approx(physical.light, abs=0.12)
            assert reported["camera"] == pytest.approx(physical.camera, abs=0.12)


def test_a_frame_taken_while_a_feed_hold_slows_the_arm_is_blurred_along_the_motion() -> None:
    # GRBL reports a hold still slowing down as Hold:1 and one at rest as Hold:0: the camera must see the first
    # as motion (its sub-exposures rendered where the arm glides), the second as a pose at rest.
    rig = SimulatedGrblRig(SimRigSpec(seed=2))
    with rig, rig.open_link() as link:
        assert rig.camera is not None
        pose = require(inverse(rig.spec.geometry, 30.0, 0.0, 60.0, 180.0)).as_dict()
        start = {k: float(v) for k, v in pose.items()}
        link.move_to(start)  # homes first
        link.wait_in_position(timeout_s=60.0)
        renders: list[tuple[float, float]] = []
        inner = rig._radiance

        def recorded(*args: object, **kwargs: object) -> np.ndarray:
            renders.append((rig.clock.now(), float(rig.joints_now().as_dict()["camera"])))
            return inner(*args, **kwargs)  # type: ignore[arg-type]

        rig._radiance = recorded  # type: ignore[method-assign]
        rig.camera.set_exposure(0.02)
        link.move_to({**start, "camera": start["camera"] - 60.0})
        axis = next(a for a in rig.axes if a.name == "camera")
        rig.clock.sleep(2.0 * axis.max_speed_deg_s / axis.max_accel_deg_s2)  # well into the cruise
        link.feed_hold()
        link.status()  # answered in order after the hold: the deceleration has begun
        assert rig.controller.state == "Hold:1"
        assert rig.moving()
        renders.clear()
        rig.camera.capture()
        assert rig.controller.state == "Hold:1"  # the frame ended before the arm came to rest
        angles = [j for _, j in renders]
        assert len(angles) >= 4 and all(b < a for a, b in itertools.pairwise(angles)), angles
        steps = np.diff(angles[-4:])  # the sub-exposures', evenly spaced in time
        assert abs(steps[-1]) < abs(steps[0])  # slowing down along the frame
        rig.clock.sleep(axis.max_speed_deg_s / axis.max_accel_deg_s2)  # time enough to stop from full speed
        assert rig.controller.state == "Hold:0" and not rig.moving()
        renders.clear()
        rig.camera.capture()
        assert len(renders) == 1  # at rest: one render, no blur
        link.resume()
        link.wait_in_position(timeout_s=60.0)
