"""Dynamixel Protocol 2.0 framing, as the servo side of the wire sees it.

A packet is ``FF FF FD 00 | ID | LEN_L LEN_H | INST | PARAMS | CRC_L CRC_H``. LEN counts INST, PARAMS and
the two CRC bytes after byte stuffing; the CRC-16 (polynomial 0x8005, initial value 0, MSB first, no
reflection) covers everything from the header up to the last parameter, stuffing included. Inside INST and
PARAMS every ``FF FF FD`` is followed by an extra ``FD`` so that no header can appear within a packet.

The parser takes bytes as they arrive, in chunks of any size, and yields whole packets. It resynchronises
on noise one byte at a time, so a real packet that follows garbage (or sits inside a bogus "packet" with a
bad CRC) is still found.
"""

from __future__ import annotations

import enum
import time
from dataclasses import dataclass

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC
STATUS_INSTRUCTION = 0x55
ALERT_BIT = 0x80
MAX_PACKET_LENGTH = 1024
"""Largest LEN the parser accepts; anything longer is taken to be noise (the SDK's buffers are 1 KiB too)."""

_HEADER3 = HEADER[:3]
_STUFFED = b"\xff\xff\xfd\xfd"


class Instruction(enum.IntEnum):
    """Instruction codes of Protocol 2.0 (e-Manual, "Instruction")."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    STATUS = 0x55
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A
    BULK_READ = 0x92
    BULK_WRITE = 0x93
    FAST_BULK_READ = 0x9A


class ErrorNumber(enum.IntEnum):
    """Error numbers carried in the low 7 bits of a status packet's error byte."""

    NONE = 0
    RESULT_FAIL = 1
    INSTRUCTION = 2
    CRC = 3
    DATA_RANGE = 4
    DATA_LENGTH = 5
    DATA_LIMIT = 6
    ACCESS = 7


def _make_crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_CRC_TABLE = _make_crc_table()


def crc16(data: bytes | bytearray, crc: int = 0) -> int:
    """CRC-16 of ``data`` as Protocol 2.0 computes it (poly 0x8005, MSB first), continuing from ``crc``."""
    table = _CRC_TABLE
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ table[((crc >> 8) ^ byte) & 0xFF]
    return crc


def stuff(payload: bytes) -> bytes:
    """Insert the stuffing ``FD`` after every ``FF FF FD`` in INST+PARAMS bytes."""
    # The pattern cannot overlap itself, so a left-to-right replace is exactly the manual's rule.
    return payload.replace(_HEADER3, _STUFFED)


def unstuff(payload: bytes) -> bytes:
    """Remove the stuffing ``FD`` from received INST+PARAMS bytes (inverse of ``stuff``)."""
    return payload.replace(_STUFFED, _HEADER3)


def build_packet(packet_id: int, instruction: int, params: bytes = b"", *, stuffed: bool = True) -> bytes:
    """A complete packet: header, id, length, instruction, (stuffed) parameters and CRC."""
    if not 0 <= packet_id <= 0xFF:
        raise ValueError(f"packet id {packet_id!r} outside 0..255")
    body = bytes([instruction]) + bytes(params)
    if stuffed:
        body = stuff(body)
    length = len(body) + 2
    if length > 0xFFFF:
        raise ValueError(f"packet of {len(body)} instruction+parameter bytes does not fit a 16-bit LEN")
    head = HEADER + bytes([packet_id, length & 0xFF, length >> 8])
    crc = crc16(head + body)
    return head + body + bytes([crc & 0xFF, crc >> 8])


def build_status(packet_id: int, error: int, params: bytes = b"") -> bytes:
    """A status packet (INST 0x55) from ``packet_id`` with error byte ``error`` and ``params``."""
    return build_packet(packet_id, STATUS_INSTRUCTION, bytes([error & 0xFF]) + bytes(params))


def fast_status_header(total_segment_bytes: int) -> bytes:
    """Header, broadcast id, LEN and INST 0x55 of a Fast Sync/Bulk Read reply whose segments total ``n`` bytes.

    Each segment is ``ERR ID DATA CRC_L CRC_H``; the CRC after a segment covers the whole packet so far, so
    the last segment's CRC is the packet's CRC. These replies are not stuffed (e-Manual, Fast Sync Read).
    """
    length = 1 + total_segment_bytes
    return HEADER + bytes([BROADCAST_ID, length & 0xFF, length >> 8, STATUS_INSTRUCTION])


@dataclass(frozen=True)
class Packet:
    """A received instruction packet with stuffing removed."""

    packet_id: int
    instruction: int
    params: bytes


@dataclass(frozen=True)
class CrcMismatch:
    """A frame whose header, id and length looked valid but whose CRC did not match."""

    packet_id: int
    instruction: int


class PacketParser:
    """Incremental parser for instruction packets: ``feed`` bytes, get whole packets back.

    ``stale_after_s`` (real time) drops a partial packet that stops arriving, like the servo's 1.5 ms
    byte-to-byte timeout but looser, because a pseudo-terminal delivers in bursts scheduled by the OS.
    """

    def __init__(self, stale_after_s: float = 0.02) -> None:
        self._buf = bytearray()
        self._stale_after_s = stale_after_s
        self._last_rx = time.monotonic()
        self.noise_bytes = 0
        self.crc_mismatches = 0

    def feed(self, data: bytes) -> list[Packet | CrcMismatch]:
        """Add received bytes; return every complete frame now available, in order."""
        now = time.monotonic()
        if self._buf and now - self._last_rx >= self._stale_after_s:
            # A partial frame that went quiet: treat its first byte as noise and rescan the rest.
            self._drop(1)
        self._last_rx = now
        self._buf.extend(data)
        out: list[Packet | CrcMismatch] = []
        while True:
            frame = self._next_frame()
            if frame is None:
                return out
            out.append(frame)

    def pending(self) -> int:
        """Bytes held back waiting for the rest of a frame."""
        return len(self._buf)

    def _drop(self, n: int) -> None:
        self.noise_bytes += n
        del self._buf[:n]

    def _next_frame(self) -> Packet | CrcMismatch | None:
        buf = self._buf
        while True:
            start = buf.find(_HEADER3)
            if start < 0:
                # Keep a trailing FF or FF FF: it may be the start of a header split across chunks.
                keep = 2 if buf.endswith(b"\xff\xff") else 1 if buf.endswith(b"\xff") else 0
                self._drop(len(buf) - keep)
                return None
            if start:
                self._drop(start)
            if len(buf) < 7:
                return None
            packet_id = buf[4]
            length = buf[5] | (buf[6] << 8)
            if buf[3] != 0x00 or packet_id in (0xFD, 0xFF) or not 3 <= length <= MAX_PACKET_LENGTH:
                self._drop(1)
                continue
            total = 7 + length
            if len(buf) < total:
                return None
            frame = bytes(buf[:total])
            received_crc = frame[-2] | (frame[-1] << 8)
            if crc16(frame[:-2]) != received_crc:
                self.crc_mismatches += 1
                # Only the header is consumed: a real packet may hide inside what looked like this one.
                self._drop(1)
                return CrcMismatch(packet_id, frame[7])
            del buf[:total]
            body = unstuff(frame[7:-2])
            return Packet(packet_id, body[0], body[1:])
