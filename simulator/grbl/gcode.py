"""G-code parsing for the virtual GRBL: one cleaned line -> a validated block, or a GRBL 1.1 error code.

Coordinates are in controller units (GRBL's millimetres; ``G20`` input is converted at 25.4 units per inch) and
feed rates in units per minute. The subset: G0 G1 G4 G17-G19 G20 G21 G40 G49 G53 G54-G59 G61 G80 G90 G91 G94,
M2 M3 M4 M5 M7 M8 M9 M30, words F N P S T and the configured axis letters. Anything else GRBL 1.1 supports (arcs,
probing, G10/G28/G30/G92 offsets, inverse-time feed, M0/M1 pauses) is answered with ``error:20`` here.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace
from enum import IntEnum

from model.errors import GonioError

MM_PER_INCH = 25.4
MAX_LINE_NUMBER = 10_000_000
MAX_TOOL_NUMBER = 255


class Status(IntEnum):
    """GRBL 1.1 ``error:N`` codes (numbering of the GRBL wiki's error table)."""

    EXPECTED_COMMAND_LETTER = 1
    BAD_NUMBER_FORMAT = 2
    INVALID_STATEMENT = 3
    NEGATIVE_VALUE = 4
    SETTING_DISABLED = 5
    SETTING_STEP_PULSE_MIN = 6
    SETTING_READ_FAIL = 7
    IDLE_ERROR = 8
    SYSTEM_GC_LOCK = 9
    SOFT_LIMIT_ERROR = 10
    OVERFLOW = 11
    MAX_STEP_RATE_EXCEEDED = 12
    CHECK_DOOR = 13
    LINE_LENGTH_EXCEEDED = 14
    TRAVEL_EXCEEDED = 15
    INVALID_JOG_COMMAND = 16
    SETTING_DISABLED_LASER = 17
    GCODE_UNSUPPORTED_COMMAND = 20
    GCODE_MODAL_GROUP_VIOLATION = 21
    GCODE_UNDEFINED_FEED_RATE = 22
    GCODE_COMMAND_VALUE_NOT_INTEGER = 23
    GCODE_AXIS_COMMAND_CONFLICT = 24
    GCODE_WORD_REPEATED = 25
    GCODE_NO_AXIS_WORDS = 26
    GCODE_INVALID_LINE_NUMBER = 27
    GCODE_VALUE_WORD_MISSING = 28
    GCODE_UNSUPPORTED_COORD_SYS = 29
    GCODE_G53_INVALID_MOTION_MODE = 30
    GCODE_AXIS_WORDS_EXIST = 31
    GCODE_NO_AXIS_WORDS_IN_PLANE = 32
    GCODE_INVALID_TARGET = 33
    GCODE_ARC_RADIUS_ERROR = 34
    GCODE_NO_OFFSETS_IN_PLANE = 35
    GCODE_UNUSED_WORDS = 36
    GCODE_G43_DYNAMIC_AXIS_ERROR = 37
    GCODE_MAX_VALUE_EXCEEDED = 38


class Alarm(IntEnum):
    """GRBL 1.1 ``ALARM:N`` codes."""

    HARD_LIMIT = 1
    SOFT_LIMIT = 2
    ABORT_CYCLE = 3
    PROBE_FAIL_INITIAL = 4
    PROBE_FAIL_CONTACT = 5
    HOMING_FAIL_RESET = 6
    HOMING_FAIL_DOOR = 7
    HOMING_FAIL_PULLOFF = 8
    HOMING_FAIL_APPROACH = 9


class GcodeError(GonioError):
    """A line GRBL rejects; ``status`` is its error code."""

    def __init__(self, status: Status) -> None:
        super().__init__(f"error:{int(status)}")
        self.status = status


@dataclass(frozen=True)
class Modal:
    """The parser's modal state as ``$G`` reports it (feed in units/min)."""

    motion: int = 0  # 0, 1 or 80
    coord: int = 54
    plane: int = 17
    inches: bool = False
    relative: bool = False
    feed: float = 0.0
    spindle: int = 5
    coolant: int = 9
    tool: int = 0
    spindle_speed: float = 0.0


@dataclass
class Block:
    """What one accepted line asks for; positions in units, feed in units/min, dwell in seconds."""

    modal: Modal
    position: list[float]
    dwell_s: float | None = None
    target: list[float] | None = None
    rapid: bool = False
    feed: float = 0.0
    program_end: bool = False


_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)")
_VALUE_LETTERS = set("FIJKLNPRST")
# G commands (integer part) and their modal group; None = non-modal group 0.
_G_GROUPS: dict[int, str] = {
    0: "motion", 1: "motion", 80: "motion", 4: "nonmodal", 53: "nonmodal", 17: "plane", 18: "plane", 19: "plane",
    20: "units", 21: "units", 90: "distance", 91: "distance", 94: "feedmode", 40: "cutter", 49: "tlo", 61: "path",
    54: "coord", 55: "coord", 56: "coord", 57: "coord", 58: "coord", 59: "coord",
}  # fmt: skip
# Real GRBL commands this simulator does not implement; answered as unsupported (error:20).
_G_NOT_IMPLEMENTED = {2, 3, 10, 28, 30, 38, 43, 92, 93}
_M_GROUPS = {2: "stop", 30: "stop", 3: "spindle", 4: "spindle", 5: "spindle", 7: "coolant", 8: "coolant", 9: "coolant"}


class LineAssembler:
    """GRBL's input filter, fed one byte at a time: drops whitespace, control bytes and comments, upper-cases.

    ``feed`` returns ``(line, overflowed)`` at each end of line (LF or CR) and None otherwise. Lines longer than
    GRBL's 80-byte line buffer are flagged as overflowed (``error:11``) instead of growing without bound.
    """

    def __init__(self) -> None:
        self._chars: list[str] = []
        self._paren = self._semicolon = self._overflow = False

    def clear(self) -> None:
        """Forget a partial line (soft reset)."""
        self._chars.clear()
        self._paren = self._semicolon = self._overflow = False

    def feed(self, c: int) -> tuple[str, bool] | None:
        """Add byte ``c``; the cleaned line and its overflow flag when ``c`` ends it."""
        if c in (0x0A, 0x0D):
            done = ("".join(self._chars), self._overflow)
            self.clear()
            return done
        if self._paren or self._semicolon or self._overflow:
            if c == 0x29 and self._paren:  # ')' ends a comment, the line goes on
                self._paren = False
        elif c <= 0x20 or c == 0x2F:  # whitespace, control bytes, '/' block delete (unsupported)
            pass
        elif c == 0x28:
            self._paren = True
        elif c == 0x3B:
            self._semicolon = True
        elif len(self._chars) >= 79:  # LINE_BUFFER_SIZE 80 including the terminator
            self._overflow = True
        else:
            self._chars.append(chr(c).upper())
        return None


def split_words(line: str) -> list[tuple[str, float]]:
    """Letter/value pairs of a cleaned line; raises ``GcodeError`` (1: no letter, 2: bad number)."""
    words: list[tuple[str, float]] = []
    i = 0
    while i < len(line):
        letter = line[i]
        if not "A" <= letter <= "Z":
            raise GcodeError(Status.EXPECTED_COMMAND_LETTER)
        m = _NUMBER.match(line, i + 1)
        if m is None:
            raise GcodeError(Status.BAD_NUMBER_FORMAT)
        words.append((letter, float(m.group())))
        i = m.end()
    return words


def parse_block(line: str, modal: Modal, position: list[float], axes: str, jog: bool = False) -> Block:
    """Validate a cleaned line against ``modal`` and the parser ``position`` (units); raises ``GcodeError``.

    The checks run in GRBL's order, so a line with several faults gets the error code GRBL gives it.
    """
    groups, values = _sort_words(split_words(line), axes)
    if jog:
        _check_jog(groups, values)
    if values.get("N", 0.0) > MAX_LINE_NUMBER:
        raise GcodeError(Status.GCODE_INVALID_LINE_NUMBER)
    new, scale, feed = _next_modal(modal, groups, values, jog)

    block = Block(modal=new, position=list(position))
    nonmodal = groups.get("Gnonmodal")
    if nonmodal == 4:
        if "P" not in values:
            raise GcodeError(Status.GCODE_VALUE_WORD_MISSING)
        block.dwell_s = values.pop("P")
    axis_words = {k: v for k, v in values.items() if k in axes}
    motion = 1 if jog else new.motion
    _check_motion(groups, values, axis_words, motion, nonmodal, feed)
    if axis_words and motion in (0, 1):
        target = _target(axis_words, position, axes, scale, absolute=nonmodal == 53 or not new.relative)
        block.target = target
        block.rapid = motion == 0
        block.feed = feed
        block.position = list(target)
    if groups.get("Mstop") in (2, 30):
        block.program_end = True
        block.modal = replace(block.modal, motion=1, plane=17, relative=False, coord=54, spindle=5, coolant=9)
    if jog:
        block.modal = modal  # a jog line never changes the parser's modal state
    return block


def _sort_words(words: list[tuple[str, float]], axes: str) -> tuple[dict[str, int], dict[str, float]]:
    """The line's G/M codes by modal group ("G" or "M" + group name) and its value words by letter."""
    groups: dict[str, int] = {}
    values: dict[str, float] = {}
    for letter, value in words:
        if letter in "GM":
            code = int(value)
            fractional = round(100 * (value - code)) != 0
            table = _G_GROUPS if letter == "G" else _M_GROUPS
            if code not in table or (letter == "G" and code in _G_NOT_IMPLEMENTED):
                raise GcodeError(Status.GCODE_UNSUPPORTED_COMMAND)
            if fractional:
                raise GcodeError(Status.GCODE_COMMAND_VALUE_NOT_INTEGER)
            group = letter + table[code]
            if group in groups:
                raise GcodeError(Status.GCODE_MODAL_GROUP_VIOLATION)
            groups[group] = code
            continue
        if letter not in _VALUE_LETTERS and letter not in axes:
            raise GcodeError(Status.GCODE_UNSUPPORTED_COMMAND)
        if letter in values:
            raise GcodeError(Status.GCODE_WORD_REPEATED)
        if letter in "FNPST" and value < 0:
            raise GcodeError(Status.NEGATIVE_VALUE)
        values[letter] = value
    return groups, values


def _check_jog(groups: dict[str, int], values: dict[str, float]) -> None:
    """A ``$J=`` line: only units, distance and G53, and a feed rate."""
    allowed = {"Gunits", "Gdistance", "Gnonmodal"}
    if any(g not in allowed for g in groups) or groups.get("Gnonmodal", 53) != 53:
        raise GcodeError(Status.INVALID_JOG_COMMAND)
    if "F" not in values:
        raise GcodeError(Status.GCODE_UNDEFINED_FEED_RATE)


def _next_modal(
    modal: Modal, groups: dict[str, int], values: dict[str, float], jog: bool
) -> tuple[Modal, float, float]:
    """The modal state after the line, the units' scale to controller units, and the feed (units/min) it runs at."""
    new = modal
    if "Gunits" in groups:
        new = replace(new, inches=groups["Gunits"] == 20)
    if "Gdistance" in groups:
        new = replace(new, relative=groups["Gdistance"] == 91)
    scale = MM_PER_INCH if new.inches else 1.0
    feed = values["F"] * scale if "F" in values else modal.feed
    if not jog:
        new = replace(new, feed=feed)
    if "S" in values:
        new = replace(new, spindle_speed=values["S"])
    if "T" in values:
        if values["T"] > MAX_TOOL_NUMBER:
            raise GcodeError(Status.GCODE_MAX_VALUE_EXCEEDED)
        new = replace(new, tool=int(values["T"]))
    if "Mspindle" in groups:
        new = replace(new, spindle=groups["Mspindle"])
    if "Mcoolant" in groups:
        new = replace(new, coolant=groups["Mcoolant"])
    if "Gplane" in groups:
        new = replace(new, plane=groups["Gplane"])
    if "Gcoord" in groups:
        new = replace(new, coord=groups["Gcoord"])
    if "Gmotion" in groups:
        new = replace(new, motion=groups["Gmotion"])
    return new, scale, feed


def _check_motion(
    groups: dict[str, int], values: dict[str, float], axis_words: dict[str, float], motion: int,
    nonmodal: int | None, feed: float,
) -> None:
    """Raise for a motion the line cannot make: G53 outside G0/G1, axis words under G80, G1 without a feed,
    or words nothing uses."""
    if nonmodal == 53 and motion not in (0, 1):
        raise GcodeError(Status.GCODE_G53_INVALID_MOTION_MODE)
    explicit_motion = "Gmotion" in groups
    if axis_words or explicit_motion:
        if motion == 80:
            if axis_words:
                raise GcodeError(Status.GCODE_AXIS_WORDS_EXIST)
        elif motion == 1 and feed <= 0.0:
            raise GcodeError(Status.GCODE_UNDEFINED_FEED_RATE)
    leftover = set(values) - set(axis_words) - {"F", "N", "S", "T"}
    if leftover:
        raise GcodeError(Status.GCODE_UNUSED_WORDS)


def _target(
    axis_words: dict[str, float], position: list[float], axes: str, scale: float, *, absolute: bool
) -> list[float]:
    """Where the axis words move to (units): absolute, or relative to ``position``; raises if not finite."""
    target = list(position)
    for letter, value in axis_words.items():
        i = axes.index(letter)
        v = value * scale
        if absolute:
            target[i] = v  # work offsets are all zero here, so work = machine coordinates
        else:
            target[i] = position[i] + v
    if not all(math.isfinite(v) for v in target):
        raise GcodeError(Status.GCODE_INVALID_TARGET)
    return target


def format_modal(modal: Modal) -> str:
    """The ``$G`` report line, e.g. ``[GC:G0 G54 G17 G21 G90 G94 M5 M9 T0 F0 S0]``."""
    feed = modal.feed / MM_PER_INCH if modal.inches else modal.feed
    feed_text = f"{feed:.1f}" if modal.inches else f"{feed:.0f}"
    return (
        f"[GC:G{modal.motion} G{modal.coord} G{modal.plane} G{20 if modal.inches else 21} "
        f"G{91 if modal.relative else 90} G94 M{modal.spindle} M{modal.coolant} T{modal.tool} "
        f"F{feed_text} S{modal.spindle_speed:.0f}]"
    )
