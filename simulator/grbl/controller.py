"""The virtual GRBL 1.1 controller: serial bytes in, GRBL's replies out, motion integrated on an injectable clock.

This is the device side only; ``simulator/grbl/server.py`` serves it on a pseudo-terminal. Positions are in controller
units (GRBL's millimetres; the gonio uses motor degrees), times in seconds of the clock, feeds in units/min.

Behaviour modelled on GRBL 1.1h:

- a 128-byte serial receive buffer (all 128 usable: GRBL's ring has a spare slot): bytes arriving while it is full
  are lost, so a client that does not count characters garbles lines as soon as the main loop is blocked (planner
  full, dwell, homing, feed hold);
- real-time bytes ``?`` ``!`` ``~`` 0x18 (and 0x84 safety door, 0x85 jog cancel) act at once and never enter the
  buffer; other bytes >= 0x80 (overrides) are ignored;
- a 15-block planner; the ``ok`` of a motion line comes when its block enters the planner;
- a feed hold suspends the main loop: lines wait in the receive buffer until ``~`` or a reset;
- hard limit (ALARM:1) and soft limit (ALARM:2) are critical: nothing but ``?`` and reset is served until 0x18;
  the line that was executing then gets its ``ok`` and the banner follows, as in GRBL's abort path;
- a reset while moving (Run, Jog, Hold:1) raises ALARM:3 and comes back in Alarm; in Hold:0 it keeps position;
- soft limits (``$20=1``, which needs ``$22=1``) keep targets in GRBL's default machine space ``[-$130, 0]`` per axis
  (the homing switch at 0, ``$23`` direction bits included): a G-code target outside raises ALARM:2, a jog error:15.

Faults on cue (the "fault injection" methods): a hard limit, a failed homing, a stall, status reports lost or late,
``ok`` replies lost, and a noisy line that loses or garbles replies at random (seeded; ``simulator/grbl/noise.py``).

Simplifications: every move accelerates from and stops at rest; homing moves all axes at once (GRBL does Z first,
then X and Y), the report runs straight to the switch, and a failed homing reports no motion; work offsets are
always zero (``$#`` reports zeros, so WPos = MPos); startup lines (``$Nx=``) and sleep (``$SLP``) answer
``error:3``; status reports are answered even while halted by ALARM:1/2 (GRBL 1.1h's comment says so, its loop
does not).
"""

from __future__ import annotations

from rig.instrument.clock import Clock
from simulator.grbl.core import (
    ALARM,
    BUILD_DATE,
    CHECK,
    CYCLE,
    HOLD,
    HOMING,
    IDLE,
    JOG,
    PLANNER_BLOCKS,
    RX_BUFFER_SIZE,
    VERSION,
    GrblCore,
)
from simulator.grbl.gcode import Alarm, Status, format_modal
from simulator.grbl.noise import LineNoise

HELP = "[HLP:$$ $# $G $I $N $x=val $Nx=line $J=line $SLP $C $X $H ~ ! ? ctrl-x]"


class VirtualGrbl(GrblCore):
    """A GRBL 1.1 controller in software: ``receive`` bytes, ``read_output`` replies; thread-safe.

    ``axes`` are the axis letters in report order (a subset prefix of ``XYZABC``), ``settings`` overrides GRBL's
    defaults by setting number, ``start_position`` is where each axis physically sits at power-up in homed machine
    coordinates (units; the limit switch is at 0), which is what ``$H`` has to travel.
    """

    # ---- serial side ---------------------------------------------------------------------------------------
    def power_on(self) -> None:
        """Hardware reset, as when a client opens the port of an Arduino: position report zeroed, banner sent."""
        with self._lock:
            self._advance(self._clock.now())
            self._motion.kill()
            pos = self._motion.position
            self._offset = [o + p for o, p in zip(self._offset, pos, strict=True)]
            self._motion.set_position([0.0] * len(self.axes))
            self._out.clear()
            self._state = ALARM if self.settings.flag(22) else IDLE
            self._reset_system()

    # ---- inspection ----------------------------------------------------------------------------------------
    @property
    def state(self) -> str:
        """The state field of a status report now, e.g. ``"Idle"``, ``"Run"``, ``"Hold:0"``, ``"Alarm"``."""
        with self._lock:
            self._advance(self._clock.now())
            return self._state_text()

    @property
    def mpos(self) -> dict[str, float]:
        """Machine position per axis letter in units, as the status report gives it (step-quantised)."""
        with self._lock:
            self._advance(self._clock.now())
            return dict(zip(self.axes, self._positions(), strict=True))

    @property
    def clock(self) -> Clock:
        """The clock the controller's motion runs on."""
        return self._clock

    @property
    def physical_position(self) -> dict[str, float]:
        """Where each axis physically stands (units, homed machine coordinates: the switch at 0).

        This is what the machine does, not what it reports: a power-up zeroes the report, never the axes. At rest
        an axis holds a whole step. While steps are issued (a move, a hold's deceleration, homing) it follows the
        planned path itself: an arm's inertia on the rotor low-passes the step train far below the step rate, so
        the load glides between the steps that the report (a count of steps issued) jumps by.
        """
        with self._lock:
            self._advance(self._clock.now())
            stepping = self._stepping()
            steps = [self.settings.steps_per_unit(i) for i in range(len(self.axes))]
            where = zip(self.axes, self._positions(quantise=False), self._offset, steps, strict=True)
            if stepping:
                return {a: p + o for a, p, o, _ in where}
            return {a: round((p + o) * n) / n for a, p, o, n in where}

    @property
    def stepping(self) -> bool:
        """Whether steps are issued now: a move, homing, or a feed hold's or jog cancel's deceleration (``Hold:1``,
        ``Door:2``), which the state's name alone (``Hold``) does not tell from a hold that has come to rest."""
        with self._lock:
            self._advance(self._clock.now())
            return self._stepping()

    def _stepping(self) -> bool:
        return self._homing is not None or self._motion.mode in ("run", "hold")

    @property
    def driven_direction(self) -> dict[str, int]:
        """Per axis letter, the sign of its last motion in machine coordinates (0 before any): where play lags."""
        with self._lock:
            return dict(zip(self.axes, self._driven, strict=True))

    @property
    def planner_blocks(self) -> int:
        """Blocks queued in the planner (including the one executing)."""
        with self._lock:
            return len(self._motion.moves)

    # ---- fault injection -----------------------------------------------------------------------------------
    def trip_hard_limit(self, after_s: float = 0.0) -> None:
        """A limit switch closes ``after_s`` clock seconds from now: ALARM:1 if ``$21=1`` (ignored otherwise)."""
        with self._lock:
            self._advance(self._clock.now())
            self._trip_at = self._t + max(after_s, 0.0)
            self._advance(self._clock.now())

    def fail_next_homing(self, alarm: int = 9) -> None:
        """Make the next ``$H`` fail with ALARM:8 (pull-off) or ALARM:9 (switch not found)."""
        if alarm not in (Alarm.HOMING_FAIL_PULLOFF, Alarm.HOMING_FAIL_APPROACH):
            raise ValueError(f"fail_next_homing(alarm={alarm!r}): expected 8 or 9")
        with self._lock:
            self._homing_fault = alarm

    def stall(self) -> None:
        """Freeze the motion where it is now: the controller stays in Run and never reaches its target."""
        with self._lock:
            self._advance(self._clock.now())
            self._motion.stalled = True

    def drop_status_reports(self, count: int) -> None:
        """Ignore the next ``count`` ``?`` queries (a noisy line or a busy controller)."""
        with self._lock:
            self._drop_reports += max(int(count), 0)

    def delay_status_reports(self, count: int) -> None:
        """Answer the next ``count`` ``?`` queries late, each just before the next query's report (a busy line)."""
        with self._lock:
            self._late_reports += max(int(count), 0)

    def drop_acknowledgements(self, count: int) -> None:
        """Lose the next ``count`` ``ok`` replies on the line (the lines themselves are executed)."""
        with self._lock:
            self._drop_oks += max(int(count), 0)

    def noisy_line(self, drop: float = 0.0, garble: float = 0.0, seed: int = 0) -> LineNoise:
        """From now on each ``ok`` and status report is lost (``drop``) or garbled (``garble``); zeros end it.

        Returns the noise, whose ``dropped`` and ``garbled`` count what it did (see ``simulator.grbl.noise``).
        """
        noise = LineNoise(drop, garble, seed)
        with self._lock:
            self._noise = noise if drop or garble else None
        return noise

    def open_door(self) -> None:
        """The safety door opens (same as the 0x84 real-time byte)."""
        self.receive(b"\x84")

    # ---- '$' commands --------------------------------------------------------------------------------------
    def _system_command(self, line: str) -> None:
        rest = line[1:]
        head = rest[:1]
        if not rest:
            self._emit(HELP)
        elif head == "J":
            if self._state not in (IDLE, JOG):
                self._error(Status.IDLE_ERROR)
            elif rest[1:2] != "=":
                self._error(Status.INVALID_STATEMENT)
            else:
                self._gcode(line, jog=True)
            return
        elif head in ("$", "G", "C", "X"):
            if len(rest) != 1:
                self._error(Status.INVALID_STATEMENT)
                return
            if head == "$":
                if self._state in (CYCLE, HOLD):
                    self._error(Status.IDLE_ERROR)
                    return
                for text in self.settings.report_lines():
                    self._emit(text)
            elif head == "G":
                self._emit(format_modal(self._modal))
            elif head == "X":
                if self._state == ALARM:
                    self._emit("[MSG:Caution: Unlocked]")
                    self._state = IDLE
            elif self._state == CHECK:
                self._emit("[MSG:Disabled]")
                self._emit("ok")
                self._state = IDLE
                self._reset_system()
                return
            elif self._state != IDLE:
                self._error(Status.IDLE_ERROR)
                return
            else:
                self._state = CHECK
                self._emit("[MSG:Enabled]")
        elif self._state not in (IDLE, ALARM):
            self._error(Status.IDLE_ERROR)
            return
        elif rest == "#":
            zeros = ",".join(self._fmt(0.0) for _ in self.axes)
            for name in ("G54", "G55", "G56", "G57", "G58", "G59", "G28", "G30", "G92"):
                self._emit(f"[{name}:{zeros}]")
            self._emit(f"[TLO:{self._fmt(0.0)}]")
            self._emit(f"[PRB:{zeros}:0]")
        elif rest == "H":
            if not self.settings.flag(22):
                self._error(Status.SETTING_DISABLED)
            else:
                self._start_homing()
            return
        elif rest == "I":
            self._emit(f"[VER:{VERSION}.{BUILD_DATE}:]")
            self._emit(f"[OPT:V,{PLANNER_BLOCKS},{RX_BUFFER_SIZE}]")
        elif rest.startswith("I="):
            pass  # storing a build-info string: accepted and forgotten
        elif rest == "N":
            self._emit("$N0=")
            self._emit("$N1=")
        elif rest in ("RST=$", "RST=#", "RST=*"):
            if rest != "RST=#":
                self.settings.values = self.settings.defaults()
            self._emit("[MSG:Restoring defaults]")
            self._emit("ok")
            self._reset_system()
            return
        elif head in ("#", "H", "I", "N", "R", "S"):
            self._error(Status.INVALID_STATEMENT)  # includes $Nx=line and $SLP, not simulated
            return
        else:
            status = self._setting_command(rest)
            if status is not None:
                self._error(status)
                return
        self._emit("ok")

    def _setting_command(self, rest: str) -> Status | None:
        num = _leading_number(rest)
        if num is None:
            return Status.BAD_NUMBER_FORMAT  # GRBL reads a setting number first, so '$Q' fails as a number
        key_text, tail = num
        if not tail.startswith("="):
            return Status.INVALID_STATEMENT
        value = _leading_number(tail[1:])
        if value is None:
            return Status.BAD_NUMBER_FORMAT
        value_text, trailing = value
        key = float(key_text)
        if trailing or key > 255 or key != int(key):
            return Status.INVALID_STATEMENT
        return self.settings.store(int(key), float(value_text))

    # ---- homing --------------------------------------------------------------------------------------------
    def _start_homing(self) -> None:
        s = self.settings
        seek, feed, pulloff = s[25] / 60.0, s[24] / 60.0, s[27]
        start = self._motion.position
        end: list[float] = []
        switches: list[float] = []
        search = 0.0
        travel = max(s.max_travel(i) for i in range(len(self.axes)))
        fault = self._homing_fault
        self._homing_fault = None
        for i, p in enumerate(start):
            inverted = bool(int(s[23]) >> i & 1)
            switch = -s.max_travel(i) if inverted else 0.0
            switches.append(switch)
            physical = p + self._offset[i]
            distance = abs(switch - physical)
            if distance > 1.5 * s.max_travel(i):
                fault = fault or Alarm.HOMING_FAIL_APPROACH
            search = max(search, distance)
            end.append(switch + pulloff if inverted else switch - pulloff)
        if fault == Alarm.HOMING_FAIL_APPROACH:
            duration = 1.5 * travel / seek
        elif fault == Alarm.HOMING_FAIL_PULLOFF:
            duration = search / seek + pulloff / seek
        else:
            duration = search / seek + 2.0 * pulloff / seek + pulloff / feed
        # The report runs toward the switch during the cycle, then GRBL redefines it as the pulled-off position.
        toward = [p + (0.0 if fault else switches[i] - p - self._offset[i]) for i, p in enumerate(start)]
        self._state = HOMING
        self._homing = (self._t, self._t + duration, start, toward, fault)
        self._homing_end = start if fault else end
        self._pending = [("blocked", None)]

    def _finish_homing(self) -> None:
        assert self._homing is not None
        fault = self._homing[4]
        self._homing = None
        self._motion.set_position(self._homing_end)
        self._pending = None
        if fault is not None:
            self._raise_alarm(fault)
            self._emit("ok")  # '$H' returns before the abort, like GRBL's system_execute_line
            self._reset_system()
            return
        self._offset = [0.0] * len(self.axes)
        # Homing ends pulling off its switch: away from machine 0 (negative), or positive with $23's bit set.
        self._driven = [1 if int(self.settings[23]) >> i & 1 else -1 for i in range(len(self.axes))]
        self._state = IDLE
        self._sync_parser()
        self._emit("ok")


def _leading_number(text: str) -> tuple[str, str] | None:
    """Split GRBL's ``read_float`` prefix (sign, digits, one point) off ``text``."""
    i = 0
    if text[:1] in ("+", "-"):
        i = 1
    digits = point = 0
    while i < len(text) and (text[i].isdigit() or (text[i] == "." and not point)):
        if text[i] == ".":
            point = 1
        else:
            digits += 1
        i += 1
    if digits == 0:
        return None
    return text[:i], text[i:]
