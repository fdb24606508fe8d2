"""Core of the virtual GRBL 1.1 controller: serial bytes in, replies out, motion on an injectable clock.

``GrblCore`` is GRBL's serial interrupt, main loop, G-code execution, real-time commands and reports;
``simulator.grbl.controller.VirtualGrbl`` adds the ``$`` commands, homing and fault injection. Positions are in
controller units (GRBL's millimetres; the gonio uses motor degrees), times in seconds of the clock, feeds in
units/min. See ``simulator/grbl/controller.py`` for what is modelled and what is simplified.

One file past 400 lines on purpose: GRBL's line protocol, real-time bytes and state machine act on one
shared state; G-code parsing, settings and motion are in gcode.py, settings.py and motion.py.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Mapping

from rig.instrument.clock import Clock, SystemClock
from simulator.grbl.gcode import Alarm, GcodeError, LineAssembler, Modal, Status, parse_block
from simulator.grbl.motion import MotionQueue, Move
from simulator.grbl.noise import LineNoise
from simulator.grbl.settings import AXIS_LETTERS, GrblSettings

VERSION = "1.1h"
BUILD_DATE = "20190830"
RX_BUFFER_SIZE = 128
PLANNER_BLOCKS = 15
BANNER = f"\r\nGrbl {VERSION} ['$' for help]\r\n"
MSG_LOCKED = "[MSG:'$H'|'$X' to unlock]"

IDLE, ALARM, CHECK, HOMING, CYCLE, HOLD, JOG, DOOR = "Idle", "Alarm", "Check", "Home", "Run", "Hold", "Jog", "Door"
_Action = tuple[str, object]


class GrblCore:
    """GRBL's serial buffer, main loop, planner and reports; subclasses supply ``$`` commands and homing."""

    def __init__(
        self,
        clock: Clock | None = None,
        axes: str = "XYZ",
        settings: Mapping[int, float] | None = None,
        start_position: Mapping[str, float] | None = None,
    ) -> None:
        if not axes or AXIS_LETTERS[: len(axes)] != axes:
            raise ValueError(f"virtual GRBL axes {axes!r}: expected a prefix of {AXIS_LETTERS!r}, e.g. 'XYZ'")
        self._clock: Clock = clock if clock is not None else SystemClock()
        self._lock = threading.RLock()
        self.axes = axes
        self.settings = GrblSettings(len(axes), settings)
        n = len(axes)
        self._motion = MotionQueue(n, PLANNER_BLOCKS)
        start = start_position or {}
        unknown = set(start) - set(axes)
        if unknown:
            raise ValueError(f"virtual GRBL: start_position names unknown axes {sorted(unknown)}")
        # Physical position = reported machine position + offset; power-up zeroes the report, homing finds 0.
        self._offset = [float(start.get(a, 0.0)) for a in axes]
        self._t = self._clock.now()
        self._out = bytearray()
        self._rx: deque[int] = deque()
        self._assembler = LineAssembler()
        self._state = IDLE
        self._critical = False
        self._pending: list[_Action] | None = None
        self._soft_limit_hold = False
        self._modal = Modal()
        self._gc_pos = [0.0] * n
        self._planned = [0.0] * n
        # Per axis, the sign of its last motion (0: none yet), for gear play that lags behind it.
        self._driven = [0] * n
        # Homing in progress: (start time, end time, reported start, reported position at the end, fault).
        self._homing: tuple[float, float, list[float], list[float], int | None] | None = None
        self._homing_end: list[float] = [0.0] * n
        self._reports = 0
        # Fault injection and diagnostics.
        self._trip_at: float | None = None
        self._homing_fault: int | None = None
        self._drop_reports = 0
        self._late_reports = 0
        self._held_report: str | None = None  # a late report, sent just before the next one
        self._noise: LineNoise | None = None  # what a noisy line does to replies ('ok' and status reports)
        self._drop_oks = 0
        self.rx_dropped = 0  # bytes lost to a full receive buffer
        self.lines_received = 0  # complete lines the main loop has taken in
        self.rx_peak = 0  # most bytes ever waiting in the receive buffer
        self.last_alarm: int | None = None

    def receive(self, data: bytes) -> None:
        """Bytes arriving on the serial line, in order."""
        with self._lock:
            self._advance(self._clock.now())
            for c in data:
                if c in (0x3F, 0x21, 0x7E, 0x18) or c >= 0x80:
                    self._realtime(c)
                elif len(self._rx) >= RX_BUFFER_SIZE:
                    self.rx_dropped += 1
                else:
                    self._rx.append(c)
                    self.rx_peak = max(self.rx_peak, len(self._rx))
                    self._service()

    def update(self) -> None:
        """Advance the simulation to the clock's now (events, queued lines, alarms)."""
        with self._lock:
            self._advance(self._clock.now())

    def read_output(self) -> bytes:
        """Take the bytes the controller has sent since the last call."""
        with self._lock:
            data = bytes(self._out)
            self._out.clear()
            return data

    # ---- time ----------------------------------------------------------------------------------------------
    def _next_event(self) -> float | None:
        times = [self._motion.next_event(), self._trip_at]
        if self._pending:
            kind, arg = self._pending[0]
            # A dwell that ran out while the main loop is suspended is no longer an event.
            if kind == "until" and isinstance(arg, float) and arg > self._t:
                times.append(arg)
        if self._homing is not None:
            times.append(self._homing[1])
        found = [t for t in times if t is not None]
        return min(found) if found else None

    def _advance(self, now: float) -> None:
        for _ in range(1_000_000):
            event = self._next_event()
            if event is None or event > now:
                self._step_to(now)
                return
            self._step_to(event)
        raise RuntimeError("virtual GRBL: event loop did not converge (simulator bug)")

    def _step_to(self, t: float) -> None:
        self._t = max(t, self._t)
        event = self._motion.step(self._t)
        if event == "done" and not self._motion.busy and self._state in (CYCLE, JOG):
            self._state = IDLE
        elif event == "stopped":
            if self._soft_limit_hold:
                self._soft_limit_hold = False
                self._critical_alarm(Alarm.SOFT_LIMIT)
            elif not self._motion.busy:  # a cancelled jog: its remaining moves are gone
                self._sync_parser()
                if self._state == JOG:
                    self._state = IDLE
        if self._trip_at is not None and self._t >= self._trip_at:
            self._trip_at = None
            if self.settings.flag(21) and self._state not in (ALARM, HOMING):
                self._critical_alarm(Alarm.HARD_LIMIT)
        if self._homing is not None and self._t >= self._homing[1]:
            self._finish_homing()
        self._service()

    # ---- real-time commands --------------------------------------------------------------------------------
    def _realtime(self, c: int) -> None:
        if c == 0x18:
            self._soft_reset()
        elif c == 0x3F:
            if self._drop_reports:
                self._drop_reports -= 1
                return
            report = self._status_report()
            if self._held_report is not None:
                self._emit(self._held_report)
                self._held_report = None
            if self._late_reports:
                self._late_reports -= 1
                self._held_report = report
            else:
                self._emit(report)
        elif self._critical:
            return
        elif c == 0x21:
            if self._state == CYCLE or (self._state == IDLE and not self._pending):
                self._motion.hold(self._t)
                self._state = HOLD
            elif self._state == JOG:
                self._motion.hold(self._t, cancel=True)
        elif c == 0x7E:
            if self._state in (HOLD, DOOR) and self._motion.mode in ("held", "idle"):
                self._motion.resume(self._t)
                self._state = CYCLE if self._motion.mode == "run" else IDLE
                self._service()
        elif c == 0x85 and self._state == JOG:
            self._motion.hold(self._t, cancel=True)
        elif c == 0x84 and self._state in (IDLE, CYCLE, HOLD, JOG):
            self._emit("[MSG:Check Door]")
            self._motion.hold(self._t, cancel=self._state == JOG)
            self._state = DOOR

    def _soft_reset(self) -> None:
        alarm: int | None = None
        if self._state == HOMING:
            alarm = Alarm.HOMING_FAIL_RESET
        elif self._state in (CYCLE, JOG) or self._motion.mode == "hold":
            alarm = Alarm.ABORT_CYCLE
        self._motion.kill()
        if alarm is not None:
            self._raise_alarm(alarm)
        if self._pending is not None:
            self._emit("ok")  # the interrupted line returns before GRBL's main loop aborts
        self._reset_system()

    def _reset_system(self) -> None:
        if self._homing is not None:
            self._motion.set_position(self._positions(quantise=False))
            self._homing = None
        self._motion.kill()
        self._rx.clear()
        self._assembler.clear()
        self._pending = None
        self._critical = False
        self._soft_limit_hold = False
        self._modal = Modal()
        self._sync_parser()
        self._state = ALARM if self._state == ALARM else IDLE
        self._reports = 0
        self._out += BANNER.encode()
        if self._state == ALARM:
            self._emit(MSG_LOCKED)

    def _raise_alarm(self, code: int) -> None:
        self._state = ALARM
        self.last_alarm = int(code)
        self._emit(f"ALARM:{int(code)}")

    def _critical_alarm(self, code: int) -> None:
        self._motion.kill()
        self._sync_parser()
        self._raise_alarm(code)
        self._emit("[MSG:Reset to continue]")
        self._critical = True

    # ---- main loop -----------------------------------------------------------------------------------------
    def _service(self) -> None:
        while not (self._critical or self._state in (HOLD, DOOR)):
            if self._pending is not None:
                if not self._run_pending():
                    return
                continue
            if not self._rx:
                return
            done = self._assembler.feed(self._rx.popleft())
            if done is not None:
                self._execute_line(*done)

    def _run_pending(self) -> bool:
        """Work through the executing line's actions; True once it has answered ``ok``."""
        assert self._pending is not None
        while self._pending:
            kind, arg = self._pending[0]
            if kind == "move":
                if self._motion.full:
                    return False
                assert isinstance(arg, tuple)
                self._queue_move(*arg)
            elif kind == "sync":
                if self._motion.busy:
                    return False
            elif kind == "dwell":
                assert isinstance(arg, float)
                self._pending[0] = ("until", self._t + arg)
                continue
            elif kind == "until":
                assert isinstance(arg, float)
                if self._t < arg:
                    return False
            elif kind == "end":
                self._modal = Modal(motion=1, feed=self._modal.feed, tool=self._modal.tool)
                self._emit("[MSG:Pgm End]")
            else:  # "blocked": homing or a soft-limit stop in progress
                return False
            self._pending.pop(0)
        self._pending = None
        self._emit("ok")
        return True

    def _execute_line(self, line: str, overflow: bool) -> None:
        self.lines_received += 1
        if overflow:
            self._error(Status.OVERFLOW)
        elif not line:
            self._emit("ok")
        elif line[0] == "$":
            self._system_command(line)
        elif self._state in (ALARM, JOG):
            self._error(Status.SYSTEM_GC_LOCK)
        else:
            self._gcode(line, jog=False)

    def _error(self, status: int) -> None:
        self._emit(f"error:{int(status)}")

    def _gcode(self, line: str, jog: bool) -> None:
        try:
            block = parse_block(line[3:] if jog else line, self._modal, self._gc_pos, self.axes, jog=jog)
        except GcodeError as exc:
            self._error(exc.status)
            return
        actions: list[_Action] = []
        checking = self._state == CHECK
        if block.dwell_s is not None and not checking:
            actions += [("sync", None), ("dwell", float(block.dwell_s))]
        if block.target is not None:
            if self.settings.flag(20) and not self._within_travel(block.target):
                if jog:
                    self._error(Status.TRAVEL_EXCEEDED)
                    return
                self._soft_limit()
                return
            if not checking:
                actions.append(("move", (block.target, block.rapid, block.feed, jog)))
        if block.program_end:
            actions += [("sync", None), ("end", None)]
        self._modal = block.modal
        self._gc_pos = block.position
        self._pending = actions
        self._run_pending()

    def _soft_limit(self) -> None:
        self._pending = [("blocked", None)]
        if self._motion.busy and self._motion.mode == "run":
            # GRBL stops the buffered motion with a controlled hold first, so the position stays valid.
            self._motion.hold(self._t, cancel=True)
            self._soft_limit_hold = True
            self._state = HOLD
        else:
            self._critical_alarm(Alarm.SOFT_LIMIT)

    def _within_travel(self, target: list[float]) -> bool:
        return all(-self.settings.max_travel(i) <= v <= 0.0 for i, v in enumerate(target))

    def _queue_move(self, target: list[float], rapid: bool, feed: float, jog: bool) -> None:
        s = self.settings
        quantised = tuple(round(v * s.steps_per_unit(i)) / s.steps_per_unit(i) for i, v in enumerate(target))
        start = tuple(self._planned)
        deltas = [abs(b - a) for a, b in zip(start, quantised, strict=True)]
        length = math.hypot(*deltas)
        if length <= 0.0:
            return  # GRBL drops zero-length blocks
        rate = min(s.max_rate(i) / 60.0 * length / d for i, d in enumerate(deltas) if d > 0)
        accel = min(s.accel(i) * length / d for i, d in enumerate(deltas) if d > 0)
        speed = rate if rapid else min(rate, feed / 60.0)
        self._motion.add(Move(start, quantised, speed, accel, jog=jog), self._t)
        self._driven = [(b > a) - (b < a) or d for a, b, d in zip(start, quantised, self._driven, strict=True)]
        self._planned = list(quantised)
        if self._state == IDLE:
            self._state = JOG if jog else CYCLE

    def _sync_parser(self) -> None:
        pos = self._positions(quantise=False)
        self._gc_pos = list(pos)
        self._planned = list(pos)

    # ---- reports -------------------------------------------------------------------------------------------
    def _positions(self, quantise: bool = True) -> list[float]:
        if self._homing is not None:
            t0, t1, start, end, _ = self._homing
            f = min(max((self._t - t0) / (t1 - t0), 0.0), 1.0) if t1 > t0 else 1.0
            pos = [a + (b - a) * f for a, b in zip(start, end, strict=True)]
        else:
            pos = self._motion.position
        if not quantise:
            return pos
        return [round(p * self.settings.steps_per_unit(i)) / self.settings.steps_per_unit(i) for i, p in enumerate(pos)]

    def _state_text(self) -> str:
        if self._state in (HOLD, DOOR):
            decelerating = self._motion.mode == "hold"
            if self._state == HOLD:
                return "Hold:1" if decelerating else "Hold:0"
            return "Door:2" if decelerating else "Door:0"
        return self._state

    def _fmt(self, v: float) -> str:
        if self.settings.flag(13):
            return f"{v / 25.4:.4f}"
        return f"{v:.3f}"

    def _status_report(self) -> str:
        mask = int(self.settings[10])
        coords = ",".join(self._fmt(v) for v in self._positions())
        parts = [self._state_text(), f"{'MPos' if mask & 1 else 'WPos'}:{coords}"]
        if mask & 2:
            parts.append(f"Bf:{PLANNER_BLOCKS - len(self._motion.moves)},{RX_BUFFER_SIZE - len(self._rx)}")
        speed = self._motion.speed * 60.0
        if self._homing is not None:
            speed = self.settings[25]
        feed = f"{speed / 25.4:.1f}" if self.settings.flag(13) else f"{speed:.0f}"
        parts.append(f"FS:{feed},0")
        # GRBL sends the work offset only every 10-30 reports (first after a reset) and the overrides in the
        # report after it, whatever $10 says; clients must cope with both coming and going.
        if self._reports % 10 == 0:
            parts.append("WCO:" + ",".join(self._fmt(0.0) for _ in self.axes))
        elif self._reports % 10 == 1:
            parts.append("Ov:100,100,100")
        self._reports += 1
        return "<" + "|".join(parts) + ">"

    def _emit(self, text: str) -> None:
        line = text.encode() + b"\r\n"
        if text == "ok" and self._drop_oks:
            self._drop_oks -= 1
            return
        if self._noise is not None and (text == "ok" or text.startswith("<")):
            line = self._noise.carry(line)
        self._out += line

    # ---- supplied by the subclass --------------------------------------------------------------------------
    def _system_command(self, line: str) -> None:
        raise NotImplementedError

    def _finish_homing(self) -> None:
        raise NotImplementedError
