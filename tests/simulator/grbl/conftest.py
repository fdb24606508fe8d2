"""Fixtures of the virtual-GRBL tests: a shared ManualClock, and a GRBL with a client attached."""

from __future__ import annotations

import pytest

from rig.instrument.clock import ManualClock
from simulator.grbl.server import open_virtual_grbl
from tests.simulator.grbl.grbl_client import Client


@pytest.fixture
def clock():
    return ManualClock()


@pytest.fixture
def grbl(clock, request):
    settings = getattr(request, "param", None)
    with open_virtual_grbl(clock, settings=settings) as sim:
        client = Client(sim.port, clock)
        yield client, sim
        client.close()
