"""The virtual bus's faults and edge cases through the unmodified ``dynamixel_sdk``: dropped, corrupted and
delayed replies, overload and stalls, replies byte for byte, baud scans, bad construction, the server.
"""

from __future__ import annotations

import threading
import time

import pytest
import serial
from dynamixel_sdk import (
    COMM_RX_CORRUPT,
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupSyncRead,
)

from rig.instrument.clock import ManualClock
from simulator.dynamixel import HardwareError, VirtualDynamixelBus, open_virtual_bus, serve_forever
from simulator.dynamixel.protocol import Instruction, build_packet, build_status
from tests.simulator.dynamixel.sdk_client import ALERT, GOAL, IDS, PRESENT, TORQUE, Client, connect


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
