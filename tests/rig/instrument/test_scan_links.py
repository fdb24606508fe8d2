"""What continuous scans ask of a link (``ScanLink``): a speed cap the device runs at, and where it comes to rest."""

from __future__ import annotations

import re

import numpy as np
import pytest

from rig.instrument.clock import ManualClock
from rig.instrument.links.base import ScanLink
from rig.instrument.links.dynamixel import DynamixelLink
from rig.instrument.links.grbl import GrblLink
from simulator.dynamixel import open_virtual_bus
from simulator.grbl.server import open_virtual_grbl
from tests.rig.instrument.test_dynamixel_link import LATENCY_MS
from tests.rig.instrument.test_dynamixel_link import make_axes as servo_axes
from tests.rig.instrument.test_grbl_link import connect


def test_a_grbl_scan_runs_at_the_capped_speed_in_g1_feed_units_per_minute_while_it_is_polled() -> None:
    clock = ManualClock()
    with open_virtual_grbl(clock) as sim, connect(sim, clock) as link:
        assert isinstance(link, GrblLink) and isinstance(link, ScanLink)
        # The light arm is geared 3:1: 5 deg/s of joint is 15 motor deg/s, a feed of 900 motor deg/min.
        assert link.set_speed({"light": 5.0}) == {"light": 5.0}
        link.move_to({"light": 20.0})
        assert re.search(r" F900$", str(link.session.last_motion_line))
        clock.advance(1.0)  # past the ramp (15 / 120 s)
        seen = []
        for _ in range(4):
            status = link.status()
            assert status.state == "Run" and status.feed == 900.0
            seen.append((clock.now(), link.read_positions()["light"]))
            clock.advance(0.3)
        t, deg = np.array(seen).T
        # Each read-back is a whole step (1/30 deg of joint) of a path at 5 deg/s.
        assert np.diff(deg) / np.diff(t) == pytest.approx([5.0] * 3, abs=2 / 30 / 0.3)
        link.wait_in_position(timeout_s=10.0)
        link.set_speed(None)
        link.move_to({"light": 0.0})
        assert re.search(r" F3600$", str(link.session.last_motion_line))  # back to the axis's top, 20 deg/s x 3


def test_where_a_grbl_axis_comes_to_rest_is_its_target_rounded_to_whole_steps() -> None:
    clock = ManualClock()
    with open_virtual_grbl(clock) as sim, connect(sim, clock) as link:
        # 30 steps per joint degree: 10.01 deg is step 300.3, so the arm rests on step 300, short of the target.
        pose = {"light": 10.01, "camera": -20.0}
        assert link.stops_at(pose) == pytest.approx({"light": 10.0, "camera": -20.0}, abs=1e-12)
        link.move_to(pose)
        assert link.wait_in_position(timeout_s=10.0) == pytest.approx(link.stops_at(pose), abs=1e-9)


def test_where_a_servo_comes_to_rest_is_its_target_rounded_to_whole_counts() -> None:
    clock = ManualClock()
    with open_virtual_bus(ids=(1, 2, 3, 4), baudrate=1_000_000, clock=clock) as bus:
        link = DynamixelLink.open(bus.port, servo_axes(), clock=clock, latency_timer_ms=LATENCY_MS)
        with link:
            assert isinstance(link, ScanLink)
            pose = {"camera": 10.03}  # count 2162.1 (2048 at 0 deg): it rests on count 2162, short of the target
            assert link.stops_at(pose)["camera"] == pytest.approx((2162 - 2048) * 360 / 4096)
            link.move_to(pose)
            assert link.wait_in_position(timeout_s=10.0)["camera"] == pytest.approx(link.stops_at(pose)["camera"])
