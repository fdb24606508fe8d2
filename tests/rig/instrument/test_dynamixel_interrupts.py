"""A stop reaches every servo from any interrupt point: Ctrl-C inside an SDK transaction, then the runner's stop path.

A signal raised inside ``dynamixel_sdk`` leaves ``PortHandler.is_using`` set (and maybe a reply on the wire). The
trials below raise KeyboardInterrupt at the n-th call the SDK makes on the port (writes, reads, byte counts,
timeouts) while the arms move and are polled, so n walks through the inside of every kind of transaction; then
they run what the runner does on a stop (``stop()``, ``shutdown()`` by the torque policy) and look at the servos
themselves.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import pytest

from rig.instrument.clock import ManualClock
from rig.instrument.links.base import LinkError
from rig.instrument.links.dynamixel import DynamixelLink
from simulator.dynamixel import open_virtual_bus
from simulator.dynamixel.bus import VirtualDynamixelBus
from tests.rig.instrument.test_dynamixel_link import LATENCY_MS, make_axes

#: The port methods the SDK calls inside a transaction.
PORT_CALLS = ("clearPort", "writePort", "readPort", "getBytesAvailable", "setPacketTimeout", "isPacketTimeout")


class Injector:
    """Raises KeyboardInterrupt at the n-th SDK call on the port once armed; counts calls otherwise."""

    def __init__(self, port: Any) -> None:
        self.calls = 0
        self.at: int | None = None
        self.fired = False
        for name in PORT_CALLS:
            setattr(port, name, self._wrap(getattr(port, name)))

    def _wrap(self, real: Callable[..., Any]) -> Callable[..., Any]:
        def call(*args: Any) -> Any:
            if self.at is not None:
                self.calls += 1
                if self.calls == self.at:
                    self.fired = True
                    self.at = None
                    raise KeyboardInterrupt
            return real(*args)

        return call


def interrupt_trial(bus: VirtualDynamixelBus, clock: ManualClock, at: int, hold: bool) -> tuple[bool, list[str]]:
    """Move and poll, interrupted at SDK call ``at``; then stop and shut down as the runner does.

    Returns whether the interrupt fired and what is unsafe afterwards (empty: every servo safe).
    """
    link = DynamixelLink.open(bus.port, make_axes(), clock=clock, latency_timer_ms=LATENCY_MS)
    injector = Injector(link.bus._port)
    injector.at = at
    try:
        for target in (40.0, -35.0, 20.0):
            link.move_to(dict.fromkeys(("light", "camera", "tilt", "roll"), target))
            clock.advance(0.3)  # the arms are mid-move when the next polls come
            link.wait_in_position(timeout_s=30.0)
    except KeyboardInterrupt:
        pass
    fired = injector.fired
    injector.at = None
    # The runner's stop path: stop first (errors reported, not raised), then shutdown by the policy.
    problems: list[str] = []
    try:
        link.stop()
    except LinkError as exc:
        problems.append(f"stop: {exc}")
    try:
        link.shutdown(keep_torque=hold)
    except LinkError as exc:
        problems.append(f"shutdown: {exc}")
    clock.advance(5.0)  # long enough for any move still running to end
    for servo in bus.servos:
        if hold:
            # Holding: torque on, and no longer on its way to the old goal (stopped where it was).
            before = servo.present_position_ticks()
            clock.advance(1.0)
            if not servo.torque_enabled or servo.present_position_ticks() != before:
                problems.append(f"servo {servo.id} not holding still")
        elif servo.torque_enabled:
            problems.append(f"servo {servo.id} still powered")
    for servo in bus.servos:  # the next trial starts from a powered-down rest
        servo.poke("torque_enable", 0)
    return fired, problems


@pytest.fixture
def rig() -> Iterator[tuple[VirtualDynamixelBus, ManualClock]]:
    clock = ManualClock()
    with open_virtual_bus(ids=(1, 2, 3, 4), baudrate=1_000_000, clock=clock) as bus:
        yield bus, clock


def test_a_stop_reaches_every_servo_from_any_interrupt_point(rig: tuple[VirtualDynamixelBus, ManualClock]) -> None:
    bus, clock = rig
    fired = 0
    failures = []
    # Interrupt points spread over the whole move-and-poll sequence (every 3rd SDK call, both torque policies).
    for trial, at in enumerate(range(1, 331, 3)):
        hit, problems = interrupt_trial(bus, clock, at, hold=trial % 5 == 4)
        fired += hit
        if problems:
            failures.append((at, problems))
    assert fired >= 100, fired
    assert not failures, failures[:3]


def test_a_pulled_cable_is_a_link_error_not_an_os_error(rig: tuple[VirtualDynamixelBus, ManualClock]) -> None:
    bus, clock = rig
    link = DynamixelLink.open(bus.port, make_axes(), clock=clock, latency_timer_ms=LATENCY_MS)
    link.move_to({"light": 30.0})
    bus.close()  # the device end of the line is gone: the port answers EIO
    with pytest.raises(LinkError, match=r"the port failed .*unplugged"):
        link.wait_in_position(timeout_s=10.0)
    with pytest.raises(LinkError, match="shutdown incomplete"):
        link.shutdown()
    link.shutdown()  # and again: quiet, the port is closed


def test_a_slow_host_gets_its_reply_instead_of_a_hardware_fault(rig: tuple[VirtualDynamixelBus, ManualClock]) -> None:
    bus, clock = rig
    # A 1 ms latency timer gives a ~4 ms reply window; a servo answers after 30 ms (a host or adapter that is
    # late), so the first tries time out. The link waits longer instead of calling the servo dead.
    link = DynamixelLink.open(bus.port, make_axes(), clock=clock, latency_timer_ms=1.0, retries=1)
    link.bus.reply_patience_s = 60.0  # generous: how long a slow host may take must not decide this test
    bus.servo(1).faults.reply_delay_s = 0.03
    link.move_to({"light": 2.0})
    held = link.wait_in_position(timeout_s=30.0)
    assert abs(held["light"] - 2.0) < 0.2
    assert link.bus.comm_retries_used > 0
    link.shutdown()
