"""The virtual bus driven by the unmodified ``dynamixel_sdk`` over a pseudo-terminal, as a real client would.

Every SDK instruction runs at 57600 and at 1000000 baud. Motion is driven by a ``ManualClock`` shared
with the test, so nothing waits for a servo; the only real waits are the SDK's own packet timeouts (tens
of ms) when a reply is meant to be missing, and bounded polls for bytes already on their way.
"""

from __future__ import annotations

from dynamixel_sdk import (
    COMM_NOT_AVAILABLE,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupBulkRead,
    GroupBulkWrite,
    GroupSyncRead,
    GroupSyncWrite,
)

from rig.instrument.clock import ManualClock
from simulator.dynamixel import VirtualDynamixelBus
from simulator.dynamixel.protocol import Instruction, build_packet, build_status
from tests.simulator.dynamixel.sdk_client import GOAL, IDS, LED, PRESENT, TORQUE, Client, le32, signed32


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
