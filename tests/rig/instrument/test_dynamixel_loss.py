"""The Dynamixel bus's reply window on a bus that loses replies and on a host that answers late.

The real ``dynamixel_sdk`` against the virtual bus on a ``ManualClock``: a dropped reply costs its window on the
simulated clock (the bus settles, sees nothing will come, and charges the wait there), never on the wall.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from rig.instrument.clock import ManualClock
from rig.instrument.links.dynamixel import DynamixelLink
from rig.instrument.links.dynamixel_bus import LOSS_LIMIT, MAX_TIMEOUT_SCALE, CommunicationError
from simulator.dynamixel import open_virtual_bus
from simulator.dynamixel.bus import VirtualDynamixelBus
from tests.rig.instrument.test_dynamixel_link import LATENCY_MS, NAMES, make_axes

#: The SDK's reply window for a 4-servo SYNC_READ of 14 bytes at 1 Mbps with a 60 ms latency timer (ms).
WINDOW_MS = 2 * LATENCY_MS + 2.0 + 0.01 * (11 + 14) * 4


@pytest.fixture
def rig() -> Iterator[tuple[VirtualDynamixelBus, ManualClock]]:
    clock = ManualClock()
    with open_virtual_bus(ids=(1, 2, 3, 4), baudrate=1_000_000, clock=clock) as bus:
        yield bus, clock


def _lose(bus: VirtualDynamixelBus, p: float) -> None:
    for servo in bus.servos:
        servo.faults.reseed(100 + servo.id)
        servo.faults.drop_probability = p


def test_a_bus_losing_5_percent_of_replies_keeps_its_window_and_costs_one_window_a_loss(
    rig: tuple[VirtualDynamixelBus, ManualClock],
) -> None:
    bus, clock = rig
    link = DynamixelLink.open(bus.port, make_axes(), clock=clock, latency_timer_ms=LATENCY_MS, retries=2)
    _lose(bus, 0.05)
    start = clock.now()
    for _ in range(400):
        link.read_positions()
    spent = clock.now() - start
    lost = link.bus.replies_lost
    _lose(bus, 0.0)
    link.shutdown()
    # About one read in five loses a reply (1 - 0.95^4): each such loss is one SDK window and a retry on the
    # simulated clock. Before, every loss doubled a window kept for 200 replies on time, which a read at this
    # loss never sees: it sat at 64 x (7.9 s) and a loss cost that.
    assert 40 <= lost <= 120, lost
    assert link.bus.window_scale == 1.0
    assert spent <= lost * 2.0 * WINDOW_MS / 1000.0, (spent, lost)
    assert link.bus.loss_rate < LOSS_LIMIT


def test_a_bus_losing_most_replies_is_a_hardware_fault_naming_the_loss(
    rig: tuple[VirtualDynamixelBus, ManualClock],
) -> None:
    bus, clock = rig
    link = DynamixelLink.open(bus.port, make_axes(), clock=clock, latency_timer_ms=LATENCY_MS, retries=2)
    for _ in range(60):  # a history of replies on time: the loss shows against it
        link.read_positions()
    _lose(bus, 0.6)
    with pytest.raises(CommunicationError, match=r"\d+% of the last \d+ replies lost or garbled") as info:
        for _ in range(100):
            link.read_positions()
    assert "sync read" in str(info.value)
    _lose(bus, 0.0)
    link.shutdown()


@pytest.fixture
def fast_link(rig: tuple[VirtualDynamixelBus, ManualClock]) -> Iterator[tuple[VirtualDynamixelBus, DynamixelLink]]:
    """A link with a 1 ms latency timer (the SDK's window ~4 ms, the widest 16 x that); clears servo 2's faults."""
    bus, clock = rig
    link = DynamixelLink.open(bus.port, make_axes(), clock=clock, latency_timer_ms=1.0, retries=1)
    try:
        yield bus, link
    finally:
        bus.servo(2).faults.clear()
        link.shutdown()


def test_a_reply_later_than_the_widest_window_is_waited_for_within_the_patience(
    fast_link: tuple[VirtualDynamixelBus, DynamixelLink],
) -> None:
    bus, link = fast_link
    # A servo that answers after 200 ms is there, on a host too slow for the widest window (~70 ms; a pty-served
    # device under load): the bus keeps asking at the widest window for its whole patience instead of reporting
    # no servo after ~130 ms.
    assert link.bus.reply_patience_s >= 1.0
    bus.servo(2).faults.reply_delay_s = 0.2
    assert set(link.read_positions()) == set(NAMES)
    assert link.bus.comm_retries_used >= 1


def test_late_replies_widen_the_window_and_replies_on_time_narrow_it_again(
    fast_link: tuple[VirtualDynamixelBus, DynamixelLink],
) -> None:
    bus, link = fast_link
    # A servo that answers after 30 ms of wall time is late for the ~4 ms window.
    link.bus.reply_patience_s = 60.0
    bus.servo(2).faults.reply_delay_s = 0.03
    link.read_positions()
    widened = link.bus.window_scale
    assert 4.0 <= widened <= MAX_TIMEOUT_SCALE  # 30 ms needs at least 7 x the 4.2 ms window
    link.read_positions()
    assert link.bus.window_scale >= 0.9 * widened  # still as slow: the window stays wide enough
    bus.servo(2).faults.clear()
    for _ in range(40):  # back on time: narrowed by 0.9 a reply, to the SDK's window within ~30 replies
        link.read_positions()
    assert link.bus.window_scale == 1.0
    assert link.bus.replies_lost == 0  # a late reply is no loss


def test_a_reply_delivered_in_two_pieces_is_late_not_garbled(
    fast_link: tuple[VirtualDynamixelBus, DynamixelLink],
) -> None:
    bus, link = fast_link
    # The first half of each reply, then the rest 30 ms on: the ~4 ms window closes on a partial reply, which the SDK
    # calls corrupt. Its rest arriving is what a loaded host or an adapter's latency timer does, not a garbled
    # line: the window widens until the whole reply fits, and nothing counts as lost.
    link.bus.reply_patience_s = 60.0
    bus.servo(2).faults.reply_split_s = 0.03
    assert set(link.read_positions()) == set(NAMES)
    assert link.bus.comm_retries_used >= 1 and link.bus.window_scale > 1.0
    assert link.bus.replies_lost == 0


def test_an_absent_servo_is_not_a_lossy_bus(fast_link: tuple[VirtualDynamixelBus, DynamixelLink]) -> None:
    _bus, link = fast_link
    # Pinging ids nobody has (commissioning: `gonio servo ping 1 2 3 4 5` on a chain of four) must not teach the
    # bus that it loses replies: counted as losses, each absent id would buy the next ping more retries.
    for absent in (7, 9):
        with pytest.raises(CommunicationError):
            link.bus.ping(absent)
        assert link.bus.replies_lost == 0 and link.bus.loss_rate == 0.0
    assert set(link.read_positions()) == set(NAMES)
