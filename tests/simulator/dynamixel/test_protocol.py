"""Protocol 2.0 framing against the e-Manual's example packets, byte stuffing, and the resynchronising parser.

Every hex string below is copied from the ROBOTIS e-Manual, "DYNAMIXEL Protocol 2.0" (instruction
examples), so these tests check our CRC, LEN and stuffing rules against the primary source. The SDK's
own stuffing and CRC serve as a second, independent implementation.
"""

from __future__ import annotations

import pytest
from dynamixel_sdk import PacketHandler
from hypothesis import given
from hypothesis import strategies as st

from simulator.dynamixel.protocol import (
    CrcMismatch,
    Instruction,
    Packet,
    PacketParser,
    build_packet,
    build_status,
    crc16,
    fast_status_header,
    stuff,
    unstuff,
)


def h(text: str) -> bytes:
    return bytes.fromhex(text)


# (instruction packet, id, instruction, params) from the e-Manual examples.
MANUAL_INSTRUCTIONS = [
    ("FF FF FD 00 01 03 00 01 19 4E", 0x01, Instruction.PING, ""),
    ("FF FF FD 00 FE 03 00 01 31 42", 0xFE, Instruction.PING, ""),
    ("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15", 0x01, Instruction.READ, "84 00 04 00"),
    ("FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89", 0x01, Instruction.WRITE, "74 00 00 02 00 00"),
    ("FF FF FD 00 01 09 00 04 68 00 C8 00 00 00 AE 8E", 0x01, Instruction.REG_WRITE, "68 00 C8 00 00 00"),
    ("FF FF FD 00 01 03 00 05 02 CE", 0x01, Instruction.ACTION, ""),
    ("FF FF FD 00 01 04 00 06 01 A1 E6", 0x01, Instruction.FACTORY_RESET, "01"),
    ("FF FF FD 00 01 03 00 08 2F 4E", 0x01, Instruction.REBOOT, ""),
    ("FF FF FD 00 01 08 00 10 01 44 58 4C 22 B1 DC", 0x01, Instruction.CLEAR, "01 44 58 4C 22"),
    ("FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA", 0xFE, Instruction.SYNC_READ, "84 00 04 00 01 02"),
    (
        "FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87",
        0xFE,
        Instruction.SYNC_WRITE,
        "74 00 04 00 01 96 00 00 00 02 AA 00 00 00",
    ),
    (
        "FF FF FD 00 FE 0D 00 92 01 90 00 02 00 02 92 00 01 00 1A 05",
        0xFE,
        Instruction.BULK_READ,
        "01 90 00 02 00 02 92 00 01 00",
    ),
    (
        "FF FF FD 00 FE 10 00 93 01 20 00 02 00 A0 00 02 1F 00 01 00 50 B7 68",
        0xFE,
        Instruction.BULK_WRITE,
        "01 20 00 02 00 A0 00 02 1F 00 01 00 50",
    ),
    (
        "FF FF FD 00 FE 0A 00 8A 84 00 04 00 03 07 04 20 F2",
        0xFE,
        Instruction.FAST_SYNC_READ,
        "84 00 04 00 03 07 04",
    ),
]

# (status packet, id, error, params) from the e-Manual examples.
MANUAL_STATUS = [
    ("FF FF FD 00 01 07 00 55 00 06 04 26 65 5D", 1, 0, "06 04 26"),
    ("FF FF FD 00 02 07 00 55 00 06 04 26 6F 6D", 2, 0, "06 04 26"),
    ("FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0", 1, 0, "A6 00 00 00"),
    ("FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE", 2, 0, "1F 08 00 00"),
    ("FF FF FD 00 01 04 00 55 00 A1 0C", 1, 0, ""),
    ("FF FF FD 00 01 06 00 55 00 77 00 C3 69", 1, 0, "77 00"),
    ("FF FF FD 00 02 05 00 55 00 24 8B A9", 2, 0, "24"),
]


def test_crc_of_the_two_packets_quoted_in_the_brief() -> None:
    assert build_packet(1, Instruction.PING)[-2:] == h("19 4E")
    assert build_packet(1, Instruction.READ, h("84 00 04 00"))[-2:] == h("1D 15")


@pytest.mark.parametrize(("packet", "dxl_id", "inst", "params"), MANUAL_INSTRUCTIONS)
def test_instruction_packets_match_the_manual(packet: str, dxl_id: int, inst: int, params: str) -> None:
    assert build_packet(dxl_id, inst, h(params)) == h(packet)
    assert PacketParser().feed(h(packet)) == [Packet(dxl_id, inst, h(params))]


@pytest.mark.parametrize(("packet", "dxl_id", "error", "params"), MANUAL_STATUS)
def test_status_packets_match_the_manual(packet: str, dxl_id: int, error: int, params: str) -> None:
    assert build_status(dxl_id, error, h(params)) == h(packet)


@pytest.mark.parametrize(
    ("manual", "segments"),
    [
        ("FF FF FD 00 FE 19 00 55 00 03 A6 00 00 00 84 08 00 07 1F 08 00 00 16 CA 00 04 FF 03 00 00 D1 9E",
         ((3, "A6 00 00 00"), (7, "1F 08 00 00"), (4, "FF 03 00 00"))),
        ("FF FF FD 00 FE 14 00 55 00 03 A6 00 00 00 67 A4 00 07 A5 01 24 74 00 04 1F D9 C1",
         ((3, "A6 00 00 00"), (7, "A5 01"), (4, "1F"))),
    ],
    ids=["fast_sync_read", "fast_bulk_read"],
)  # fmt: skip
def test_fast_read_replies_match_the_manual(manual: str, segments: tuple[tuple[int, str], ...]) -> None:
    """The manual's Fast Sync and Bulk Read replies (IDs 3, 7, 4): each segment's CRC covers everything before it."""
    packet = fast_status_header(sum(1 + 1 + len(h(data)) + 2 for _, data in segments))  # ERR ID DATA CRC_L CRC_H
    for dxl_id, data in segments:
        packet += bytes([0, dxl_id]) + h(data)
        crc = crc16(packet)
        packet += bytes([crc & 0xFF, crc >> 8])
    assert packet == h(manual)


def test_the_manuals_fast_bulk_read_instruction_example_has_a_wrong_crc() -> None:
    """The e-Manual prints CRC ``20 F2`` (copied from its Fast Sync Read example); the true CRC differs."""
    params = h("03 84 00 04 00 07 7C 00 02 00 04 92 00 01 00")
    packet = build_packet(0xFE, Instruction.FAST_BULK_READ, params)
    assert packet[:-2] == h("FF FF FD 00 FE 12 00 9A") + params
    assert packet[-2:] != h("20 F2")
    assert PacketParser().feed(packet[:-2] + h("20 F2")) == [CrcMismatch(0xFE, Instruction.FAST_BULK_READ)]


def test_stuffing_round_trip_and_length() -> None:
    params = h("74 00 FF FF FD 00")  # a Goal Position whose bytes contain the header pattern
    packet = build_packet(1, Instruction.WRITE, params)
    assert packet[5] == 3 + len(params) + 1  # LEN counts the stuffing byte
    assert h("FF FF FD FD") in packet[7:]
    assert PacketParser().feed(packet) == [Packet(1, Instruction.WRITE, params)]


def test_stuffing_agrees_with_the_sdk() -> None:
    """dynamixel_sdk stuffs and checksums its instruction packets independently of our code."""
    sdk = PacketHandler(2.0)
    params = list(h("00 01 FF FF FD FF FF FD FD 02"))
    tx = [0] * 7 + [Instruction.WRITE, *params, 0, 0]
    tx[4], tx[5], tx[6] = 1, (len(params) + 3) & 0xFF, 0
    tx = sdk.addStuffing(tx)
    tx[0:4] = [0xFF, 0xFF, 0xFD, 0x00]
    total = tx[5] + 7
    crc = sdk.updateCRC(0, tx, total - 2)
    tx[total - 2 : total] = [crc & 0xFF, crc >> 8]
    assert build_packet(1, Instruction.WRITE, bytes(params)) == bytes(tx[:total])


@given(st.binary(max_size=64))
def test_unstuff_inverts_stuff(payload: bytes) -> None:
    stuffed = stuff(payload)
    assert unstuff(stuffed) == payload
    assert h("FF FF FD") not in stuffed.replace(h("FF FF FD FD"), b"")


@given(st.binary(max_size=40), st.integers(0, 252), st.binary(max_size=20), st.integers(1, 7))
def test_parser_finds_packets_after_noise_in_any_chunking(noise: bytes, dxl_id: int, params: bytes, step: int) -> None:
    packet = build_packet(dxl_id, Instruction.WRITE, params)
    stream = noise + packet
    parser = PacketParser(stale_after_s=1e9)
    frames = []
    for i in range(0, len(stream), step):
        frames += parser.feed(stream[i : i + step])
    packets = [f for f in frames if isinstance(f, Packet)]
    # Only a bogus header in the noise whose LEN reaches past the end of the stream may still hold the
    # packet back (until the line goes quiet); a complete bogus frame is rescanned and the packet found.
    if packets:
        assert packets[-1] == Packet(dxl_id, Instruction.WRITE, params)
    else:
        assert parser.pending() > len(packet)


def test_parser_skips_bad_reserved_bad_id_and_bad_length() -> None:
    noise = h("00 13 FF FF FD 01 FF FF FD 00 FD 55 FF FF FD 00 01 02 00 FF")
    ping = build_packet(2, Instruction.PING)
    parser = PacketParser()
    assert parser.feed(noise + ping) == [Packet(2, Instruction.PING, b"")]
    assert parser.noise_bytes == len(noise)


def test_parser_reports_crc_mismatch_and_recovers_a_packet_hidden_inside() -> None:
    ping = build_packet(3, Instruction.PING)
    bogus = h("FF FF FD 00 01 0E 00 02") + ping + h("00 00 00")  # LEN 14 swallows the ping
    frames = PacketParser().feed(bogus)
    assert frames == [CrcMismatch(1, Instruction.READ), Packet(3, Instruction.PING, b"")]


def test_parser_drops_a_partial_frame_that_went_quiet() -> None:
    parser = PacketParser(stale_after_s=0.0)  # every pause counts as "quiet": no real waiting needed
    assert parser.feed(h("FF FF FD 00 01 FF 00 02")) == []  # a header promising 255 more bytes
    assert parser.feed(build_packet(1, Instruction.PING)) == [Packet(1, Instruction.PING, b"")]


def test_header_split_across_chunks() -> None:
    packet = build_packet(7, Instruction.READ, h("84 00 04 00"))
    parser = PacketParser()
    assert parser.feed(h("00 FF")) == []
    assert parser.feed(h("FF")) == []
    assert parser.feed(packet[2:]) == [Packet(7, Instruction.READ, h("84 00 04 00"))]
    assert parser.pending() == 0
