"""An SDK client of the virtual bus, and the constants and helpers the SDK tests share."""

from __future__ import annotations

import time
from dataclasses import dataclass

from dynamixel_sdk import (
    COMM_SUCCESS,
    PacketHandler,
    PortHandler,
)

BAUDS = [57_600, 1_000_000]


IDS = (1, 2, 3, 4)


TORQUE, LED, GOAL, PRESENT = 64, 65, 116, 132


ALERT = 0x80


SDK_LATENCY_MS = 60
"""The SDK budgets 2 x 16 ms of USB latency per reply; on a loaded 2-core machine the bus thread can
be scheduled later than that, so the tests allow more, as one would raise it for a slow adapter."""


def signed32(value: int) -> int:
    return value - (1 << 32) if value & 0x80000000 else value


def le32(value: int) -> list[int]:
    return list((value & 0xFFFFFFFF).to_bytes(4, "little"))


@dataclass
class Client:
    """An SDK port and packet handler, plus the helpers the tests need."""

    port: PortHandler
    sdk: PacketHandler

    def read(self, dxl_id: int, address: int, size: int) -> int:
        op = {1: self.sdk.read1ByteTxRx, 2: self.sdk.read2ByteTxRx, 4: self.sdk.read4ByteTxRx}[size]
        value, result, error = op(self.port, dxl_id, address)
        assert (result, error) == (COMM_SUCCESS, 0), self.explain(result, error)
        return int(value)

    def write(self, dxl_id: int, address: int, size: int, value: int) -> None:
        op = {1: self.sdk.write1ByteTxRx, 2: self.sdk.write2ByteTxRx, 4: self.sdk.write4ByteTxRx}[size]
        result, error = op(self.port, dxl_id, address, value)
        assert (result, error) == (COMM_SUCCESS, 0), self.explain(result, error)

    def sync(self, dxl_id: int = 1) -> None:
        """A round trip: the bus handles packets in order, so everything sent before has now run.

        Needed before advancing a ManualClock after packets that get no reply (broadcasts, SYNC/BULK
        WRITE): otherwise the clock may move before the servo has even seen the goal.
        """
        assert self.sdk.ping(self.port, dxl_id)[1] == COMM_SUCCESS

    def explain(self, result: int, error: int) -> str:
        return f"{self.sdk.getTxRxResult(result)} {self.sdk.getRxPacketError(error)}"

    def await_bytes(self, count: int, timeout_s: float = 2.0) -> bytes:
        """Read ``count`` bytes the SDK does not read itself (bounded wait), e.g. replies to TxOnly calls."""
        deadline = time.monotonic() + timeout_s
        while self.port.getBytesAvailable() < count:
            assert time.monotonic() < deadline, f"expected {count} bytes, got {self.port.getBytesAvailable()}"
            time.sleep(0.001)  # a poll interval, not a wait for an outcome
        return bytes(self.port.readPort(count))


def connect(port_name: str, baud: int) -> Client:
    port = PortHandler(port_name)
    assert port.openPort(), f"cannot open {port_name}"
    assert port.setBaudRate(baud)
    return Client(port, PacketHandler(2.0))
