"""What the servos on a bus do with one instruction packet, and which status packets they send back.

Rules from the e-Manual (Protocol 2.0 and the X-series control table):

- PING always gets a reply, whatever the Status Return Level; to the broadcast ID every servo answers,
  in ID order.
- The broadcast ID gets status packets only for PING, SYNC READ and BULK READ (and their Fast variants);
  READ to the broadcast ID is not executed at all, the other instructions run silently.
- Status Return Level (68): 0 replies to PING only, 1 to PING and reads, 2 to everything.
- A servo whose Secondary ID (12) matches executes the instruction but never replies.
- FACTORY_RESET to the broadcast ID with option 0xFF (reset all) is ignored (firmware 42 and later).
- SYNC/BULK READ replies come in the order of the IDs in the instruction. The Fast variants build one
  status packet together: each servo appends ``ERR ID DATA CRC``, the CRC running over the packet so far.
- A frame with a bad CRC is answered with CRC Error (3) by the servo it names: the e-Manual's error table
  defines that error for exactly this case. ``crc_error_replies=False`` makes servos ignore such frames.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from simulator.dynamixel.protocol import (
    BROADCAST_ID,
    CrcMismatch,
    ErrorNumber,
    Instruction,
    Packet,
    build_status,
    fast_status_header,
)
from simulator.dynamixel.servo import VirtualServo

_READS = frozenset(
    {Instruction.READ, Instruction.SYNC_READ, Instruction.BULK_READ, Instruction.FAST_SYNC_READ,
     Instruction.FAST_BULK_READ}
)  # fmt: skip


@dataclass(frozen=True)
class Reply:
    """Bytes one servo puts on the wire in answer to one packet.

    For a Fast Sync/Bulk Read segment (``fast_segment``) the two CRC bytes are not included: they are
    computed at transmit time over everything the group has put on the wire so far.
    """

    servo: VirtualServo
    data: bytes
    fast_segment: bool = False


def replies_allowed(servo: VirtualServo, instruction: int) -> bool:
    """Whether ``servo``'s Status Return Level lets it answer ``instruction``."""
    level = servo.status_return_level
    if instruction == Instruction.PING:
        return True
    if instruction in _READS:
        return level >= 1
    return level >= 2


def handle(
    frame: Packet | CrcMismatch, servos: Sequence[VirtualServo], *, crc_error_replies: bool = True
) -> list[Reply]:
    """Execute ``frame`` on the servos that can hear it; return their status packets in wire order."""
    if isinstance(frame, CrcMismatch):
        if not crc_error_replies or frame.packet_id == BROADCAST_ID:
            return []
        return [
            Reply(s, build_status(s.id, s.status_error(ErrorNumber.CRC)))
            for s in servos
            if s.id == frame.packet_id and replies_allowed(s, frame.instruction)
        ]
    inst, params, pid = frame.instruction, frame.params, frame.packet_id
    if inst in (Instruction.SYNC_READ, Instruction.FAST_SYNC_READ, Instruction.BULK_READ,
                Instruction.FAST_BULK_READ, Instruction.SYNC_WRITE, Instruction.BULK_WRITE):  # fmt: skip
        return _group(inst, params, servos) if pid == BROADCAST_ID else []
    if pid == BROADCAST_ID:
        if inst == Instruction.PING:
            return [_ping(s) for s in sorted(servos, key=lambda s: s.id)]
        for s in servos:
            _execute(s, inst, params, broadcast=True)
        return []
    replies = []
    for s in servos:
        if s.id == pid:
            allowed = replies_allowed(s, inst)  # decided on reception: a write to level 68 still gets its reply
            error, data = _execute(s, inst, params, broadcast=False)
            if inst == Instruction.PING:
                replies.append(_ping(s))
            elif error is not None and allowed:
                replies.append(Reply(s, build_status(pid, error, data)))
        elif s.secondary_id == pid:
            _execute(s, inst, params, broadcast=True)
    return replies


def _ping(servo: VirtualServo) -> Reply:
    model = servo.value("model_number")
    params = bytes([model & 0xFF, model >> 8, servo.value("firmware_version")])
    return Reply(servo, build_status(servo.id, servo.status_error(ErrorNumber.NONE), params))


def _execute(servo: VirtualServo, inst: int, params: bytes, *, broadcast: bool) -> tuple[int | None, bytes]:
    """Run one unicast-style instruction on one servo: (status error byte, or None for "no reply"; data)."""
    # REBOOT and FACTORY_RESET answer before the servo restarts, so their status still carries the Alert.
    before = servo.status_error(ErrorNumber.NONE)
    error, data = _run(servo, inst, params, broadcast=broadcast)
    if error is None:
        return None, data
    if inst in (Instruction.REBOOT, Instruction.FACTORY_RESET):
        return before | error, data
    return servo.status_error(error), data


def _run(servo: VirtualServo, inst: int, params: bytes, *, broadcast: bool) -> tuple[int | None, bytes]:
    if inst == Instruction.PING:
        return ErrorNumber.NONE, b""
    if inst == Instruction.READ:
        if broadcast:
            return None, b""
        if len(params) != 4:
            return ErrorNumber.DATA_LENGTH, b""
        return servo.read(_u16(params, 0), _u16(params, 2))
    if inst in (Instruction.WRITE, Instruction.REG_WRITE):
        if len(params) < 3:
            return ErrorNumber.DATA_LENGTH, b""
        op = servo.write if inst == Instruction.WRITE else servo.reg_write
        return op(_u16(params, 0), params[2:]), b""
    if inst == Instruction.ACTION:
        return servo.action(), b""
    if inst in (Instruction.REBOOT, Instruction.FACTORY_RESET):
        if inst == Instruction.FACTORY_RESET:
            if len(params) != 1:
                return ErrorNumber.DATA_LENGTH, b""
            if params[0] not in (0xFF, 0x01, 0x02):
                return ErrorNumber.DATA_RANGE, b""
            if broadcast and params[0] == 0xFF:
                return None, b""
        if inst == Instruction.REBOOT:
            servo.reboot()
        else:
            servo.factory_reset(params[0])
        return ErrorNumber.NONE, b""
    if inst == Instruction.CLEAR:
        return servo.clear(params), b""
    if inst == Instruction.STATUS:
        return None, b""  # another device's status packet: not for us
    return ErrorNumber.INSTRUCTION, b""


def _group(inst: int, params: bytes, servos: Sequence[VirtualServo]) -> list[Reply]:
    """SYNC/BULK READ/WRITE and the Fast reads; malformed parameter blocks are ignored (no one may answer)."""
    if inst in (Instruction.SYNC_READ, Instruction.FAST_SYNC_READ, Instruction.SYNC_WRITE):
        if len(params) < 4:
            return []
        address, length = _u16(params, 0), _u16(params, 2)
        body = params[4:]
        if inst == Instruction.SYNC_WRITE:
            chunk = 1 + length
            if length == 0 or len(body) % chunk:
                return []
            for i in range(0, len(body), chunk):
                for s in _with_id(servos, body[i]):
                    s.write(address, body[i + 1 : i + chunk])
            return []
        requests = [(dxl_id, address, length) for dxl_id in body]
    elif inst == Instruction.BULK_WRITE:
        i = 0
        while i + 5 <= len(params):
            dxl_id, address, length = params[i], _u16(params, i + 1), _u16(params, i + 3)
            data = params[i + 5 : i + 5 + length]
            if len(data) != length:
                break
            for s in _with_id(servos, dxl_id):
                s.write(address, data)
            i += 5 + length
        return []
    else:
        if len(params) % 5:
            return []
        requests = [(params[i], _u16(params, i + 1), _u16(params, i + 3)) for i in range(0, len(params), 5)]
    fast = inst in (Instruction.FAST_SYNC_READ, Instruction.FAST_BULK_READ)
    return _fast_read(requests, servos) if fast else _read_each(requests, servos)


def _read_each(requests: list[tuple[int, int, int]], servos: Sequence[VirtualServo]) -> list[Reply]:
    replies = []
    for dxl_id, address, length in requests:
        for s in _with_id(servos, dxl_id):
            if replies_allowed(s, Instruction.SYNC_READ):
                error, data = s.read(address, length)
                replies.append(Reply(s, build_status(s.id, s.status_error(error), data)))
    return replies


def _fast_read(requests: list[tuple[int, int, int]], servos: Sequence[VirtualServo]) -> list[Reply]:
    # The first servo writes the header and LEN for the whole group, counted from the request.
    total = sum(length + 4 for _, _, length in requests)
    replies: list[Reply] = []
    for dxl_id, address, length in requests:
        for s in _with_id(servos, dxl_id):
            if not replies_allowed(s, Instruction.FAST_SYNC_READ):
                continue
            error, data = s.read(address, length)
            segment = bytes([s.status_error(error), s.id]) + data.ljust(length, b"\x00")
            prefix = fast_status_header(total) if not replies else b""
            replies.append(Reply(s, prefix + segment, fast_segment=True))
    return replies


def _with_id(servos: Sequence[VirtualServo], dxl_id: int) -> list[VirtualServo]:
    return [s for s in servos if s.id == dxl_id]


def _u16(data: bytes, offset: int) -> int:
    return data[offset] | (data[offset + 1] << 8)
