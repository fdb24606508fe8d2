"""The GRBL link waits for a status report in blocking reads (pyserial with a timeout), never in a spin."""

from __future__ import annotations

from rig.instrument.axis import Axis
from rig.instrument.clock import ManualClock
from rig.instrument.links.grbl import GrblLink
from simulator.grbl.server import open_virtual_grbl


def test_a_status_poll_takes_a_few_reads() -> None:
    clock = ManualClock()
    axes = [Axis(name="light", address="X", units_per_degree=10.0),
            Axis(name="camera", address="Y", units_per_degree=10.0)]  # fmt: skip
    with open_virtual_grbl(clock=clock, axes="XY") as server:
        link = GrblLink(server.port, axes, clock=clock)
        try:
            ser = link.session._ser
            assert ser is not None
            calls = [0]
            original = ser.read

            def read(size: int = 1) -> bytes:
                calls[0] += 1
                return original(size)

            ser.read = read
            polls = 100
            for _ in range(polls):
                assert link.session.status().state == "Idle"
            # The report arrives in one or two chunks; a lost one costs a retry's reads, not thousands.
            assert polls <= calls[0] <= 4 * polls
        finally:
            link.shutdown()
