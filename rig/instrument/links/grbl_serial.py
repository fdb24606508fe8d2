"""One GRBL 1.1 serial session over pyserial: banner handshake, character counting, ``?`` polling, alarms, resets.

Replies are awaited in wall time (``reply_timeout_s``, ``banner_timeout_s``: a serial answer either comes within
milliseconds or not at all), but every wait for the *machine* (a queued line's acknowledgement, a feed hold, homing)
polls with ``?`` every ``poll_interval_s`` of the injected clock, so a client and a virtual controller sharing a
``ManualClock`` advance the simulation by polling, and with a real controller ``?`` doubles as a keep-alive.

Streaming counts the bytes (line + LF) sent and not yet answered by ``ok``/``error:N`` and never lets them exceed
GRBL's 128-byte receive buffer (or what ``[OPT:...]`` reports), so nothing is ever dropped however many lines are
queued. Real-time bytes (``?`` ``!`` ``~`` 0x18) bypass the buffer and are not counted.

A noisy line loses replies (GRBL has no checksum). A lost status report is asked for again (``status_retries``
times); lines left unanswered while GRBL reports Idle (or Alarm) in polls over a quarter of a second were done,
their replies lost: ``GrblReplyLost`` says so then instead of after ``command_timeout_s``,
``command(..., repeatable=True)`` sends such a line again (``status_retries`` times), and ``replies_lost`` counts
them. A corrupted report (a byte that is no character, an unknown state) is dropped, never read as another state.

One file past 400 lines on purpose: the handshake, character counting, polling and reset handling share
the session's receive buffer state.
"""

from __future__ import annotations

import logging
import re
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping

import serial

from rig.instrument.clock import Clock
from rig.instrument.links.base import LinkError
from rig.instrument.links.grbl_protocol import (
    BANNER_RE,
    CRITICAL_ALARMS,
    POSITION_LOST_ALARMS,
    REPLY_LOST,
    GrblConnectError,
    GrblError,
    GrblReplyLost,
    GrblResetError,
    GrblStatus,
    GrblTimeoutError,
    alarm_error,
    command_error,
    parse_status,
)

log = logging.getLogger(__name__)

RX_BUFFER_BYTES = 128
_READ_SLICE_S = 0.01  # pyserial read timeout: the granularity of every wall-time wait
_RESET = b"\x18"
_UNPLUGGED = "is the cable or the controller unplugged?"
#: Clock seconds GRBL has to answer a line it took in while Idle: milliseconds, or the ~50 ms of a '$$' dump
#: at 115200 baud, whose 'ok' comes last (a report may slip in before it).
_REPLY_WITHIN_S = 0.25
_DWELL = re.compile(r"G0*4(?![0-9.])", re.IGNORECASE)  # G4 (G04): a dwell keeps GRBL Idle before its 'ok'
# Alarms after which GRBL resets itself and prints its banner (3 and 6 are the result of a reset, not a cause).
_RESET_FOLLOWS = frozenset({7, 8, 9, 10})


def format_number(value: float) -> str:
    """A G-code number with at most 4 decimals and no trailing zeros (units as given)."""
    text = f"{value:.4f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


class GrblSession:
    """An open serial connection to a GRBL 1.1 controller; raises ``GrblError`` subclasses for what GRBL reports.

    Opens ``port`` and waits for the banner (soft-resetting first with ``reset_on_connect``; one 0x18 is also
    tried when no banner comes, for boards without auto-reset), then reads ``$I`` and ``$$``.
    """

    def __init__(
        self,
        port: str,
        clock: Clock,
        *,
        baudrate: int = 115200,
        reset_on_connect: bool = False,
        banner_timeout_s: float = 3.0,
        reply_timeout_s: float = 0.5,
        status_retries: int = 3,
        poll_interval_s: float = 0.1,
        command_timeout_s: float = 30.0,
    ) -> None:
        self.port = port
        self.clock = clock
        self.poll_interval_s = poll_interval_s
        self.command_timeout_s = command_timeout_s
        self._banner_timeout_s = banner_timeout_s
        self._reply_timeout_s = reply_timeout_s
        self._status_retries = max(int(status_retries), 0)
        self._rx = bytearray()
        self._inflight: deque[tuple[str, int]] = deque()
        self._inflight_bytes = 0
        self._sent = 0
        self._acked = 0
        self._data: list[str] = []
        self._status: GrblStatus | None = None
        self._status_count = 0
        self._banners = 0
        self._wco: tuple[float, ...] | None = None
        self._resets_expected = 0
        self._handshaking = False
        self._quiet = False
        self.messages: deque[str] = deque(maxlen=50)
        self.version: str | None = None
        self.rx_buffer_bytes = RX_BUFFER_BYTES
        self.report_inches = False
        self.halted = False  # after ALARM:1/2 GRBL serves nothing but '?' and reset
        self.last_alarm: int | None = None
        self.position_lost = False
        self.generation = 0  # bumped by every reset and alarm: modal state and planned position must be re-read
        self.last_motion_line: str | None = None
        self.replies_lost = 0  # 'ok'/'error:N' replies lost on the line (GRBL went Idle without sending them)
        try:
            self._ser: serial.Serial | None = serial.Serial(
                port, baudrate=baudrate, timeout=_READ_SLICE_S, write_timeout=reply_timeout_s
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            raise GrblConnectError(f"cannot open GRBL port {port!r}: {exc}") from exc
        try:
            self._handshake(reset_on_connect, baudrate)
            for text in self.command("$I", repeatable=True):
                fields = text[5:-1].split(",") if text.startswith("[OPT:") else []
                if len(fields) >= 3 and fields[2].isdigit():
                    self.rx_buffer_bytes = int(fields[2])
            if self.last_status.state in ("Idle", "Alarm"):
                self.report_inches = self.settings().get(13, 0.0) == 1.0
        except BaseException:
            self.close()
            raise

    # ---- public --------------------------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        """Whether the port is still open."""
        return self._ser is not None

    @property
    def in_flight(self) -> int:
        """Lines sent and not yet answered."""
        return len(self._inflight)

    @property
    def last_status(self) -> GrblStatus:
        """The most recent status report (queries one if none yet)."""
        return self._status if self._status is not None else self.status()

    @property
    def work_offset(self) -> tuple[float, ...] | None:
        """The last ``WCO`` reported (units), for reports that give ``WPos``."""
        return self._wco

    def close(self) -> None:
        """Close the port (no commands sent); safe to call twice."""
        ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except (serial.SerialException, OSError) as exc:
                log.warning("GRBL on %s: error closing the port: %s", self.port, exc)

    def status(self) -> GrblStatus:
        """Send ``?`` and handle every line up to the report; retries when a report goes missing.

        Lines already waiting are handled first: a report that came after its query was given up on (and
        asked again) must not pass for the answer to this one, or the link acts on where the axes were.
        """
        self._take_waiting()
        for _ in range(self._status_retries + 1):
            count = self._status_count
            self.write_realtime(b"?")
            deadline = time.monotonic() + self._reply_timeout_s
            while self._status_count == count:
                line = self._read_line(deadline - time.monotonic())
                if line is None:
                    break
                self._handle(line)
            if self._status is not None and self._status_count != count:
                return self._status
        tries = self._status_retries + 1
        raise GrblTimeoutError(
            f"GRBL on {self.port}: no status report to {tries} '?' ({self._reply_timeout_s:g} s each); "
            f"if it answers otherwise, {REPLY_LOST}"
        )

    def _take_waiting(self) -> None:
        """Handle every complete line already received, without waiting for more."""
        while (line := self._read_line(0.0)) is not None:
            self._handle(line)

    def write_realtime(self, data: bytes) -> None:
        """Send real-time bytes (``?``, ``!``, ``~``, 0x18), which bypass GRBL's line buffer."""
        if self._ser is None:
            raise LinkError(f"GRBL link on {self.port} is shut down")
        try:
            self._ser.write(data)
        except serial.SerialTimeoutException as exc:
            raise GrblTimeoutError(f"GRBL on {self.port}: write timed out ({exc})") from exc
        except (serial.SerialException, OSError) as exc:
            raise GrblError(f"GRBL on {self.port}: write failed: {exc}; {_UNPLUGGED}") from exc

    def send(self, line: str) -> int:
        """Queue ``line`` as soon as it fits in GRBL's receive buffer (character counting); its sequence number."""
        data = line.encode("ascii")
        if b"\n" in data or b"\r" in data:
            raise ValueError(f"one G-code line at a time, without line breaks: {line!r}")
        n = len(data) + 1
        if n > self.rx_buffer_bytes:
            raise ValueError(f"line of {n} bytes can never fit GRBL's {self.rx_buffer_bytes}-byte buffer: {line!r}")
        self.check_not_halted()
        self.wait_for(lambda: self._inflight_bytes + n <= self.rx_buffer_bytes, self.command_timeout_s, "buffer room")
        self._inflight.append((line, n))
        self._inflight_bytes += n
        self._sent += 1
        self.write_realtime(data + b"\n")
        return self._sent

    def wait_acknowledged(self, timeout_s: float | None = None) -> None:
        """Wait (clock seconds) until every line sent has been answered; raises on the first ``error:N``."""
        timeout = timeout_s if timeout_s is not None else self.command_timeout_s
        self.wait_for(lambda: not self._inflight, timeout, "acknowledgement of queued lines")

    def command(self, line: str, timeout_s: float | None = None, *, repeatable: bool = False) -> list[str]:
        """Send one line after the queue drains and wait for ``ok``; returns the lines GRBL printed before it.

        A ``repeatable`` line (one that does the same however often it runs, such as ``$$`` or ``G21 G90``) is
        sent again when its reply is lost, ``status_retries`` times at most; any other raises ``GrblReplyLost``.
        """
        timeout = timeout_s if timeout_s is not None else self.command_timeout_s
        tries = self._status_retries + 1 if repeatable else 1
        for attempt in range(1, tries + 1):
            try:
                return self._command_once(line, timeout)
            except GrblReplyLost as exc:
                if tries == 1:
                    raise
                if attempt == tries:
                    raise GrblTimeoutError(f"GRBL on {self.port}: no reply to {line!r} although GRBL went Idle "
                                           f"with it done, {tries} times: {REPLY_LOST}") from exc  # fmt: skip
                log.warning("%s; sending it again", exc)
        raise AssertionError("unreachable")

    def _command_once(self, line: str, timeout: float) -> list[str]:
        """``command`` without the retries: send after the queue drains, wait for the reply, the lines before it."""
        self.wait_acknowledged(timeout)
        self._data.clear()
        seq = self.send(line)
        self.wait_for(lambda: self._acked >= seq, timeout, f"reply to {line!r}")
        data = list(self._data)
        self._data.clear()
        return data

    def send_lines(self, lines: Iterable[str], timeout_s: float | None = None) -> None:
        """Stream lines with character counting and wait until all are answered; raises on the first error."""
        for line in lines:
            self.send(line)
        self.wait_acknowledged(timeout_s)

    def settings(self) -> dict[int, float]:
        """The ``$$`` settings by number."""
        values: dict[int, float] = {}
        for text in self.command("$$", repeatable=True):
            key, sep, value = text.partition("=")
            if sep and key.startswith("$") and key[1:].isdigit():
                values[int(key[1:])] = float(value.split()[0])
        return values

    def write_settings(self, values: Mapping[int, float]) -> None:
        """Write ``$N=value`` settings, streamed; GRBL validates each (``error:N`` raises)."""
        self.send_lines(f"${k}={format_number(v)}" for k, v in values.items())

    def reset(self) -> GrblStatus:
        """Soft reset (0x18), wait for the banner, return the status after it (Alarm if it was moving)."""
        self._quiet = True
        try:
            self._resets_expected += 1
            banners = self._banners
            self.write_realtime(_RESET)
            deadline = time.monotonic() + self._banner_timeout_s
            while self._banners == banners:
                line = self._read_line(deadline - time.monotonic())
                if line is None:
                    raise GrblTimeoutError(f"GRBL on {self.port}: no banner {self._banner_timeout_s:g} s after reset")
                self._handle(line)
            status = self.status()
        finally:
            self._quiet = False
        self._resets_expected = 0
        return status

    def wait_for(self, done: Callable[[], bool], timeout_s: float, what: str, fresh: bool = False) -> None:
        """Poll ``?`` every ``poll_interval_s`` of clock time until ``done()``; ``GrblTimeoutError`` after.

        Lines still unanswered while GRBL reports Idle (or Alarm) in polls running over ``_REPLY_WITHIN_S`` were
        done (its main loop is free then, and it answers a line as it takes it in): their replies were lost, and
        ``GrblReplyLost`` says so then rather than after ``timeout_s`` (a dwell, the one line that idles
        unanswered, is waited out).
        """
        if not fresh and done():
            return
        deadline = self.clock.now() + timeout_s
        idle = 0
        idle_since = 0.0
        while True:
            status = self.status()
            if done():
                return
            self.check_not_halted()
            dwelling = any(_DWELL.search(text) for text, _ in self._inflight)
            free = status.state in ("Idle", "Alarm")  # GRBL's main loop takes lines in (Alarm answers error:9)
            if self._inflight and free and not dwelling:
                idle_since = idle_since if idle else self.clock.now()
                idle += 1
            else:
                idle = 0
            if idle >= 2 and self.clock.now() - idle_since >= _REPLY_WITHIN_S:
                raise self._replies_lost()
            if self.clock.now() >= deadline:
                raise GrblTimeoutError(f"GRBL on {self.port}: {what}: not done after {timeout_s:g} s ({status.state})")
            self.clock.sleep(self.poll_interval_s)

    def _replies_lost(self) -> GrblReplyLost:
        """Take the unanswered lines as done (their replies lost) and the exception that says so."""
        lost = [text for text, _ in self._inflight]
        self._inflight.clear()
        self._inflight_bytes = 0
        self._acked = self._sent
        self.replies_lost += len(lost)
        return GrblReplyLost(self.port, lost)

    def check_not_halted(self) -> None:
        """Raise if GRBL is halted by a critical alarm (it answers nothing but ``?`` and reset)."""
        if self.halted:
            raise GrblError(f"GRBL on {self.port} is halted by ALARM:{self.last_alarm}: call reset() first")

    def alarm_state_error(self) -> GrblError:
        """The exception for finding the controller in Alarm (the last alarm's, or the homing lock)."""
        if self.last_alarm is not None:
            return alarm_error(self.port, self.last_alarm, self.last_motion_line)
        return GrblError(f"GRBL on {self.port} is in Alarm (homing required): call home() or unlock()")

    # ---- handshake -----------------------------------------------------------------------------------------
    def _handshake(self, reset: bool, baudrate: int) -> None:
        self._handshaking = True
        try:
            # An Arduino resets when the port opens and prints its banner after the bootloader.
            got, seen = self._await_banner(min(self._banner_timeout_s, 0.5) if reset else self._banner_timeout_s)
            if reset or not got:
                self.write_realtime(_RESET)
                got, more = self._await_banner(self._banner_timeout_s)
                seen += more
            if not got:
                what = (
                    f"received {seen[:3]!r}: is this a GRBL controller at {baudrate} baud?"
                    if seen
                    else "nothing received: wrong port, wrong baud rate, or controller not powered?"
                )
                raise GrblConnectError(f"no GRBL banner on {self.port} within {self._banner_timeout_s:g} s ({what})")
            self.status()
        finally:
            self._handshaking = False
        self._resets_expected = 0

    def _await_banner(self, timeout_s: float) -> tuple[bool, list[str]]:
        deadline = time.monotonic() + timeout_s
        seen: list[str] = []
        while True:
            line = self._read_line(deadline - time.monotonic())
            if line is None:
                return False, seen
            if BANNER_RE.match(line):
                self._handle(line)
                return True, seen
            if line:
                seen.append(line)

    # ---- reading and dispatch ------------------------------------------------------------------------------
    def _read_line(self, timeout_s: float) -> str | None:
        """One line (CR/LF stripped) within ``timeout_s`` seconds of wall time, else None."""
        if self._ser is None:
            raise LinkError(f"GRBL link on {self.port} is shut down")
        deadline = time.monotonic() + max(timeout_s, 0.0)
        while True:
            end = self._rx.find(b"\n")
            if end >= 0:
                raw = bytes(self._rx[:end])
                del self._rx[: end + 1]
                return raw.decode("ascii", "replace").strip()
            try:
                waiting = self._ser.in_waiting
                if not waiting and time.monotonic() >= deadline:
                    return None
                self._rx += self._ser.read(waiting or 1)  # blocks at most _READ_SLICE_S for the first byte
            except (serial.SerialException, OSError) as exc:
                raise GrblError(f"GRBL on {self.port}: read failed: {exc}; {_UNPLUGGED}") from exc

    def _handle(self, line: str) -> None:
        """Dispatch one line from GRBL; raises for ``error:N``, ``ALARM:N`` and unexpected resets."""
        if not line:
            return
        if line == "ok" or line.startswith("error:"):
            code = None if line == "ok" else int(line[6:]) if line[6:].isdigit() else -1
            if not self._inflight:
                log.debug("GRBL on %s: reply %r with nothing in flight", self.port, line)
                return
            text, n = self._inflight.popleft()
            self._inflight_bytes -= n
            self._acked += 1
            if code is not None and not self._quiet:
                raise command_error(self.port, code, text)
        elif line.startswith("<"):
            try:
                status = parse_status(line)
            except ValueError as exc:
                log.warning("GRBL on %s: %s", self.port, exc)
                return
            self._status = status
            self._status_count += 1
            if status.wco is not None:
                self._wco = status.wco
        elif line.startswith("ALARM:") and line[6:].isdigit():
            self._on_alarm(int(line[6:]))
        elif BANNER_RE.match(line):
            self._on_banner(line)
        elif line.startswith("[MSG:"):
            self.messages.append(line[5:].rstrip("]"))
            if line == "[MSG:Reset to continue]":
                self.halted = True
        else:
            self._data.append(line)

    def _on_alarm(self, code: int) -> None:
        self.last_alarm = code
        self.generation += 1
        if code in POSITION_LOST_ALARMS:
            self.position_lost = True
        if code in CRITICAL_ALARMS:
            self.halted = True
        if code in _RESET_FOLLOWS:
            self._resets_expected += 1
        if not self._quiet:
            where = self._inflight[0][0] if self._inflight else self.last_motion_line
            raise alarm_error(self.port, code, where)
        log.warning("GRBL on %s: ALARM:%d during reset", self.port, code)

    def _on_banner(self, line: str) -> None:
        m = BANNER_RE.match(line)
        assert m is not None
        major, minor = int(m.group(1)), int(m.group(2))
        if (major, minor) < (1, 1):
            raise GrblConnectError(f"{line!r} on {self.port}: this link speaks GRBL 1.1 (status format differs)")
        self.version = f"{major}.{minor}{m.group(3)}"
        lost = len(self._inflight)
        self._inflight.clear()
        self._inflight_bytes = 0
        self._acked = self._sent
        self._data.clear()
        self._banners += 1
        self.halted = False
        self.generation += 1
        if self._handshaking:
            return
        if self._resets_expected > 0:
            self._resets_expected -= 1
            return
        raise GrblResetError(f"GRBL on {self.port} reset unexpectedly; {lost} queued line(s) were lost")
