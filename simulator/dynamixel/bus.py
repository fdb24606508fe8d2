"""A virtual Dynamixel bus served on a pseudo-terminal: clients open ``bus.port`` like a USB adapter.

One daemon thread owns the pty master: it reads instruction packets, lets the servos execute them and
writes their status packets back, applying each servo's reply faults on the way. The thread polls with a
short timeout and a wake-up pipe, so ``close`` returns promptly.

Baud rate: a pty carries bytes at any speed, but its termios settings still record the speed the client
asked for, and the master side sees the client's ``tcsetattr`` (pyserial sets it on open and on every
baud change). Before each packet the bus reads that speed from its own handle on the slave, and only
servos whose Baud Rate (8) matches it within 3 % (the UART tolerance the e-Manual quotes) hear the
packet; the others would see garbage, so they stay silent. A baud scan therefore finds each servo only
at its own rate. ``set_line_baud`` overrides the detected speed (for clients that do not set one).

Timing with a ``ManualClock``: packets run in the order they arrive, but a packet that gets no reply
(broadcast WRITE or ACTION, SYNC/BULK WRITE, any TxOnly call) returns to the client before the bus has
necessarily seen it. Do one round trip (a PING) before advancing the clock, or the move may start late.
The SDK also leaves the status packets of unicast ACTION and TxOnly writes unread in its input buffer.
On a clock that settles (``ManualClock.add_settler``) the bus registers itself: time cannot move on while
bytes a client wrote wait unhandled, so every packet acts at the simulated time it was sent, however late the
serving thread runs on a loaded host (``pause`` holds the thread, to test exactly that).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import os
import select
import struct
import termios
import threading
import time
import tty
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from rig.instrument.clock import Clock, SystemClock
from simulator.dynamixel import instructions
from simulator.dynamixel.faults import ReplyFate
from simulator.dynamixel.protocol import PacketParser, crc16
from simulator.dynamixel.servo import VirtualServo
from simulator.settling import Settling

BAUD_TOLERANCE = 0.03
"""Relative baud mismatch a UART tolerates (e-Manual: under 3 % does not affect communication)."""

_TCGETS2 = 0x802C542A  # Linux termios2 read, for speeds set with BOTHER (e.g. 4.5 Mbps)
_BOTHER = 0o010000
_TERMIOS_SPEEDS = {
    getattr(termios, name): int(name[1:])
    for name in dir(termios)
    if name.startswith("B") and name[1:].isdigit() and int(name[1:]) > 0
}
_POLL_S = 0.05
_WRITE_TIMEOUT_S = 0.5


@dataclass
class BusStats:
    """Counters of what crossed the wire since the bus started."""

    packets: int = 0
    crc_mismatches: int = 0
    noise_bytes: int = 0
    replies_sent: int = 0
    replies_dropped: int = 0
    replies_corrupted: int = 0


class VirtualDynamixelBus(Settling):
    """A set of virtual XM430-W350 servos answering Protocol 2.0 on a pseudo-terminal.

    ``start``/``close`` serve and stop; in a ``with`` block (``open_virtual_bus``) it serves for the block.

    Parameters
    ----------
    ids:
        IDs of the servos on the bus (0..252).
    baudrate:
        The servos' Baud Rate register at start, in bits per second (57600, 1000000, ...).
    clock:
        Time source of the servos' motion (a ``ManualClock`` in tests); ``SystemClock`` by default.
    seed:
        Base seed of the servos' random faults (servo ``i`` gets ``seed + id``).
    positions:
        Optional start position in ticks per ID (default 2048, mid-range).
    return_delay:
        When True, each reply waits the servo's Return Delay Time (9) in real time (default 250 -> 0.5 ms).
        Off by default so tests stay fast.
    crc_error_replies:
        When True (default), a frame with a bad CRC addressed to a servo gets a status packet with
        CRC Error (3); when False it is ignored.
    """

    def __init__(
        self,
        ids: Iterable[int] = (1, 2, 3, 4),
        baudrate: int = 1_000_000,
        clock: Clock | None = None,
        *,
        seed: int = 0,
        positions: Mapping[int, int] | None = None,
        return_delay: bool = False,
        crc_error_replies: bool = True,
    ) -> None:
        ids = list(ids)
        if len(set(ids)) != len(ids):
            raise ValueError(f"servo ids {ids} contain duplicates")
        positions = dict(positions or {})
        unknown = set(positions) - set(ids)
        if unknown:
            raise ValueError(f"positions given for ids {sorted(unknown)} that are not on the bus {ids}")
        self.clock: Clock = clock if clock is not None else SystemClock()
        self.lock = threading.RLock()
        self._servos = [
            VirtualServo(
                i, clock=self.clock, lock=self.lock, baudrate=baudrate, position_ticks=positions.get(i, 2048),
                seed=seed + i,
            )
            for i in ids
        ]  # fmt: skip
        self.baudrate = baudrate
        self.return_delay = return_delay
        self.crc_error_replies = crc_error_replies
        self.stats = BusStats()
        self.errors: list[BaseException] = []
        """Exceptions raised while handling packets (the thread logs them here and keeps serving)."""
        self._line_baud_override: int | None = None
        self._parser = PacketParser()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._init_settling()
        self._unsettle = None
        self._master = -1
        self._slave = -1
        self._wake_r = self._wake_w = -1
        self.port = ""

    # --- lifecycle ------------------------------------------------------------------------------------

    def start(self) -> VirtualDynamixelBus:
        """Open the pseudo-terminal and start serving; returns self."""
        if self._thread is not None:
            raise RuntimeError(f"virtual bus on {self.port} is already running")
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self._wake_r, self._wake_w = os.pipe()
        self.port = os.ttyname(self._slave)
        self._stop.clear()
        self._thread = threading.Thread(target=self._serve, name=f"virtual-dynamixel {self.port}", daemon=True)
        self._thread.start()
        self._settle_with(self.clock)
        return self

    def close(self) -> None:
        """Stop the thread and close the pseudo-terminal (idempotent)."""
        self._stop_serving()
        if self._wake_w >= 0:
            with contextlib.suppress(OSError):
                os.write(self._wake_w, b"x")
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        for fd in (self._master, self._slave, self._wake_r, self._wake_w):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self._master = self._slave = self._wake_r = self._wake_w = -1

    def __enter__(self) -> VirtualDynamixelBus:
        return self if self._thread is not None else self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def running(self) -> bool:
        """True while the serving thread is alive."""
        return self._thread is not None and self._thread.is_alive()

    # --- servos and line ------------------------------------------------------------------------------

    @property
    def servos(self) -> tuple[VirtualServo, ...]:
        """All servos on the bus, in the order they were created."""
        return tuple(self._servos)

    def servo(self, dxl_id: int) -> VirtualServo:
        """The servo whose ID (7) is ``dxl_id`` now; KeyError naming the IDs present otherwise."""
        with self.lock:
            found = [s for s in self._servos if s.id == dxl_id]
            if len(found) == 1:
                return found[0]
            present = sorted(s.id for s in self._servos)
            if not found:
                raise KeyError(f"no servo with id {dxl_id!r} on the virtual bus {self.port}; ids present: {present}")
            raise KeyError(f"{len(found)} servos share id {dxl_id} on the virtual bus {self.port}; ids: {present}")

    def set_line_baud(self, baudrate: int | None) -> None:
        """Force the line speed the servos compare with (bps); None follows the client's termios setting."""
        if baudrate is not None and baudrate <= 0:
            raise ValueError(f"line baud rate {baudrate!r}: expected a positive number of bits per second")
        self._line_baud_override = baudrate

    def line_baud(self) -> int | None:
        """Line speed in bps the servos hear now: the override, else the pty's termios speed (None if unknown)."""
        if self._line_baud_override is not None:
            return self._line_baud_override
        if self._slave < 0:
            return None
        try:
            speed = termios.tcgetattr(self._slave)[5]
        except termios.error:
            return None
        if speed == _BOTHER:
            return _termios2_speed(self._slave)
        return _TERMIOS_SPEEDS.get(speed)

    def listening(self) -> list[VirtualServo]:
        """Servos that can decode the line right now: matching baud rate and Protocol 2.0."""
        line = self.line_baud()
        with self.lock:
            return [
                s
                for s in self._servos
                if s.speaks_protocol_2 and (line is None or abs(line - s.baudrate) <= BAUD_TOLERANCE * s.baudrate)
            ]

    # --- settling -------------------------------------------------------------------------------------

    def _serving(self) -> bool:
        return self.running

    def _input_waiting(self) -> bool:
        try:
            return bool(select.select([self._master], [], [], 0)[0])
        except (OSError, ValueError):
            return False

    # --- serving --------------------------------------------------------------------------------------

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self._master, self._wake_r], [], [], _POLL_S)
            except (OSError, ValueError):
                return  # fds closed under us: we are shutting down
            if self._wake_r in ready or self._master not in ready:
                continue
            with self._idle:
                self._handling = True
            try:
                self._running.wait()
                self._serve_input()
            finally:
                with self._idle:
                    self._handling = False
                    self._idle.notify_all()

    def _serve_input(self) -> None:
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno == errno.EIO:  # no slave open right now; we hold one, so only transiently
                self._stop.wait(_POLL_S)
                return
            raise
        try:
            self._handle_bytes(data)
        except Exception as exc:  # keep serving; tests assert bus.errors is empty
            self.errors.append(exc)

    def _handle_bytes(self, data: bytes) -> None:
        frames = self._parser.feed(data)
        self.stats.noise_bytes = self._parser.noise_bytes
        self.stats.crc_mismatches = self._parser.crc_mismatches
        for frame in frames:
            self.stats.packets += 1
            servos = self.listening()
            with self.lock:
                replies = instructions.handle(frame, servos, crc_error_replies=self.crc_error_replies)
                fates = [r.servo.faults.next_reply_fate() for r in replies]
                delays = [r.servo.return_delay_s if self.return_delay else 0.0 for r in replies]
            self._transmit(replies, fates, delays)

    def _transmit(
        self,
        replies: list[instructions.Reply],
        fates: list[ReplyFate],
        return_delays: list[float],
    ) -> None:
        group = b""  # what a Fast Read group has put on the wire so far (its CRCs run over it)
        for reply, fate, return_delay in zip(replies, fates, return_delays, strict=True):
            if fate.drop:
                self.stats.replies_dropped += 1
                continue
            wait = fate.delay_s + return_delay
            if wait > 0 and self._stop.wait(wait):
                return
            data = reply.data
            if reply.fast_segment:
                crc = crc16(group + data)
                data += bytes([crc & 0xFF, crc >> 8])
            if fate.corrupt:
                data = data[:-2] + bytes([data[-2] ^ 0xFF, data[-1]])
                self.stats.replies_corrupted += 1
            if reply.fast_segment:
                group += data
            self.stats.replies_sent += 1  # counted first: a client may check the count once the bytes arrive
            if fate.split_s > 0:
                half = len(data) // 2
                self._write_all(data[:half])
                if self._stop.wait(fate.split_s):
                    return
                data = data[half:]
            self._write_all(data)

    def _write_all(self, data: bytes) -> None:
        view = memoryview(data)
        deadline = time.monotonic() + _WRITE_TIMEOUT_S
        while view and not self._stop.is_set():
            try:
                view = view[os.write(self._master, view) :]
            except BlockingIOError:
                # Nobody reads the pty: a real bus would not buffer either, so give up after a while.
                if time.monotonic() > deadline:
                    return
                select.select([], [self._master], [], _POLL_S)


def _termios2_speed(fd: int) -> int | None:
    try:
        raw = fcntl.ioctl(fd, _TCGETS2, bytes(44))
    except OSError:
        return None
    return int(struct.unpack_from("I", raw, 40)[0])


#: Serve virtual XM430-W350 servos on a pty for a ``with`` block: ``with open_virtual_bus(ids, baudrate) as bus``
#: yields the running bus (open ``bus.port`` with any Dynamixel client, reach the servos with ``bus.servo(id)``),
#: closed at the block's end. The bus is its own context manager; this name says what the block does.
open_virtual_bus = VirtualDynamixelBus


def serve_forever(bus: VirtualDynamixelBus, stop: threading.Event | None = None, poll_s: float = 0.2) -> None:
    """Block until ``stop`` is set or Ctrl-C while ``bus`` serves (starting it if needed); poll every ``poll_s`` s.

    Raises RuntimeError if the bus was closed or its serving thread dies. The bus is left open on return:
    closing it is the caller's job.
    """
    if not bus.running:
        if bus.port:
            raise RuntimeError(f"virtual Dynamixel bus on {bus.port} stopped serving (closed?)")
        bus.start()
    stop = stop if stop is not None else threading.Event()
    try:
        while not stop.wait(poll_s):
            if not bus.running:
                raise RuntimeError(f"virtual Dynamixel bus on {bus.port} stopped serving")
    except KeyboardInterrupt:
        return
