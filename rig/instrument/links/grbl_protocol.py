"""GRBL 1.1 wire protocol for the link: error and alarm meanings, the exceptions they map to, report parsing.

Codes and meanings follow the GRBL 1.1 wiki (error_codes / alarm_codes tables). Every ``error:N`` becomes a
``GrblCommandError`` carrying the code, its meaning and the line GRBL rejected; every ``ALARM:N`` a ``GrblAlarm``
subclass naming what happened and whether the machine position can still be trusted.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

from rig.instrument.links.base import LinkError

ERROR_MEANINGS: dict[int, str] = {
    1: "expected command letter: a G-code word has no letter",
    2: "bad number format: a word's value is missing or malformed",
    3: "invalid statement: the '$' system command is not recognised or not supported",
    4: "value < 0: a negative value where a positive one is expected",
    5: "setting disabled: homing is not enabled ($22=0)",
    6: "value < 3 usec: the step pulse must be at least 3 microseconds",
    7: "EEPROM read fail: settings restored to defaults",
    8: "not idle: this '$' command needs the controller Idle (or in Alarm)",
    9: "G-code lock: G-code is refused in Alarm or Jog state (home with $H or unlock with $X)",
    10: "homing not enabled: soft limits need homing ($22=1) first",
    11: "line overflow: more than 80 characters in one line",
    12: "step rate > 30 kHz: this steps-per-unit and max-rate combination is too fast",
    13: "check door: the safety door is open",
    14: "line length exceeded: build info or startup line too long for EEPROM",
    15: "travel exceeded: jog target beyond the machine travel; jog ignored",
    16: "invalid jog command: no '=' or a forbidden G-code in a $J= line",
    17: "setting disabled: laser mode needs PWM spindle output",
    20: "unsupported command: unsupported or invalid G-code in the block",
    21: "modal group violation: two commands of one modal group in the block",
    22: "undefined feed rate: no F value set for a feed move",
    23: "command value not integer: this G-code needs an integer value",
    24: "axis command conflict: two commands that both need axis words",
    25: "word repeated: a G-code word appears twice in the block",
    26: "no axis words: the command needs axis words and has none",
    27: "invalid line number: N outside 1..9,999,999",
    28: "value word missing: the command needs a P or L value",
    29: "unsupported coordinate system: G59.x is not supported",
    30: "G53 invalid motion mode: G53 works only with G0 and G1",
    31: "axis words exist: axis words with no command that uses them (G80 active)",
    32: "no axis words in plane: G2/G3 needs an in-plane axis word",
    33: "invalid target: the motion target is invalid",
    34: "arc radius error: the G2/G3 radius is impossible",
    35: "no offsets in plane: G2/G3 needs an in-plane offset word",
    36: "unused words: value words that no command in the block uses",
    37: "G43.1 axis error: dynamic tool length offset on an unconfigured axis",
    38: "max value exceeded: tool number larger than supported",
}

ALARM_MEANINGS: dict[int, str] = {
    1: "hard limit triggered; position likely lost after the sudden stop, re-homing highly recommended",
    2: "soft limit: a motion target exceeds the machine travel; position kept, the alarm may be unlocked",
    3: "reset while in motion; position likely lost, re-homing highly recommended",
    4: "probe fail: the probe is not in the expected initial state",
    5: "probe fail: the probe did not contact the workpiece within the programmed travel",
    6: "homing fail: the homing cycle was reset",
    7: "homing fail: the safety door was opened during homing",
    8: "homing fail: pull-off travel failed to clear the limit switch (increase $27 or check wiring)",
    9: "homing fail: limit switch not found within the search distance (check $130.., pull-off, wiring)",
    10: "homing fail: second switch of a dual-motor axis not found",
}

# After these alarms GRBL resets itself and prints its banner; after 1 and 2 it waits for a reset (critical).
SELF_RESETTING_ALARMS = frozenset({3, 6, 7, 8, 9, 10})
CRITICAL_ALARMS = frozenset({1, 2})
POSITION_LOST_ALARMS = frozenset({1, 3, 6, 7, 8, 9, 10})

#: Why a reply goes missing while the controller works on: what a lost reply's message says.
REPLY_LOST = "the serial line is losing replies (electrical noise, a loose cable or connector, a USB hub?)"
#: The states of a GRBL 1.1 status report; anything else is a corrupted report.
STATES = frozenset({"Idle", "Run", "Hold", "Jog", "Alarm", "Door", "Check", "Home", "Sleep"})

BANNER_RE = re.compile(r"^Grbl (\d+)\.(\d+)(\w*) \[.*\]\s*$")


class GrblError(LinkError):
    """Something the GRBL controller reported or failed to do; names the port."""


class GrblConnectError(GrblError):
    """The port cannot be opened, or what answers on it is not GRBL 1.1."""


class GrblTimeoutError(GrblError, TimeoutError):
    """The controller did not answer or finish within the timeout."""


class GrblReplyLost(GrblTimeoutError):
    """GRBL went Idle with ``lines`` done but never answered them: the replies were lost on the serial line."""

    def __init__(self, port: str, lines: list[str]) -> None:
        self.port, self.lines = port, lines
        more = f" (and {len(lines) - 1} more)" if len(lines) > 1 else ""
        super().__init__(f"GRBL on {port}: no reply to {lines[0]!r}{more} although GRBL went Idle with it done: "
                         f"{REPLY_LOST}")  # fmt: skip


class GrblResetError(GrblError):
    """The controller reset without being asked (power, cable, another program): queued lines are lost."""


class GrblCommandError(GrblError):
    """GRBL answered ``error:N`` to a line; ``code``, ``meaning`` and the offending ``line``."""

    def __init__(self, port: str, code: int, line: str) -> None:
        self.port, self.code, self.line = port, code, line
        self.meaning = ERROR_MEANINGS.get(code, "unknown error code")
        super().__init__(f"GRBL on {port} rejected {line!r}: error:{code} ({self.meaning})")


class GrblLockedError(GrblCommandError):
    """``error:9``: G-code refused because the controller is in Alarm (home with ``home()`` or ``unlock()``)."""


class GrblAlarm(GrblError):
    """GRBL raised ``ALARM:N``; ``code``, ``meaning``, the ``line`` in flight, and what recovery it needs."""

    def __init__(self, port: str, code: int, line: str | None) -> None:
        self.port, self.code, self.line = port, code, line
        self.meaning = ALARM_MEANINGS.get(code, "unknown alarm code")
        self.position_lost = code in POSITION_LOST_ALARMS
        self.needs_reset = code in CRITICAL_ALARMS
        where = f" while executing {line!r}" if line else ""
        hint = "call reset(), then home() or unlock()" if self.needs_reset else "call home() or unlock()"
        super().__init__(f"GRBL on {port}: ALARM:{code} ({self.meaning}){where}; {hint}")


class GrblLimitAlarm(GrblAlarm):
    """ALARM:1 (hard limit switch) or ALARM:2 (soft limit: target beyond ``$130..`` travel)."""


class GrblAbortAlarm(GrblAlarm):
    """ALARM:3: a reset during motion; GRBL no longer trusts its position."""


class GrblHomingAlarm(GrblAlarm):
    """ALARM:6..10: the homing cycle failed."""


class GrblProbeAlarm(GrblAlarm):
    """ALARM:4 or 5: a probing cycle failed."""


def command_error(port: str, code: int, line: str) -> GrblCommandError:
    """The exception for ``error:code`` answered to ``line``."""
    cls = GrblLockedError if code == 9 else GrblCommandError
    return cls(port, code, line)


def alarm_error(port: str, code: int, line: str | None) -> GrblAlarm:
    """The exception for ``ALARM:code`` (``line``: what was executing, if known)."""
    if code in (1, 2):
        return GrblLimitAlarm(port, code, line)
    if code == 3:
        return GrblAbortAlarm(port, code, line)
    if code in (4, 5):
        return GrblProbeAlarm(port, code, line)
    if 6 <= code <= 10:
        return GrblHomingAlarm(port, code, line)
    return GrblAlarm(port, code, line)


@dataclass(frozen=True)
class GrblStatus:
    """One ``<...>`` status report: ``state`` (``Idle``, ``Run``, ``Hold``...), its ``substate`` code, positions."""

    state: str
    substate: int | None
    mpos: tuple[float, ...] | None
    wpos: tuple[float, ...] | None
    wco: tuple[float, ...] | None
    feed: float | None
    fields: dict[str, str] = field(default_factory=dict)

    @property
    def moving(self) -> bool:
        """Whether the axes may still be moving (Run, Jog, Home, or a hold/door still decelerating)."""
        if self.state in ("Run", "Jog", "Home"):
            return True
        return (self.state == "Hold" and self.substate == 1) or (self.state == "Door" and self.substate == 2)

    def machine_position(self, wco: tuple[float, ...] | None) -> tuple[float, ...] | None:
        """Machine position in controller units: MPos, or WPos plus the work offset (this report's or ``wco``)."""
        if self.mpos is not None:
            return self.mpos
        offset = self.wco or wco
        if self.wpos is None:
            return None
        if offset is None:
            offset = (0.0,) * len(self.wpos)
        return tuple(w + o for w, o in zip(self.wpos, offset, strict=False))


def _floats(text: str) -> tuple[float, ...]:
    return tuple(float(v) for v in text.split(","))


def parse_status(line: str) -> GrblStatus:
    """Parse a GRBL 1.1 report such as ``<Idle|MPos:0.000,0.000,0.000|FS:0,0>``; raises ``ValueError``."""
    if not (line.startswith("<") and line.endswith(">")):
        raise ValueError(f"not a GRBL status report: {line!r}")
    parts = line[1:-1].split("|")
    state, _, sub = parts[0].partition(":")
    if state not in STATES:  # a corrupted byte must not turn 'Run' into a state that reads as stopped
        raise ValueError(f"unknown state {state!r} in status report {line!r}")
    fields: dict[str, str] = {}
    for part in parts[1:]:
        key, sep, value = part.partition(":")
        if not sep:
            raise ValueError(f"malformed field {part!r} in status report {line!r}")
        fields[key] = value
    try:
        mpos = _floats(fields["MPos"]) if "MPos" in fields else None
        wpos = _floats(fields["WPos"]) if "WPos" in fields else None
        wco = _floats(fields["WCO"]) if "WCO" in fields else None
        rates = fields.get("FS") or fields.get("F")
        feed = float(rates.split(",")[0]) if rates else None
        substate = int(sub) if sub else None
    except ValueError as exc:
        raise ValueError(f"malformed status report {line!r}: {exc}") from None
    if mpos is None and wpos is None:
        raise ValueError(f"status report without MPos or WPos: {line!r}")
    return GrblStatus(state, substate, mpos, wpos, wco, feed, fields)
