"""Bus latency: what one poll and one move-and-settle cycle cost over the virtual buses, against the wire.

The anchor is the physical limit: the time the packets' bytes take on the line at its baud rate (10 bits
per byte: start, 8 data, stop), with a zero Return Delay Time. A pty moves bytes at memory speed, so the
measured time is all software (the SDK's packet handling, our bus owner, the virtual servos); a ratio
below 1 says the software is faster than a real 1 Mbps line could be, so on hardware the wire (plus the
USB adapter's latency timer) sets the pace, not this code.

1. One SYNC_READ of Moving, Moving Status and Present Position (14 bytes) from 4 servos: through the raw
   ``dynamixel_sdk`` GroupSyncRead on the SDK's own port (zero read timeout: its receive loop spins, so a
   loaded host loses replies, counted as "lost" rather than stopping the benchmark), and through
   ``DynamixelBus.sync_read`` (reads that block in select(), lock, retries, error bytes).
2. One full move-and-settle cycle of ``DynamixelLink`` (one SYNC_WRITE, then SYNC_READ polls every 10 ms
   of simulated time until all four axes are in position), on a ManualClock so the motion costs only its
   polls; its wire time is the SYNC_WRITE plus every poll's bytes.
3. One GRBL status poll (``?`` -> ``<Idle|MPos:...>``) at 115200 baud, for comparison.

Every exchange reports its spread (min, median, max of the timed repetitions), how many ``readPort`` calls
the SDK made per transaction, and the load average, since the machine is usually shared.

Run: ``.venv/bin/python -m bench.bus_latency [--reps N] [--no-docs]``.
"""

from __future__ import annotations

import datetime
import statistics
import time

import dynamixel_sdk as sdk

from bench._common import (
    bench_parser,
    format_table,
    load_average,
    machine_description,
    markdown_table,
    record,
    timed_calls,
)
from rig.instrument.axis import Axis
from rig.instrument.clock import ManualClock
from rig.instrument.geometry import RigGeometry
from rig.instrument.links.dynamixel import DynamixelLink, DynamixelOptions
from rig.instrument.links.dynamixel_table import X_SERIES
from rig.instrument.links.grbl import GrblLink
from rig.run.config.files import default_axes
from simulator.dynamixel import open_virtual_bus
from simulator.grbl.server import open_virtual_grbl

BAUD = 1_000_000
GRBL_BAUD = 115_200
IDS = (1, 2, 3, 4)
BITS_PER_BYTE = 10
POSE = {"light": 30.0, "camera": -45.0, "tilt": 10.0, "roll": 90.0}


def packet_bytes(n_params: int) -> int:
    """Bytes of a Protocol 2.0 packet with ``n_params`` parameter bytes (header, id, length, inst, CRC)."""
    return 10 + n_params


def sync_read_bytes(n_servos: int, data: int) -> int:
    """Wire bytes of one SYNC_READ: the instruction (address, length, ids) and one status per servo."""
    return packet_bytes(4 + n_servos) + n_servos * packet_bytes(1 + data)


def sync_write_bytes(n_servos: int, data: int) -> int:
    """Wire bytes of one SYNC_WRITE (no replies)."""
    return packet_bytes(4 + n_servos * (1 + data))


def wire_s(n_bytes: int, baud: int) -> float:
    """Seconds ``n_bytes`` take on a UART line at ``baud``."""
    return n_bytes * BITS_PER_BYTE / baud


def spread(samples: list[float]) -> list[str]:
    """Min, median and max of wall-clock ``samples`` (seconds) as table cells in milliseconds."""
    if not samples:
        return ["-", "-", "-"]
    return [f"{min(samples) * 1e3:.3f}", f"{statistics.median(samples) * 1e3:.3f}", f"{max(samples) * 1e3:.3f}"]


def count_reads(port: sdk.PortHandler) -> list[int]:
    """Count ``port.readPort`` calls from now on (a one-element list that grows)."""
    calls = [0]
    original = port.readPort

    def read(length: int) -> object:
        calls[0] += 1
        return original(length)

    port.readPort = read
    return calls


def dynamixel_rows(reps: int) -> list[list[str]]:
    """Rows for the Dynamixel measurements."""
    address, size = X_SERIES.motion_block
    read_wire = wire_s(sync_read_bytes(len(IDS), size), BAUD)
    rows = []
    clock = ManualClock()
    with open_virtual_bus(ids=IDS, baudrate=BAUD, clock=clock) as vbus:
        port = sdk.PortHandler(vbus.port)
        ph = sdk.PacketHandler(2.0)
        port.openPort()
        group = sdk.GroupSyncRead(port, ph, address, size)
        for i in IDS:
            group.addParam(i)
        lost = 0

        def raw() -> None:
            nonlocal lost
            if group.txRxPacket() != sdk.COMM_SUCCESS:
                lost += 1
                port.clearPort()  # a late reply must not pass for the next one

        timed_calls(raw, 10, warmup=0)
        lost, calls = 0, count_reads(port)
        samples = timed_calls(raw, reps, warmup=0)
        port.closePort()
        med = statistics.median(samples)
        rows.append(["SYNC_READ 4 x 14 B, raw dynamixel_sdk (spinning reads)", *spread(samples),
                     f"{read_wire * 1e3:.3f}", f"{med / read_wire:.2f}", f"{calls[0] / reps:.1f}",
                     f"{lost} of {reps}"])  # fmt: skip

        link = DynamixelLink.open(vbus.port, default_axes(RigGeometry()), clock=clock, latency_timer_ms=60.0,
                                  options=DynamixelOptions(poll_interval_s=0.01))  # fmt: skip
        try:
            timed_calls(lambda: link.bus.sync_read(address, size, list(IDS)), 10, warmup=0)
            retries, calls = link.bus.comm_retries_used, count_reads(link.bus._port)
            samples = timed_calls(lambda: link.bus.sync_read(address, size, list(IDS)), reps, warmup=0)
            med = statistics.median(samples)
            rows.append(["SYNC_READ 4 x 14 B, DynamixelBus (blocking reads)", *spread(samples),
                         f"{read_wire * 1e3:.3f}", f"{med / read_wire:.2f}", f"{calls[0] / reps:.1f}",
                         f"0 of {reps} ({link.bus.comm_retries_used - retries} retried)"])  # fmt: skip

            polls = 0
            original = link.poll

            def counted() -> dict[str, object]:
                nonlocal polls
                polls += 1
                return original()  # type: ignore[return-value]

            link.poll = counted  # type: ignore[method-assign,assignment]
            targets = [POSE, dict.fromkeys(POSE, 0.0)]
            cycles: list[float] = []
            polls_per_cycle: list[int] = []
            settle_s: list[float] = []
            calls[0] = 0
            for k in range(max(4, reps // 50)):
                polls = 0
                t_sim = clock.now()
                t0 = time.perf_counter()
                link.move_to(targets[k % 2])
                link.wait_in_position(timeout_s=60.0)
                cycles.append(time.perf_counter() - t0)
                polls_per_cycle.append(polls)
                settle_s.append(clock.now() - t_sim)
            n_polls = statistics.median(polls_per_cycle)
            cycle_wire = wire_s(sync_write_bytes(len(IDS), 4), BAUD) + n_polls * read_wire
            med = statistics.median(cycles)
            rows.append([f"move and settle ({statistics.median(settle_s):.2f} s simulated, {n_polls:.0f} polls)",
                         *[f"{float(c):.2f}" for c in spread(cycles)], f"{cycle_wire * 1e3:.2f}",
                         f"{med / cycle_wire:.2f}", f"{calls[0] / sum(polls_per_cycle):.1f} per poll",
                         "0"])  # fmt: skip
        finally:
            link.shutdown()
    return rows


def grbl_row(reps: int) -> list[str]:
    """Row for one GRBL status poll."""
    clock = ManualClock()
    with open_virtual_grbl(clock=clock, axes="XY") as server:
        grbl_axes = [Axis(name="light", address="X", units_per_degree=10.0),
                     Axis(name="camera", address="Y", units_per_degree=10.0)]  # fmt: skip
        link = GrblLink(server.port, grbl_axes, clock=clock)
        try:
            report = f"<Idle|MPos:{0:.3f},{0:.3f}|FS:0,0>\r\n"
            wire = wire_s(1 + len(report), GRBL_BAUD)
            samples = timed_calls(link.status, max(50, reps // 4), warmup=10)
        finally:
            link.shutdown()
    med = statistics.median(samples)
    return ["GRBL status poll ? -> report", *spread(samples), f"{wire * 1e3:.3f}", f"{med / wire:.2f}", "-", "0"]


HEADERS = ["exchange", "min ms", "median ms", "max ms", "wire ms (anchor)", "ratio", "reads/transaction", "lost"]


def main() -> None:
    """Measure, print and record the bus latencies."""
    parser = bench_parser(__doc__)
    parser.add_argument("--reps", type=int, default=1000, help="timed repetitions per exchange (default 1000)")
    args = parser.parse_args()
    machine = machine_description()
    today = datetime.date.today().isoformat()
    load_before = load_average()
    rows = [*dynamixel_rows(args.reps), grbl_row(args.reps)]
    load = f"{load_before} before, {load_average()} after"
    print(f"# bus_latency, {today}\nMachine: {machine}; {load}\nDynamixel at {BAUD} baud, GRBL at {GRBL_BAUD} baud; "
          "ratio = measured median / wire time of the same bytes\n")  # fmt: skip
    print(format_table(HEADERS, rows))
    if not args.no_docs:
        record(
            "bus_latency", "Bus latency", f" --reps {args.reps}", f"{machine}; shared with other work, {load}.",
            "Virtual buses on a pty, the real `dynamixel_sdk` and pyserial as clients. Anchor: the wire time of the "
            f"same packets at the line's baud rate (10 bits per byte, zero return delay). Dynamixel at {BAUD} baud, "
            f"GRBL at {GRBL_BAUD}. A ratio below 1 means the software costs less than the line itself would. "
            "reads/transaction: the SDK's `readPort` calls per transaction (the raw SDK's port spins with a zero "
            "timeout; `DynamixelBus` waits in select()). lost: transactions without a valid reply.",
            markdown_table(HEADERS, rows),
        )  # fmt: skip


if __name__ == "__main__":
    main()
