"""Fixtures of the virtual-bus tests: each baud rate, a shared ManualClock, a patient SDK, the bus, a client."""

from __future__ import annotations

from collections.abc import Iterator

import dynamixel_sdk.port_handler
import pytest

from rig.instrument.clock import ManualClock
from simulator.dynamixel import VirtualDynamixelBus, open_virtual_bus
from tests.simulator.dynamixel.sdk_client import BAUDS, IDS, SDK_LATENCY_MS, Client, connect


@pytest.fixture(params=BAUDS, ids=["57600", "1M"])
def baud(request: pytest.FixtureRequest) -> int:
    return int(request.param)


@pytest.fixture
def clock() -> ManualClock:
    return ManualClock()


@pytest.fixture(autouse=True)
def _patient_sdk(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(dynamixel_sdk.port_handler, "LATENCY_TIMER", SDK_LATENCY_MS)


@pytest.fixture
def bus(baud: int, clock: ManualClock) -> Iterator[VirtualDynamixelBus]:
    with open_virtual_bus(IDS, baud, clock) as b:
        yield b
        assert not b.errors, b.errors


@pytest.fixture
def client(bus: VirtualDynamixelBus, baud: int) -> Iterator[Client]:
    c = connect(bus.port, baud)
    yield c
    c.port.closePort()
