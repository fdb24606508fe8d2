"""A virtual GRBL 1.1 controller on a pseudo-terminal, for pyserial clients such as ``rig.instrument.links.grbl``.

The controller itself (``VirtualGrbl``: G-code, ``$`` commands, real-time bytes, motion, alarms, fault injection)
lives in ``simulator/grbl/controller.py`` and its core modules; this module puts it on a pty:

- ``open_virtual_grbl(...)``: context manager that serves it from a daemon thread and yields a ``GrblPtyServer``
  whose ``.port`` is the slave path to open with ``serial.Serial(port, 115200)`` and ``.controller`` the state;
- ``serve_grbl(...)``: the same, blocking in the calling thread until a stop event or Ctrl-C (``gonio sim grbl``).

Opening the port resets the controller and prints the banner, as an Arduino's auto-reset (DTR) does; nothing else
but 0x18 does. A pty has no DTR, so the server watches for opens of the slave (inotify ``IN_OPEN`` on Linux; a
hang-up, i.e. no client at all, where inotify is missing) and resets at the input flush pyserial performs on open,
after which the banner can no longer be flushed away. A flush mid-session (``reset_input_buffer()``,
``reset_output_buffer()``) drops bytes on the host only: the controller never notices. A client that opens the port
without flushing gets no banner until it sends 0x18. Output is dropped while no client has the port open.

Time comes from an injectable ``rig.instrument.clock.Clock``: share a ``ManualClock`` with the client in tests so
polling advances the simulation, or use a ``ScaledClock`` to run faster than real time for an external program.
On a clock that settles (``ManualClock.add_settler``) the server registers itself, so time cannot move on while
bytes a client wrote wait unhandled: every line and real-time byte acts at the simulated time it was sent,
however late the serving thread runs on a loaded host.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import fcntl
import logging
import os
import select
import struct
import termios
import threading
import tty
from collections.abc import Callable, Iterator, Mapping
from typing import TypeVar

from rig.instrument.clock import Clock
from simulator.grbl.controller import VirtualGrbl
from simulator.settling import Settling

log = logging.getLogger(__name__)

__all__ = ["GrblPtyServer", "VirtualGrbl", "open_virtual_grbl", "serve_grbl"]

_TIOCPKT_FLUSHREAD = 0x01
_MAX_PENDING_OUTPUT = 1 << 16  # bytes kept for a client that stopped reading; older output is dropped
_IN_OPEN = 0x20
_T = TypeVar("_T")


class _OpenWatch:
    """Sees opens of a device path through inotify; where inotify is missing (not Linux) it sees none."""

    def __init__(self, path: str) -> None:
        self._fd = -1
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            fd = libc.inotify_init1(os.O_NONBLOCK | os.O_CLOEXEC)
        except (OSError, AttributeError):
            return
        if fd < 0:
            return
        if libc.inotify_add_watch(fd, os.fsencode(path), _IN_OPEN) < 0:
            os.close(fd)
            return
        self._fd = fd

    def opened(self) -> bool:
        """Whether the path was opened since the last call (drains the events)."""
        seen = False
        while self._fd >= 0:
            try:
                data = os.read(self._fd, 4096)
            except BlockingIOError:
                break
            offset = 0
            while offset + 16 <= len(data):  # struct inotify_event: wd, mask, cookie, len, then len bytes of name
                _, mask, _, length = struct.unpack_from("iIII", data, offset)
                seen = seen or bool(mask & _IN_OPEN)
                offset += 16 + length
        return seen

    def close(self) -> None:
        """Stop watching; safe to call twice."""
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


class GrblPtyServer(Settling):
    """Serves one ``VirtualGrbl`` on a new pseudo-terminal; ``port`` is the path clients open."""

    def __init__(
        self, controller: VirtualGrbl, tick_s: float = 0.01, stop_event: threading.Event | None = None
    ) -> None:
        self.controller = controller
        self._tick_ms = max(int(tick_s * 1000), 1)
        master, slave = os.openpty()
        tty.setraw(slave)
        self.port = os.ttyname(slave)
        # Packet mode reports the slave's input flushes, which is how a pyserial open shows up on the master.
        fcntl.ioctl(master, termios.TIOCPKT, struct.pack("i", 1))
        os.set_blocking(master, False)
        # Closing our slave end lets the master see a hang-up whenever no client has the port open.
        os.close(slave)
        self._master = master
        self._stop = stop_event if stop_event is not None else threading.Event()
        self._thread: threading.Thread | None = None
        self._out = bytearray()
        self._hung_up = True
        self._opens = _OpenWatch(self.port)
        # An open not yet answered with a reset: the reset waits for the open's flush, which would drop the banner.
        self._open_pending = True
        self.opens = 0  # how many times a client opened the port (each one resets the controller)
        self.error: Exception | None = None  # what stopped the serving thread, if it crashed
        self._init_settling()
        self._settle_with(controller.clock)

    def start(self) -> None:
        """Serve from a daemon thread."""
        if self._thread is None:
            self._thread = threading.Thread(target=self.run, name=f"virtual-grbl {self.port}", daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """Stop serving (within one tick) and close the pty."""
        self._stop_serving()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        if self._master >= 0:
            os.close(self._master)
            self._master = -1
        self._opens.close()

    def run(self) -> None:
        """Serve until ``stop()``: feed client bytes to the controller, advance it, write its replies."""
        poller = select.poll()
        poller.register(self._master, select.POLLIN | select.POLLPRI)
        try:
            self._serve(poller)
        except Exception as exc:
            # A simulator bug must not look like a silent controller: record it and say so.
            self.error = exc
            log.exception("virtual GRBL on %s stopped", self.port)

    def _serve(self, poller: select.poll) -> None:
        while not self._stop.is_set():
            mask = select.POLLIN | select.POLLPRI | (select.POLLOUT if self._out else 0)
            poller.modify(self._master, mask)
            events = poller.poll(self._tick_ms)
            hung_up = any(ev & select.POLLHUP for _, ev in events)
            if hung_up:
                self._on_hangup()
                self._stop.wait(self._tick_ms / 1000.0)  # POLLHUP stays set: do not spin
                continue
            with self._idle:
                self._handling = True
            try:
                if any(ev & (select.POLLIN | select.POLLPRI) for _, ev in events):
                    self._running.wait()
                    self._read()
                self.controller.update()
                self._queue_output(self.controller.read_output())
                self._flush()
            finally:
                with self._idle:
                    self._handling = False
                    self._idle.notify_all()

    @property
    def hung_up(self) -> bool:
        """Whether no client has the port open, as far as the serving thread has seen."""
        return self._hung_up

    def _serving(self) -> bool:
        return self._alive()

    def _settle_poll_s(self) -> float:
        return self._tick_ms / 1000.0

    def _alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive() and not self._stop.is_set()

    def _input_waiting(self) -> bool:
        """Whether a client's bytes (or a port open) wait on the master; a hang-up is no input."""
        if self._master < 0:
            return False
        poller = select.poll()
        poller.register(self._master, select.POLLIN | select.POLLPRI)
        try:
            events = poller.poll(0)
        except OSError:
            return False
        return any(ev & (select.POLLIN | select.POLLPRI) and not ev & select.POLLHUP for _, ev in events)

    def _on_hangup(self) -> None:
        self._hung_up = True
        self._open_pending = True  # whoever comes next opens the port
        self._out.clear()
        self.controller.read_output()  # nobody is listening: GRBL's replies go nowhere

    def _on_master(self, io: Callable[[], _T]) -> _T | None:
        """``io()`` on the master; None if it would block, or if no client has the port (then a hang-up)."""
        try:
            return io()
        except BlockingIOError:
            return None
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            self._on_hangup()
            return None

    def _read(self) -> None:
        packet = self._on_master(lambda: os.read(self._master, 4096))
        if not packet:
            return
        opened = self._opens.opened()
        if packet[0] == 0:
            if len(packet) > 1:
                self._hung_up = False  # someone is writing, so someone can read the replies
                self._open_pending = False  # a client that talks without flushing first opened without a reset
                self.controller.receive(packet[1:])
        elif packet[0] & _TIOCPKT_FLUSHREAD and (opened or self._open_pending):
            # The flush of an open (a quick close-and-reopen may never show a hang-up, inotify sees it) resets.
            self._hung_up = False
            self._open_pending = False
            self.opens += 1
            self.controller.power_on()
        # Any other flush is the host dropping its own buffered bytes: GRBL never sees it.

    def _queue_output(self, data: bytes) -> None:
        if data and not self._hung_up:
            self._out += data
            if len(self._out) > _MAX_PENDING_OUTPUT:
                del self._out[: len(self._out) - _MAX_PENDING_OUTPUT]

    def _flush(self) -> None:
        while self._out:
            n = self._on_master(lambda: os.write(self._master, self._out))
            if n is None:
                return
            del self._out[:n]


@contextlib.contextmanager
def open_virtual_grbl(
    clock: Clock | None = None,
    axes: str = "XYZ",
    settings: Mapping[int, float] | None = None,
    start_position: Mapping[str, float] | None = None,
) -> Iterator[GrblPtyServer]:
    """Serve a virtual GRBL 1.1 on a pty for the ``with`` block; units per setting, start position in units."""
    server = GrblPtyServer(VirtualGrbl(clock, axes=axes, settings=settings, start_position=start_position))
    server.start()
    try:
        yield server
    finally:
        server.stop()


def serve_grbl(
    clock: Clock | None = None,
    axes: str = "XYZ",
    settings: Mapping[int, float] | None = None,
    start_position: Mapping[str, float] | None = None,
    stop: threading.Event | None = None,
    on_ready: Callable[[str], None] | None = None,
) -> None:
    """Serve a virtual GRBL on a pty in this thread until ``stop`` is set or Ctrl-C; ``on_ready(port)`` first."""
    controller = VirtualGrbl(clock, axes=axes, settings=settings, start_position=start_position)
    server = GrblPtyServer(controller, stop_event=stop)
    if on_ready is not None:
        on_ready(server.port)
    try:
        server.run()
    except KeyboardInterrupt:
        pass
    finally:
        server.stop()
