"""Reads block: the real dynamixel_sdk's receive loop calls readPort a few times per status packet, not
hundreds, whether the reply comes at once or late (the SDK's own port spins with a zero timeout)."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator

import pytest

from rig.instrument.clock import ManualClock
from rig.instrument.links.dynamixel_bus import DynamixelBus
from rig.instrument.links.dynamixel_table import X_SERIES
from simulator.dynamixel import open_virtual_bus
from simulator.dynamixel.bus import VirtualDynamixelBus
from simulator.dynamixel.control_table import MODEL_NUMBER

IDS = (1, 2, 3, 4)
#: readPort calls one status packet may take: the 11-byte head, the rest, and one spare for a split write.
CALLS_PER_PACKET = 3


@pytest.fixture
def vbus() -> Iterator[VirtualDynamixelBus]:
    with open_virtual_bus(ids=IDS, clock=ManualClock()) as b:
        yield b
        assert not b.errors, b.errors


def counted(bus: DynamixelBus) -> list[int]:
    """Count the SDK's readPort calls on ``bus`` from now on (a one-element list, so callers see it grow)."""
    calls = [0]
    port = bus._port
    original: Callable[[int], bytes] = port.readPort

    def read(length: int) -> bytes:
        calls[0] += 1
        return original(length)

    port.readPort = read  # type: ignore[method-assign]
    return calls


def test_each_status_packet_takes_a_few_reads(vbus: VirtualDynamixelBus) -> None:
    with DynamixelBus(vbus.port, latency_timer_ms=60.0) as bus:
        bus.ping(1)
        calls = counted(bus)
        address, size = X_SERIES.motion_block
        reps = 40
        for _ in range(reps):
            assert set(bus.sync_read(address, size, list(IDS))) == set(IDS)
            bus.ping(2)
            bus.read(3, X_SERIES.present_position, 4)
        packets = reps * (len(IDS) + 2)
        # A reply lost on a loaded host is retried: allow each retry a packet's reads, a timeout's included.
        allowed = CALLS_PER_PACKET * (packets + (1 + len(IDS)) * bus.comm_retries_used)
        assert packets <= calls[0] <= allowed


def test_a_late_reply_is_waited_for_not_polled(vbus: VirtualDynamixelBus) -> None:
    # A 4 s reply window; the bus is held while the client waits, then let go.
    with DynamixelBus(vbus.port, latency_timer_ms=2000.0) as bus:
        bus.ping(1)
        calls = counted(bus)
        vbus.pause()
        result: list[int] = []
        reader = threading.Thread(target=lambda: result.append(bus.ping(4)))
        reader.start()
        try:
            deadline = time.monotonic() + 60.0
            while calls[0] < 1:  # the client has sent its ping and sits in its first read
                assert time.monotonic() < deadline, "the client never started reading"
                threading.Event().wait(0.005)
            # Hold the reply a while longer: a spinning read would fill this with thousands of calls.
            threading.Event().wait(0.3)
        finally:
            vbus.resume()
            reader.join(timeout=120.0)
        assert result == [MODEL_NUMBER]
        assert calls[0] <= CALLS_PER_PACKET * (1 + bus.comm_retries_used)
