"""The virtual bus driven by the unmodified ``dynamixel_sdk`` over a pseudo-terminal, as a real client would.

Every SDK instruction runs at 57600 and at 1000000 baud. Motion is driven by a ``ManualClock`` shared
with the test, so nothing waits for a servo; the only real waits are the SDK's own packet timeouts (tens
of ms) when a reply is meant to be missing, and bounded polls for bytes already on their way.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass

import dynamixel_sdk.port_handler
import pytest
import serial
from dynamixel_sdk import (
    COMM_NOT_AVAILABLE,
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupBulkRead,
    GroupBulkWrite,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
    PortHandler,
)

from rig.instrument.clock import ManualClock
from simulator.dynamixel import HardwareError, VirtualDynamixelBus, open_virtual_bus, serve_forever
from simulator.dynamixel.protocol import Instruction, build_packet, build_status

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


def connect(port_name: str, baud: int) -> Client:
    port = PortHandler(port_name)
    assert port.openPort(), f"cannot open {port_name}"
    assert port.setBaudRate(baud)
    return Client(port, PacketHandler(2.0))


@pytest.fixture
def client(bus: VirtualDynamixelBus, baud: int) -> Iterator[Client]:
    c = connect(bus.port, baud)
    yield c
    c.port.closePort()


def test_ping_every_servo(client: Client) -> None:
    for dxl_id in IDS:
        assert client.sdk.ping(client.port, dxl_id) == (1020, COMM_SUCCESS, 0)
    assert client.sdk.ping(client.port, 9)[1] == COMM_RX_TIMEOUT


def test_broadcast_ping_finds_all_servos(client: Client, bus: VirtualDynamixelBus) -> None:
    bus.servo(3).poke("id", 9)  # replies come in ID order whatever the creation order
    found, result = client.sdk.broadcastPing(client.port)
    assert result == COMM_SUCCESS
    assert found == {1: [1020, 46], 2: [1020, 46], 4: [1020, 46], 9: [1020, 46]}


def test_read_and_write_every_size(client: Client, bus: VirtualDynamixelBus) -> None:
    client.write(1, LED, 1, 1)
    assert client.read(1, LED, 1) == 1
    client.write(1, 84, 2, 900)  # Position P Gain
    assert client.read(1, 84, 2) == 900
    client.write(2, 20, 4, -1500 & 0xFFFFFFFF)  # Homing Offset is signed
    assert signed32(client.read(2, 20, 4)) == -1500
    assert signed32(client.read(2, PRESENT, 4)) == 2048 - 1500
    assert client.read(3, 0, 2) == 1020
    assert bus.servo(1).value("led") == 1


def test_split_transmit_and_receive_calls(client: Client) -> None:
    sdk, port = client.sdk, client.port
    assert sdk.read4ByteTx(port, 2, PRESENT) == COMM_SUCCESS
    assert sdk.read4ByteRx(port, 2) == (2048, COMM_SUCCESS, 0)
    assert sdk.read2ByteTx(port, 2, 144) == COMM_SUCCESS
    assert sdk.read2ByteRx(port, 2) == (120, COMM_SUCCESS, 0)
    assert sdk.read1ByteTx(port, 2, 146) == COMM_SUCCESS
    assert sdk.read1ByteRx(port, 2) == (36, COMM_SUCCESS, 0)
    # TxOnly writes: the servo still answers (Status Return Level 2); the SDK leaves the reply unread.
    for op, value in ((sdk.write1ByteTxOnly, 1), (sdk.write2ByteTxOnly, 700), (sdk.write4ByteTxOnly, 5)):
        address = {sdk.write1ByteTxOnly: LED, sdk.write2ByteTxOnly: 84, sdk.write4ByteTxOnly: 24}[op]
        assert op(port, 3, address, value) == COMM_SUCCESS
        client.await_bytes(11)
    assert (client.read(3, LED, 1), client.read(3, 84, 2), client.read(3, 24, 4)) == (1, 700, 5)


def test_reg_write_then_action(client: Client, bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    sdk, port = client.sdk, client.port
    for dxl_id, goal in ((1, 1000), (2, 3000)):
        client.write(dxl_id, TORQUE, 1, 1)
        assert sdk.regWriteTxRx(port, dxl_id, GOAL, 4, le32(goal)) == (COMM_SUCCESS, 0)
        assert client.read(dxl_id, 69, 1) == 1  # Registered Instruction
    assert sdk.regWriteTxOnly(port, 3, LED, 1, [1]) == COMM_SUCCESS
    client.await_bytes(11)
    clock.advance(5.0)
    assert [client.read(i, PRESENT, 4) for i in (1, 2)] == [2048, 2048]
    assert sdk.action(port, 0xFE) == COMM_SUCCESS  # broadcast: every servo runs its registered write
    client.sync()
    clock.advance(5.0)
    assert [client.read(i, PRESENT, 4) for i in (1, 2, 3)] == [1000, 3000, 2048]
    assert [client.read(i, 69, 1) for i in (1, 2, 3)] == [0, 0, 0]
    assert client.read(3, LED, 1) == 1
    # Unicast ACTION with nothing registered: Instruction Error, in a reply the SDK does not read.
    assert sdk.action(port, 4) == COMM_SUCCESS
    reply = build_status(4, 0x02)
    assert client.await_bytes(len(reply)) == reply


def test_reboot_and_factory_reset(client: Client, bus: VirtualDynamixelBus) -> None:
    sdk, port = client.sdk, client.port
    client.write(1, 9, 1, 0)  # Return Delay Time (EEPROM)
    client.write(1, TORQUE, 1, 1)
    assert sdk.reboot(port, 1) == (COMM_SUCCESS, 0)
    assert (client.read(1, TORQUE, 1), client.read(1, 9, 1)) == (0, 0)
    assert sdk.factoryReset(port, 1, 0x02) == (COMM_SUCCESS, 0)
    assert client.read(1, 9, 1) == 250
    # 0x01 keeps the ID but resets the baud rate to 57600: at 1M the servo drops off the bus.
    assert sdk.factoryReset(port, 2, 0x01) == (COMM_SUCCESS, 0)
    ping = sdk.ping(port, 2)
    assert ping[1] == (COMM_SUCCESS if port.getBaudRate() == 57_600 else COMM_RX_TIMEOUT)
    assert bus.servos[1].baudrate == 57_600
    # Broadcast reset-all is refused (firmware 42+); a unicast one sets the ID back to 1.
    client.write(4, 7, 1, 20)
    assert sdk.factoryReset(port, 0xFE, 0xFF)[0] == COMM_SUCCESS
    assert sdk.ping(port, 20)[1] == COMM_SUCCESS
    assert sdk.factoryReset(port, 20, 0xFF) == (COMM_SUCCESS, 0)
    assert bus.servos[3].id == 1 and bus.servos[3].baudrate == 57_600


def test_clear_multi_turn(client: Client, clock: ManualClock) -> None:
    sdk, port = client.sdk, client.port
    client.write(1, 11, 1, 4)  # extended position mode
    client.write(1, TORQUE, 1, 1)
    client.write(1, GOAL, 4, 4096 * 2 + 300)
    clock.advance(0.05)
    assert sdk.clearMultiTurn(port, 1) == (COMM_SUCCESS, 0x01)  # Result Fail while moving
    clock.advance(30.0)
    assert sdk.clearMultiTurn(port, 1) == (COMM_SUCCESS, 0)
    assert client.read(1, PRESENT, 4) == 300


def test_sync_write_and_sync_read(client: Client, clock: ManualClock) -> None:
    sdk, port = client.sdk, client.port
    torque = GroupSyncWrite(port, sdk, TORQUE, 1)
    goals = GroupSyncWrite(port, sdk, GOAL, 4)
    for dxl_id in IDS:
        assert torque.addParam(dxl_id, [1])
        assert goals.addParam(dxl_id, le32(1000 * dxl_id))
    assert torque.txPacket() == COMM_SUCCESS
    assert goals.txPacket() == COMM_SUCCESS
    client.sync()
    clock.advance(10.0)
    reader = GroupSyncRead(port, sdk, 128, 8)  # Present Velocity and Present Position
    for dxl_id in IDS:
        assert reader.addParam(dxl_id)
    assert reader.txRxPacket() == COMM_SUCCESS
    assert [reader.getData(i, PRESENT, 4) for i in IDS] == [1000, 2000, 3000, 4000]
    assert [reader.getData(i, 128, 4) for i in IDS] == [0, 0, 0, 0]
    assert reader.fastSyncRead() == COMM_SUCCESS
    assert [reader.getData(i, PRESENT, 4) for i in IDS] == [1000, 2000, 3000, 4000]


def test_bulk_write_and_bulk_read(client: Client, bus: VirtualDynamixelBus) -> None:
    sdk, port = client.sdk, client.port
    writer = GroupBulkWrite(port, sdk)
    assert writer.addParam(1, LED, 1, [1])
    assert writer.addParam(2, 84, 2, [0x84, 0x03])  # Position P Gain 900
    assert writer.addParam(3, 9, 1, [10])  # Return Delay Time
    assert writer.txPacket() == COMM_SUCCESS
    client.sync()
    bus.servo(4).poke("present_input_voltage", 119)
    reader = GroupBulkRead(port, sdk)
    for dxl_id, address, size in ((1, LED, 1), (2, 84, 2), (3, 9, 1), (4, 144, 2)):
        assert reader.addParam(dxl_id, address, size)
    assert reader.txRxPacket() == COMM_SUCCESS
    expected = [1, 900, 10, 119]
    got = [reader.getData(i, a, s) for i, a, s in ((1, LED, 1), (2, 84, 2), (3, 9, 1), (4, 144, 2))]
    assert got == expected
    assert reader.fastBulkRead() == COMM_SUCCESS
    got = [reader.getData(i, a, s) for i, a, s in ((1, LED, 1), (2, 84, 2), (3, 9, 1), (4, 144, 2))]
    assert got == expected


def test_errors_as_the_sdk_reports_them(client: Client) -> None:
    sdk, port = client.sdk, client.port
    client.write(1, TORQUE, 1, 1)
    cases = [
        (sdk.write1ByteTxRx(port, 1, 11, 4), 0x07, "not available to target address"),  # EEPROM, torque on
        (sdk.write4ByteTxRx(port, 1, PRESENT, 5), 0x07, "not available"),  # read-only
        (sdk.write4ByteTxRx(port, 1, GOAL, 5000), 0x06, "exceeds the limit"),  # past Max Position Limit
        (sdk.write1ByteTxRx(port, 2, 11, 2), 0x04, "out of range"),  # no operating mode 2
        (sdk.write2ByteTxRx(port, 1, GOAL, 100), 0x05, "data length"),  # half of a 4-byte item
    ]
    for (result, error), expected, text in cases:
        assert (result, error) == (COMM_SUCCESS, expected)
        assert text in sdk.getRxPacketError(error)
    _, result, error = sdk.readTxRx(port, 1, 140, 10)  # runs past the table end (146)
    assert (result, error) == (COMM_SUCCESS, 0x07)
    # An instruction the servo does not know: Instruction Error.
    tx = [0] * 10
    tx[4], tx[5], tx[7] = 1, 3, 0x30
    _, result, error = sdk.txRxPacket(port, tx)
    assert (result, error) == (COMM_SUCCESS, 0x02)
    assert "Undefined instruction" in sdk.getRxPacketError(error)


def test_status_return_level(client: Client, bus: VirtualDynamixelBus) -> None:
    sdk, port = client.sdk, client.port
    client.write(1, 68, 1, 1)  # PING and READ only
    assert sdk.write1ByteTxRx(port, 1, LED, 1)[0] == COMM_RX_TIMEOUT
    assert client.read(1, LED, 1) == 1  # the write still happened
    client.sdk.write1ByteTxOnly(port, 1, 68, 0)  # PING only
    assert sdk.read1ByteTxRx(port, 1, LED)[1] == COMM_RX_TIMEOUT
    assert sdk.ping(port, 1)[1] == COMM_SUCCESS
    assert sdk.reboot(port, 1)[0] == COMM_RX_TIMEOUT  # no status, but it reboots: level back to 2
    assert client.read(1, 68, 1) == 2


def test_broadcast_read_and_write(client: Client, bus: VirtualDynamixelBus) -> None:
    sdk, port = client.sdk, client.port
    assert sdk.write1ByteTxRx(port, 0xFE, LED, 1) == (COMM_SUCCESS, 0)  # the SDK expects no reply
    client.sync()
    assert [s.value("led") for s in bus.servos] == [1, 1, 1, 1]
    assert sdk.read1ByteTxRx(port, 0xFE, LED)[1] == COMM_NOT_AVAILABLE  # the SDK refuses; send it raw
    sent = bus.stats.replies_sent
    port.ser.write(build_packet(0xFE, Instruction.READ, bytes([LED, 0, 1, 0])))
    assert sdk.ping(port, 1) == (1020, COMM_SUCCESS, 0)  # the next reply is the ping's, not a read's
    assert bus.stats.replies_sent == sent + 1


def test_changing_the_id_answers_from_the_old_id(client: Client, bus: VirtualDynamixelBus) -> None:
    client.write(2, 7, 1, 42)
    assert client.sdk.ping(client.port, 42) == (1020, COMM_SUCCESS, 0)
    assert client.sdk.ping(client.port, 2)[1] == COMM_RX_TIMEOUT
    assert bus.servo(42) is bus.servos[1]


def test_motion_seen_through_the_sdk(client: Client, clock: ManualClock) -> None:
    """Goal write, then the clock: a trapezoid whose arrival matches the closed form."""
    v_unit, a_unit = 0.229 * 4096 / 60, 214.577 * 4096 / 3600
    client.write(1, 108, 4, 20)
    client.write(1, 112, 4, 100)
    client.write(1, TORQUE, 1, 1)
    client.write(1, GOAL, 4, 3072)
    v, a = 100 * v_unit, 20 * a_unit
    arrival = 2 * v / a + (1024 - v * v / a) / v
    samples = []
    while True:
        moving = client.read(1, 122, 1)
        status = client.read(1, 123, 1)
        samples.append((clock.now(), client.read(1, PRESENT, 4), signed32(client.read(1, 128, 4)), moving, status))
        if not moving:
            break
        assert clock.now() < 5.0, "never arrived"
        clock.advance(0.01)
    t_end = samples[-1][0]
    assert arrival <= t_end < arrival + 0.01
    positions = [s[1] for s in samples]
    assert positions == sorted(positions) and positions[-1] == 3072
    assert max(s[2] for s in samples) == 100  # cruises at Profile Velocity
    assert {s[4] for s in samples[:-1]} == {0x32}  # trapezoidal profile, ongoing
    assert samples[-1][4] == 0x31  # trapezoidal profile, in position
    for t, pos, _, _, _ in samples:
        if t <= v / a:
            assert abs(pos - (2048 + 0.5 * a * t * t)) <= 1


def test_dropped_and_corrupted_replies(client: Client, bus: VirtualDynamixelBus) -> None:
    sdk, port = client.sdk, client.port
    bus.servo(1).faults.drop_replies = 2
    assert sdk.ping(port, 1)[1] == COMM_RX_TIMEOUT
    assert sdk.read4ByteTxRx(port, 1, PRESENT)[1] == COMM_RX_TIMEOUT
    assert sdk.ping(port, 1)[1] == COMM_SUCCESS
    bus.servo(2).faults.corrupt_replies = 1
    assert sdk.read4ByteTxRx(port, 2, PRESENT)[1] == COMM_RX_CORRUPT
    assert sdk.read4ByteTxRx(port, 2, PRESENT) == (2048, COMM_SUCCESS, 0)
    # A sync read fails on the servo that drops, and only there.
    bus.servo(3).faults.drop_replies = 1
    reader = GroupSyncRead(port, sdk, PRESENT, 4)
    for dxl_id in IDS:
        reader.addParam(dxl_id)
    assert reader.txRxPacket() == COMM_RX_TIMEOUT
    port.clearPort()
    assert reader.txRxPacket() == COMM_SUCCESS
    assert bus.stats.replies_dropped == 3 and bus.stats.replies_corrupted == 1


def test_random_drops_are_reproducible(client: Client, bus: VirtualDynamixelBus) -> None:
    faults = bus.servo(4).faults

    def pattern() -> list[bool]:
        faults.reseed(7)
        faults.drop_probability = 0.3
        out = [client.sdk.ping(client.port, 4)[1] == COMM_SUCCESS for _ in range(12)]
        faults.drop_probability = 0.0
        return out

    first = pattern()
    assert not all(first) and any(first)
    assert pattern() == first


def test_delayed_replies(client: Client, bus: VirtualDynamixelBus) -> None:
    sdk, port = client.sdk, client.port
    bus.servo(1).faults.reply_delay_s = 0.001
    assert sdk.ping(port, 1) == (1020, COMM_SUCCESS, 0)
    bus.servo(1).faults.reply_delay_s = 0.5  # far beyond the SDK's packet timeout
    assert sdk.ping(port, 1)[1] == COMM_RX_TIMEOUT
    bus.servo(1).faults.reply_delay_s = 0.0
    client.await_bytes(14)  # the late reply still arrives; a real client must flush it
    assert sdk.ping(port, 1) == (1020, COMM_SUCCESS, 0)


def test_overload_sets_alert_until_reboot(client: Client, bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    sdk, port = client.sdk, client.port
    client.write(1, TORQUE, 1, 1)
    client.write(1, GOAL, 4, 3000)
    clock.advance(0.2)
    bus.servo(1).inject_hardware_error(HardwareError.OVERLOAD)
    value, result, error = sdk.read1ByteTxRx(port, 1, 70)
    assert (value, result, error) == (0x20, COMM_SUCCESS, ALERT)
    assert "Hardware error" in sdk.getRxPacketError(error)
    assert sdk.read1ByteTxRx(port, 1, TORQUE) == (0, COMM_SUCCESS, ALERT)
    assert sdk.write1ByteTxRx(port, 1, TORQUE, 1) == (COMM_SUCCESS, ALERT | 0x01)  # refused until reboot
    stopped = sdk.read4ByteTxRx(port, 1, PRESENT)[0]
    clock.advance(5.0)
    assert sdk.read4ByteTxRx(port, 1, PRESENT) == (stopped, COMM_SUCCESS, ALERT)
    assert sdk.ping(port, 2) == (1020, COMM_SUCCESS, 0)  # the others are fine
    assert sdk.reboot(port, 1) == (COMM_SUCCESS, ALERT)  # answered before restarting
    assert sdk.read1ByteTxRx(port, 1, 70) == (0, COMM_SUCCESS, 0)
    client.write(1, TORQUE, 1, 1)


def test_stalled_servo_never_arrives(client: Client, bus: VirtualDynamixelBus, clock: ManualClock) -> None:
    bus.servo(2).faults.stall_short_ticks = 30
    client.write(2, TORQUE, 1, 1)
    client.write(2, GOAL, 4, 2548)
    for _ in range(100):
        clock.advance(0.1)
        assert client.read(2, 122, 1) == 1
    assert client.read(2, PRESENT, 4) == 2518
    assert client.read(2, 123, 1) & 0x09 == 0x08  # following error, not in position


def test_crc_error_reply_and_noise(bus: VirtualDynamixelBus, baud: int) -> None:
    with serial.Serial(bus.port, baud, timeout=1.0) as ser:
        bad = bytearray(build_packet(1, Instruction.READ, bytes([PRESENT, 0, 4, 0])))
        bad[-1] ^= 0x01
        ser.write(bytes(bad))
        expected = build_status(1, 0x03)
        assert ser.read(len(expected)) == expected
        noise = bytes.fromhex("00 13 FF FF FD 01 FF FF FD 00 FD 55 FF FF FD 00 01 02 00")
        ser.write(noise + build_packet(2, Instruction.PING))
        expected = build_status(2, 0, bytes([0xFC, 0x03, 46]))
        assert ser.read(len(expected)) == expected


def test_manual_read_and_sync_read_replies_byte_for_byte(bus: VirtualDynamixelBus, baud: int) -> None:
    """The e-Manual's READ and SYNC READ examples: Present Position 166 on ID 1 and 2079 on ID 2."""
    bus.servo(1).place(166)
    bus.servo(2).place(2079)
    with serial.Serial(bus.port, baud, timeout=1.0) as ser:
        ser.write(bytes.fromhex("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15"))
        expected = bytes.fromhex("FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0")
        assert ser.read(len(expected)) == expected
        ser.write(bytes.fromhex("FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA"))
        expected = bytes.fromhex(
            "FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0 FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE"
        )
        assert ser.read(len(expected)) == expected


def test_manual_fast_sync_read_reply_byte_for_byte(baud: int, clock: ManualClock) -> None:
    with open_virtual_bus((3, 4, 7), baud, clock, positions={3: 166, 7: 2079, 4: 1023}) as bus:
        with serial.Serial(bus.port, baud, timeout=1.0) as ser:
            ser.write(bytes.fromhex("FF FF FD 00 FE 0A 00 8A 84 00 04 00 03 07 04 20 F2"))
            expected = bytes.fromhex(
                "FF FF FD 00 FE 19 00 55 00 03 A6 00 00 00 84 08 00 07 1F 08 00 00 16 CA 00 04 FF 03 00 00 D1 9E"
            )
            assert ser.read(len(expected)) == expected
        assert not bus.errors


def test_baud_scan_finds_each_servo_at_its_own_rate(clock: ManualClock) -> None:
    with open_virtual_bus((1, 2, 3), 57_600, clock) as bus:
        bus.servo(2).poke("baud_rate", 3)  # 1 Mbps
        bus.servo(3).poke("baud_rate", 2)  # 115200
        found: dict[int, list[int]] = {}
        client = connect(bus.port, 57_600)
        for rate in (9_600, 57_600, 115_200, 1_000_000, 2_000_000):
            assert client.port.setBaudRate(rate)
            assert bus.line_baud() == rate  # the client's tcsetattr is visible on our side of the pty
            found[rate] = [i for i in (1, 2, 3) if client.sdk.ping(client.port, i)[1] == COMM_SUCCESS]
        client.port.closePort()
        assert found == {9_600: [], 57_600: [1], 115_200: [3], 1_000_000: [2], 2_000_000: []}
        # A servo told to change its rate answers at the old rate, then only at the new one.
        client = connect(bus.port, 57_600)
        client.write(1, 8, 1, 3)
        assert client.sdk.ping(client.port, 1)[1] == COMM_RX_TIMEOUT
        assert client.port.setBaudRate(1_000_000)
        assert client.sdk.ping(client.port, 1)[1] == COMM_SUCCESS
        # The override pins the line speed whatever the client asks for.
        bus.set_line_baud(115_200)
        assert client.sdk.ping(client.port, 3)[1] == COMM_SUCCESS
        bus.set_line_baud(None)
        client.port.closePort()
        assert not bus.errors


def test_unknown_servo_and_bad_construction_are_named() -> None:
    with open_virtual_bus((1, 2)) as bus:
        with pytest.raises(KeyError, match=r"no servo with id 9 .*ids present: \[1, 2\]"):
            bus.servo(9)
        assert bus.port.startswith("/dev/")
    assert not bus.running
    with pytest.raises(ValueError, match="duplicates"):
        VirtualDynamixelBus((1, 1))
    with pytest.raises(ValueError, match="not one an XM430 supports"):
        VirtualDynamixelBus((1,), baudrate=12_345)
    with pytest.raises(ValueError, match=r"ids \[5\]"):
        VirtualDynamixelBus((1,), positions={5: 0})


def test_fast_sync_read_with_a_silent_servo_fails(client: Client, bus: VirtualDynamixelBus) -> None:
    reader = GroupSyncRead(client.port, client.sdk, PRESENT, 4)
    for dxl_id in IDS:
        reader.addParam(dxl_id)
    bus.servo(4).faults.drop_replies = 1  # the last segment, which carries the packet's CRC, never comes
    assert reader.fastSyncRead() in (COMM_RX_TIMEOUT, COMM_RX_CORRUPT)
    client.port.clearPort()
    assert reader.fastSyncRead() == COMM_SUCCESS


def test_return_delay_can_be_switched_on(client: Client, bus: VirtualDynamixelBus) -> None:
    bus.return_delay = True  # 250 x 2 us = 0.5 ms per reply, in real time
    assert client.sdk.ping(client.port, 1) == (1020, COMM_SUCCESS, 0)
    found, result = client.sdk.broadcastPing(client.port)
    assert (sorted(found), result) == ([1, 2, 3, 4], COMM_SUCCESS)


def test_line_speed_set_with_bother_is_detected(clock: ManualClock) -> None:
    """4.5 Mbps has no Bxxx constant: pyserial sets it through termios2, which the bus reads back."""
    with open_virtual_bus((1,), 4_500_000, clock) as bus:
        with serial.Serial(bus.port, 4_500_000, timeout=1.0) as ser:
            assert bus.line_baud() == 4_500_000
            ser.write(build_packet(1, Instruction.PING))
            expected = build_status(1, 0, bytes([0xFC, 0x03, 46]))
            assert ser.read(len(expected)) == expected


def test_serve_forever_blocks_until_stopped(clock: ManualClock) -> None:
    bus = VirtualDynamixelBus((1,), 57_600, clock)
    stop = threading.Event()
    errors: list[BaseException] = []

    def run() -> None:
        try:
            serve_forever(bus, stop, poll_s=0.01)
        except BaseException as exc:  # surfaced below
            errors.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 5.0
        while not bus.running:
            assert time.monotonic() < deadline, "serve_forever did not start the bus"
            time.sleep(0.001)
        client = connect(bus.port, 57_600)
        assert client.sdk.ping(client.port, 1) == (1020, COMM_SUCCESS, 0)
        client.port.closePort()
        assert thread.is_alive()
    finally:
        stop.set()
        thread.join(timeout=5.0)
        bus.close()
    assert not thread.is_alive() and not errors
    # A bus that stops serving is reported, not waited on forever.
    with pytest.raises(RuntimeError, match="stopped serving"):
        serve_forever(bus, threading.Event(), poll_s=0.01)
