"""Who answers what: broadcast, Status Return Level, Secondary ID and malformed packets, without a wire."""

from __future__ import annotations

import pytest

from rig.instrument.clock import ManualClock
from simulator.dynamixel.instructions import handle
from simulator.dynamixel.protocol import CrcMismatch, Instruction, Packet, build_status
from simulator.dynamixel.servo import VirtualServo


@pytest.fixture
def servos() -> list[VirtualServo]:
    clock = ManualClock()
    return [VirtualServo(i, clock=clock) for i in (1, 2, 3)]


def wire(replies: list) -> list[bytes]:
    return [r.data for r in replies]


def test_broadcast_ping_answers_in_id_order(servos: list[VirtualServo]) -> None:
    servos[0].poke("id", 9)
    replies = handle(Packet(0xFE, Instruction.PING, b""), servos)
    assert [r.servo.id for r in replies] == [2, 3, 9]


def test_broadcast_write_runs_silently_and_broadcast_read_does_nothing(servos: list[VirtualServo]) -> None:
    assert handle(Packet(0xFE, Instruction.WRITE, bytes([65, 0, 1])), servos) == []
    assert [s.value("led") for s in servos] == [1, 1, 1]
    assert handle(Packet(0xFE, Instruction.READ, bytes([65, 0, 1, 0])), servos) == []


@pytest.mark.parametrize(
    ("level", "answered"),
    [(0, {Instruction.PING}), (1, {Instruction.PING, Instruction.READ}), (2, {Instruction.PING, Instruction.READ, 3})],
)
def test_status_return_level(servos: list[VirtualServo], level: int, answered: set[int]) -> None:
    servos[1].poke("status_return_level", level)
    packets = {
        Instruction.PING: b"",
        Instruction.READ: bytes([65, 0, 1, 0]),
        Instruction.WRITE: bytes([65, 0, 1]),
    }
    got = {inst for inst, params in packets.items() if handle(Packet(2, inst, params), servos)}
    assert got == answered
    assert servos[1].value("led") == 1  # the write ran whether or not it was answered


def test_secondary_id_executes_without_answering(servos: list[VirtualServo]) -> None:
    for s in servos[1:]:
        s.poke("secondary_id", 100)
    assert handle(Packet(100, Instruction.WRITE, bytes([65, 0, 1])), servos) == []
    assert [s.value("led") for s in servos] == [0, 1, 1]


def test_broadcast_factory_reset_all_is_refused(servos: list[VirtualServo]) -> None:
    servos[2].poke("return_delay_time", 0)
    handle(Packet(0xFE, Instruction.FACTORY_RESET, b"\xff"), servos)
    assert servos[2].value("return_delay_time") == 0
    handle(Packet(0xFE, Instruction.FACTORY_RESET, b"\x02"), servos)
    assert servos[2].value("return_delay_time") == 250


def test_protocol_1_servo_ignores_protocol_2(servos: list[VirtualServo]) -> None:
    assert handle(Packet(1, Instruction.WRITE, bytes([13, 0, 1])), servos)  # answered, then deaf
    # The bus leaves such servos out of the listeners; here we check the flag it uses.
    assert not servos[0].speaks_protocol_2


def test_crc_mismatch_answered_only_when_enabled(servos: list[VirtualServo]) -> None:
    frame = CrcMismatch(2, Instruction.READ)
    assert wire(handle(frame, servos)) == [build_status(2, 0x03)]
    assert handle(frame, servos, crc_error_replies=False) == []
    assert handle(CrcMismatch(0xFE, Instruction.PING), servos) == []


@pytest.mark.parametrize(
    ("inst", "params"),
    [
        (Instruction.SYNC_READ, b"\x84\x00"),  # no length
        (Instruction.BULK_READ, b"\x01\x84\x00\x04"),  # not a multiple of 5
        (Instruction.SYNC_WRITE, b"\x74\x00\x04\x00\x01\x00\x00"),  # a truncated data block
    ],
)
def test_malformed_group_packets_are_ignored(servos: list[VirtualServo], inst: int, params: bytes) -> None:
    assert handle(Packet(0xFE, inst, params), servos) == []


def test_group_instructions_need_the_broadcast_id(servos: list[VirtualServo]) -> None:
    assert handle(Packet(1, Instruction.SYNC_READ, b"\x84\x00\x04\x00\x01"), servos) == []


def test_unicast_errors(servos: list[VirtualServo]) -> None:
    assert wire(handle(Packet(1, 0x30, b""), servos)) == [build_status(1, 0x02)]
    assert wire(handle(Packet(1, Instruction.READ, b"\x84\x00"), servos)) == [build_status(1, 0x05)]
    assert wire(handle(Packet(1, Instruction.FACTORY_RESET, b"\x07"), servos)) == [build_status(1, 0x04)]
