"""Simulated time does not depend on the machine's speed: a command acts at the simulated time it was sent.

A virtual device runs in its own thread. On a loaded host that thread may get to a client's bytes only after
the client has moved the shared ManualClock on (a SYNC_WRITE of goals or a GRBL feed hold has no reply to wait
for). The clock therefore settles every device before it advances. Each test holds the device's thread (a host
too busy to run it) while the client sends and moves time on, and compares with the same steps on a device that
was never held: the simulation must be the same, whatever the thread's timing.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import pytest

from rig.instrument.axis import Axis
from rig.instrument.clock import ManualClock
from rig.instrument.links.dynamixel import DynamixelLink
from rig.instrument.links.grbl import GrblLink
from simulator.dynamixel.bus import open_virtual_bus
from simulator.grbl.server import open_virtual_grbl

XM430 = dict(units_per_degree=4096 / 360, zero_offset_deg=-180.0, min_deg=-150.0, max_deg=150.0)


def _advance_while_held(clock: ManualClock, held: object, resume: Callable[[], None], seconds: float) -> None:
    """Advance ``clock`` while the device's thread is held; let the thread go once the clock waits for it.

    Without settling the advance returns at once and the thread is let go after it: the device then acts late.
    """
    done = threading.Event()

    def release() -> None:
        deadline = time.monotonic() + 60.0  # liveness only: the outcome never depends on this bound
        while not (getattr(held, "settling", 0) or done.is_set()) and time.monotonic() < deadline:
            time.sleep(0.001)  # polling the device's state from outside it, not waiting on hardware
        resume()

    thread = threading.Thread(target=release)
    thread.start()
    try:
        clock.advance(seconds)
    finally:
        done.set()
        thread.join(timeout=120.0)


def _servo_after_goal(hold: bool) -> tuple[float, bool]:
    clock = ManualClock()
    axis = Axis("light", 1, **XM430)  # type: ignore[arg-type]
    with open_virtual_bus(ids=(1,), clock=clock) as bus:
        with DynamixelLink.open(bus.port, [axis], clock=clock, latency_timer_ms=60.0) as link:
            if hold:
                bus.pause()
            link.move_to({"light": 60.0})  # one SYNC_WRITE: no reply, the link goes on at once
            if hold:
                _advance_while_held(clock, bus, bus.resume, 0.5)
            else:
                link.read_positions()  # a round trip: the bus has taken the write
                clock.advance(0.5)
            state = bus.servo(1).state()
            return state.position, state.moving


def test_a_goal_acts_when_it_was_sent_however_late_the_bus_thread_runs() -> None:
    held, free = _servo_after_goal(hold=True), _servo_after_goal(hold=False)
    assert free[1] and free[0] != pytest.approx(2048.0)  # half a second into the move: on its way
    assert held == free


def _axis_after_feed_hold(hold: bool) -> dict[str, float]:
    clock = ManualClock()
    axes = [Axis("light", "X", units_per_degree=10.0, max_speed_deg_s=20.0, max_accel_deg_s2=40.0)]
    with open_virtual_grbl(clock) as sim, GrblLink(sim.port, axes, clock=clock, configure=True) as link:
        link.move_to({"light": 60.0})
        clock.advance(1.0)
        if hold:
            sim.pause()
        link.feed_hold()  # a real-time byte: GRBL answers nothing
        if hold:
            _advance_while_held(clock, sim, sim.resume, 3.0)
        else:
            link.status()  # a round trip: the controller has taken the byte
            clock.advance(3.0)
        assert sim.controller.state == "Hold:0"
        return sim.controller.mpos


def test_a_feed_hold_acts_when_it_was_sent_however_late_the_controller_thread_runs() -> None:
    held, free = _axis_after_feed_hold(hold=True), _axis_after_feed_hold(hold=False)
    assert 0.0 < free["X"] < 60.0  # stopped part of the way
    assert held == free
