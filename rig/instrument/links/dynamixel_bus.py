"""One owner for a Dynamixel Protocol 2.0 bus: the real ``dynamixel_sdk`` behind a lock, with bounded retries.

The SDK's ``PortHandler.is_using`` is a flag, not a lock, so two threads that share a port interleave
packets. Every transaction here runs under one re-entrant lock, and communication failures (no status
packet, corrupt status packet) are retried a bounded number of times after flushing the input buffer.
Status errors reported by a servo (range, limit, access ...) are not retried: they are answered the same
way every time, so they become a ``ServoStatusError`` naming the servo, the instruction and the meaning.

Interrupts. A signal (Ctrl-C) that lands inside an SDK transaction leaves ``is_using`` set, and every later
transaction would answer "Port is in use!", the stop and the torque-off included. Since the lock makes this
object the port's only user, a set flag on entry can only be such a leftover: it is cleared, and the reply
that may still be arriving for the abandoned request is drained, before the next transaction is sent.

Slow hosts and lossy buses. The SDK's reply timeout (transmit time + 2 x latency timer + 2 ms) is right for a quiet
host, but a loaded one can deliver a reply later. A reply that does not come is retried with the window doubled each
time (up to ``MAX_TIMEOUT_SCALE``, or a quarter of the patience if wider), for at least ``reply_patience_s`` of the
clock's time, so a slow host waits longer instead of reporting a dead servo. The window kept for later transactions
grows only on a *late* reply (one that came after it: seen by the retry that caught it, or by the drain), never on a
missing one, and relaxes geometrically with every reply on time: a bus that loses replies keeps its short window, so
each loss costs one window and a retry rather than an ever longer wait. Losses are counted on their own; a bus that
loses more than ``LOSS_LIMIT`` of its replies over the last ``LOSS_WINDOW`` attempts is a ``LossyBusError`` naming
the rate. On a simulated clock (one with ``settle``, ``rig.instrument.clock.ManualClock``) a reply the virtual
device did not send is known to be lost once the device has settled: the wait is charged to the clock, not to the
wall. A port that fails at the OS level (EIO: cable or adapter pulled) is a ``LinkError``, never a bare OSError.

One file past 400 lines on purpose: the SDK's port handler, its lock, the interrupt recovery and the
blocking reads are one ownership of the port; splitting them would spread the busy-flag invariant.
"""

from __future__ import annotations

import math
import select
import termios
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TypeVar

import dynamixel_sdk as sdk
import serial

from rig.instrument.clock import Clock
from rig.instrument.links.base import LinkError
from rig.instrument.links.dynamixel_table import ALERT_BIT, ControlTable, describe_status_error, table_for_model

SDK_BAUDRATES = (
    9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600,
    1000000, 1152000, 2000000, 2500000, 3000000, 3500000, 4000000,
)  # fmt: skip
"""Baud rates ``dynamixel_sdk.PortHandler.setBaudRate`` accepts (anything else it refuses)."""

# Failures worth another try: a reply lost or garbled on the wire. Anything else repeats identically.
_RETRYABLE = (sdk.COMM_RX_TIMEOUT, sdk.COMM_RX_CORRUPT, sdk.COMM_RX_FAIL, sdk.COMM_TX_FAIL, sdk.COMM_PORT_BUSY)

T = TypeVar("T")


class CommunicationError(LinkError):
    """No valid status packet after all retries (wrong baud or id, wiring, or a servo that is gone)."""


class LossyBusError(CommunicationError):
    """The bus loses too large a share of its replies to be measured on (names the rate and the window)."""


class ServoStatusError(LinkError):
    """A servo answered with an error in its status packet (range, limit, access, ...)."""

    def __init__(self, message: str, servo_id: int, error: int) -> None:
        super().__init__(message)
        self.servo_id = servo_id
        self.error = error


@dataclass(frozen=True)
class Found:
    """A servo found by a scan: its baud rate, id, model number and firmware version."""

    baudrate: int
    servo_id: int
    model_number: int
    firmware: int


@dataclass(frozen=True)
class Reading:
    """Bytes read from one servo and the error byte of its status packet."""

    data: bytes
    error: int

    @property
    def alert(self) -> bool:
        """Whether the servo raised its Alert bit (Hardware Error Status is non-zero)."""
        return bool(self.error & ALERT_BIT)

    def value(self, offset: int, size: int, *, signed: bool = False) -> int:
        """Little-endian integer of ``size`` bytes at ``offset`` into the data."""
        return int.from_bytes(self.data[offset : offset + size], "little", signed=signed)


def check_baudrate(baudrate: int) -> int:
    """Return ``baudrate`` if the SDK accepts it; otherwise raise ValueError listing the accepted rates."""
    if baudrate not in SDK_BAUDRATES:
        accepted = ", ".join(str(b) for b in SDK_BAUDRATES)
        raise ValueError(f"baud rate {baudrate!r} is not one dynamixel_sdk accepts; expected one of {accepted}")
    return baudrate


class _PortHandler(sdk.PortHandler):
    """The SDK's port handler with the reply timeout's latency term set per port, and reads that block.

    The SDK waits ``tx time + 2 x LATENCY_TIMER + 2`` ms for a reply, with LATENCY_TIMER a module constant
    of 16 ms (the FTDI default). Adapters set to 1 ms deserve a shorter wait, and a loaded host talking to
    the virtual bus a longer one, without patching the SDK for every other user in the process.

    The SDK opens the port with a zero read timeout and spins in ``rxPacket`` calling ``readPort`` until
    the reply is complete: ~260 empty reads per transaction, holding the GIL against whatever produces the
    reply (the virtual bus's thread) and losing replies on a loaded host. Here ``readPort`` waits in
    select() for the first byte, for at most what is left of the packet timeout, so the SDK's loop runs
    once per chunk of the reply and its timeout logic is unchanged.
    """

    def __init__(self, port_name: str, latency_timer_ms: float, clock: Clock | None = None) -> None:
        super().__init__(port_name)
        self.latency_timer_ms = latency_timer_ms
        self.timeout_scale = 1.0  # the window's multiple of the SDK's, set by the bus per attempt
        self.base_timeout_ms = 0.0  # the packet in flight's window before scaling (ms)
        self.reply_ms = 0.0  # ms after the request when the latest reply bytes arrived (0: none yet)
        self._clock = clock
        self._settle: Callable[[], None] | None = getattr(clock, "settle", None)
        self._lost = False  # the device settled without replying: the window is over

    def _start(self, base_ms: float) -> None:
        self.packet_start_time = self.getCurrentTime()
        self.base_timeout_ms = base_ms
        self.packet_timeout = base_ms * self.timeout_scale
        self.reply_ms = 0.0
        self._lost = False

    def setPacketTimeout(self, packet_length: int) -> None:
        self._start(self.tx_time_per_byte * packet_length + self.latency_timer_ms * 2.0 + 2.0)

    def setPacketTimeoutMillis(self, msec: float) -> None:
        self._start(msec)

    def settle_device(self) -> bool:
        """On a simulated clock, wait until the virtual device has answered all it will; False on real time."""
        if self._settle is None:
            return False
        self._settle()
        return True

    def isPacketTimeout(self) -> bool:
        if self._lost:
            self.packet_timeout = 0
            return True
        return bool(super().isPacketTimeout())

    def readPort(self, length: int) -> bytes:
        """Up to ``length`` bytes, waiting for the first for at most the rest of the packet timeout."""
        if length <= 0 or self._lost:
            return b""  # the SDK asks for 0 bytes when a header it just parsed completes the packet
        fd = self.ser.fileno()
        if self._settle is not None and not _readable(fd, 0.0):
            # A virtual device on a simulated clock: once it has handled the request, a reply that is not on
            # the line was dropped and never comes. The window passes on the clock, not on the wall.
            self._settle()
            if not _readable(fd, 0.0):
                assert self._clock is not None
                self._clock.sleep(max(0.0, self.packet_timeout - self.getTimeSinceStart()) / 1000.0)
                self._lost = True
                return b""
        left_ms = self.packet_timeout - self.getTimeSinceStart()
        if left_ms <= 0:
            return b""  # what arrives after the window is a late reply: the SDK times out, the drain sees it
        _readable(fd, left_ms / 1000.0)
        data = bytes(self.ser.read(length))
        if data:
            self.reply_ms = self.getTimeSinceStart()
        return data


def _readable(fd: int, wait_s: float) -> bool:
    """Whether ``fd`` has bytes to read within ``wait_s`` seconds."""
    return bool(select.select([fd], [], [], wait_s)[0])


# What a port that fails at the OS level raises: termios.error (tcflush, tcsetattr) is not an OSError.
_PORT_FAILURES = (serial.SerialException, OSError, termios.error)
MAX_TIMEOUT_SCALE = 16.0
"""Widest reply window, as a multiple of the SDK's (about 2 s at a 60 ms latency timer, 0.6 s at 16 ms)."""
PATIENCE_WINDOW_SHARE = 0.25
"""The widest window is also at least this share of ``reply_patience_s``: with a short latency timer (1 ms on a
tuned adapter or a pty) 16 x the SDK's window is under 0.1 s, less than a loaded host may take to answer."""
#: Factor on the kept window per reply on time: a window widened for a slow spell narrows again within tens.
_RELAX = 0.9
#: Room a widened window keeps above the slowest recent reply (a multiple of that reply's latency).
_HEADROOM = 1.5
#: How rarely losses by chance may end a transaction on a lossy bus, and the most silences a servo is allowed.
_CHANCE = 1e-6
_MAX_SILENCES = 12
LOSS_WINDOW = 50
"""Attempts over which the share of lost or garbled replies is judged."""
LOSS_LIMIT = 0.5
"""Share of lost replies over ``LOSS_WINDOW`` attempts beyond which the bus is a hardware fault."""


def _open_hint(exc: BaseException) -> str:
    """What usually fixes a port that will not open (docs/hardware.md has the details)."""
    text = str(exc)
    if "Permission denied" in text or getattr(exc, "errno", None) == 13:
        return "; join the port's group (usually dialout: `sudo usermod -aG dialout $USER`, then log in again)"
    if "No such file" in text or getattr(exc, "errno", None) == 2:
        return "; is the adapter plugged in? `ls /dev/serial/by-id/` lists the USB serial ports"
    return ""


class DynamixelBus:
    """An open Dynamixel Protocol 2.0 port; all access is serialised through this object.

    ``latency_timer_ms`` is the USB adapter's latency timer (16 ms by default on FTDI chips, 1 ms once
    tuned); the reply timeout is twice that plus the packet's transmit time plus 2 ms, as in the SDK.
    ``clock`` is the link's (real time when None): the retries' patience is counted on it, and on a simulated
    clock a reply the virtual device dropped costs its window there instead of on the wall.
    """

    def __init__(
        self,
        port: str,
        baudrate: int = 1_000_000,
        *,
        retries: int = 3,
        latency_timer_ms: float = 16.0,
        reply_patience_s: float = 2.0,
        clock: Clock | None = None,
    ) -> None:
        check_baudrate(baudrate)
        if retries < 0:
            raise ValueError(f"retries = {retries!r}: expected a count >= 0")
        if not latency_timer_ms > 0:
            raise ValueError(f"latency_timer_ms = {latency_timer_ms!r}: expected a positive number of ms")
        if not reply_patience_s >= 0:
            raise ValueError(f"reply_patience_s = {reply_patience_s!r}: expected a number of seconds >= 0")
        self.port_name = port
        self.retries = retries
        self.reply_patience_s = reply_patience_s
        self._abandoned = False  # a transaction was left mid-way (a signal): drain before the next one
        self.window_scale = 1.0
        """The reply window kept between transactions, a multiple of the SDK's (grown by late replies only)."""
        self._losses: deque[bool] = deque(maxlen=LOSS_WINDOW)  # per attempt that expected a reply: was it lost
        self._failed_id = -1  # the servo whose reply a failed group read missed (-1: a unicast's one servo)
        self.replies_lost = 0
        self._lock = threading.RLock()
        self._port = _PortHandler(port, latency_timer_ms, clock)
        self._now: Callable[[], float] = clock.now if clock is not None else time.monotonic
        self._ph = sdk.PacketHandler(2.0)
        self._port.baudrate = baudrate
        try:
            opened = self._port.openPort()
        except _PORT_FAILURES as exc:
            raise LinkError(f"cannot open Dynamixel port {port!r}: {exc}{_open_hint(exc)}") from exc
        if not opened:
            raise LinkError(f"cannot open Dynamixel port {port!r} at {baudrate} baud")
        self.comm_retries_used = 0

    @property
    def baudrate(self) -> int:
        """Current line rate in baud."""
        return int(self._port.getBaudRate())

    def set_baudrate(self, baudrate: int) -> None:
        """Change the host's line rate (baud); the servos keep theirs."""
        check_baudrate(baudrate)
        with self._lock:
            try:
                ok = self._port.setBaudRate(baudrate)
            except _PORT_FAILURES as exc:
                raise LinkError(f"{self.port_name}: cannot set {baudrate} baud: {exc}") from exc
            if not ok:
                raise LinkError(f"{self.port_name}: cannot set {baudrate} baud")

    def close(self) -> None:
        """Close the port; safe to call twice, and quiet if the port already failed (a pulled cable)."""
        with self._lock:
            if self._port.is_open:
                self._port.is_open = False
                try:
                    self._port.ser.close()
                except _PORT_FAILURES:
                    pass  # nothing more can be done with a port that is gone

    def __enter__(self) -> DynamixelBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- transactions -------------------------------------------------------------------------------

    def _transact(
        self, what: str, call: Callable[[], tuple[T, int, int]], *, patient: bool = True, replies: bool = True
    ) -> tuple[T, int]:
        """Run one SDK transaction returning (value, comm result, error byte), retrying lost replies.

        ``patient``: a reply that does not come is retried, with a doubling window, for at least
        ``reply_patience_s`` (a servo known to be there, on a host that may be slow); scans pass False to give
        up quickly, and their silent ids count neither as losses nor as late replies. ``replies``: False for a
        packet no servo answers (SYNC_WRITE), which says nothing about the bus's replies.
        """
        with self._lock:
            if not self._port.is_open:
                raise LinkError(f"{self.port_name}: {what}: the port is closed")
            if self._abandoned or self._port.is_using:
                self._drain()
            started = self._now()  # the link's clock: on simulated time the lost windows are charged there
            attempt = 0
            scale = kept = self.window_scale
            # Failed attempts per servo that failed them (-1: the one servo of a unicast): a servo silent again and
            # again is gone or slow, while a lossy bus spreads its losses over the servos of a group read.
            silent: dict[int, int] = {}
            lost_here, heard = 0, False  # losses this transaction counted; whether any byte came back
            allowed = self._silences_allowed()
            widest = self._widest_scale()
            try:
                while True:
                    self._port.timeout_scale = scale
                    self._failed_id = -1
                    try:
                        value, result, error = call()
                    except _PORT_FAILURES as exc:
                        self._abandoned = True
                        raise LinkError(
                            f"{self.port_name}: {what}: the port failed ({exc}); is the cable or the adapter unplugged?"
                        ) from exc
                    except BaseException:
                        self._abandoned = True  # interrupted inside the SDK: is_using set, a reply maybe in flight
                        raise
                    if result == sdk.COMM_SUCCESS:
                        if replies and patient:
                            self._losses.append(False)
                            self._learn_from_reply()
                        return value, error
                    attempt += 1
                    silent[self._failed_id] = silent.get(self._failed_id, 0) + 1
                    # A late or corrupt reply may still be arriving; drop it so the retry starts clean. A reply cut
                    # off by the window (the SDK calls a partial one corrupt) whose rest arrives now is late too: a
                    # loaded host or an adapter's latency timer delivers a reply in pieces.
                    drained = self._drain()
                    late = drained > 0 and result in (sdk.COMM_RX_TIMEOUT, sdk.COMM_RX_CORRUPT)
                    if patient and replies:
                        self._count_failure(what, late)
                        lost_here += 0 if late else 1
                    heard = heard or drained > 0 or result != sdk.COMM_RX_TIMEOUT
                    worst = max(silent.values())
                    waited = self._now() - started
                    # Past the retries, only a window that can still widen is worth waiting on (a slow host).
                    slow = (patient and (result == sdk.COMM_RX_TIMEOUT or late) and waited < self.reply_patience_s
                            and scale < widest)  # fmt: skip
                    if result not in _RETRYABLE or (worst > allowed and not slow):
                        failure = CommunicationError(
                            f"{self.port_name} at {self.baudrate} baud: {what}: {self._ph.getTxRxResult(result)} "
                            f"(after {attempt} attempt{'s' if attempt > 1 else ''} in {waited:.2f} s; "
                            f"{self._loss_text()}; check baud rate, id and wiring)"
                        )
                        if not heard and set(silent) == {-1}:
                            # One servo that never made a sound is absent, not a sign of a lossy bus: left in the
                            # loss count, each absent id pinged would make the bus retry the next one longer.
                            self._forget_losses(lost_here)
                        raise failure
                    self.comm_retries_used += 1
                    if result == sdk.COMM_RX_TIMEOUT or late:
                        # This transaction only, and by how often the same servo was silent: a slow or dead servo
                        # gets ever longer windows, losses spread over a group's servos hardly any.
                        scale = min(max(self.window_scale, kept * 2.0 ** min(worst, 64)), widest)
            finally:
                # What the SDK is called with next (a broadcast ping too) is the kept window, not a retry's.
                self._port.timeout_scale = self.window_scale
        raise AssertionError("unreachable")

    def _silences_allowed(self) -> int:
        """Failed attempts one servo may have before it counts as gone: ``retries``, more on a bus known to lose.

        On a bus that lost the share r of its recent replies, n losses in a row happen by chance r^n of the time:
        enough attempts that chance explains a give-up less than once in a million, at most ``_MAX_SILENCES``.
        """
        r = self.loss_rate
        if not 0.0 < r < 1.0:
            return self.retries
        return max(self.retries, min(_MAX_SILENCES, math.ceil(math.log(_CHANCE) / math.log(r)) - 1))

    def _widest_scale(self) -> float:
        """The widest reply window as a multiple of the SDK's nominal one (2 x latency timer + 2 ms)."""
        nominal_ms = 2.0 * self._port.latency_timer_ms + 2.0
        return max(MAX_TIMEOUT_SCALE, PATIENCE_WINDOW_SHARE * self.reply_patience_s * 1000.0 / nominal_ms)

    def _learn_from_reply(self) -> None:
        """Widen the kept window after a reply later than it, else narrow it geometrically towards the SDK's."""
        base = self._port.base_timeout_ms
        ratio = self._port.reply_ms / base if base > 0 else 0.0
        if ratio > self.window_scale:  # it came only because this transaction's retry waited longer
            self.window_scale = min(self._widest_scale(), max(2.0 * self.window_scale, _HEADROOM * ratio))
        else:
            relaxed = max(_RELAX * self.window_scale, _HEADROOM * ratio, 1.0)
            self.window_scale = min(self.window_scale, relaxed)

    def _count_failure(self, what: str, late: bool) -> None:
        """Count one failed attempt: a late reply widens the kept window, a lost one counts towards the loss rate."""
        if late:
            self.window_scale = min(self._widest_scale(), 2.0 * self.window_scale)
            self._losses.append(False)
            return
        self._losses.append(True)
        self.replies_lost += 1
        if len(self._losses) == LOSS_WINDOW and self.loss_rate > LOSS_LIMIT:
            raise LossyBusError(
                f"{self.port_name} at {self.baudrate} baud: {what}: {self._loss_text()}, more than {LOSS_LIMIT:.0%}: "
                "the bus is too lossy to measure on; check the cable, its termination and the baud rate"
            )

    def _forget_losses(self, n: int) -> None:
        """Take the last ``n`` counted losses back (they were this transaction's: the lock is held)."""
        for _ in range(min(n, len(self._losses))):
            self._losses.pop()
        self.replies_lost -= n

    @property
    def loss_rate(self) -> float:
        """Share of the last ``LOSS_WINDOW`` attempts whose reply was lost or garbled (0 before any)."""
        return sum(self._losses) / len(self._losses) if self._losses else 0.0

    def _loss_text(self) -> str:
        return f"{self.loss_rate:.0%} of the last {len(self._losses)} replies lost or garbled"

    def _drain(self) -> int:
        """Forget an abandoned transaction: clear the SDK's busy flag and discard replies until the line is quiet.

        Returns the number of bytes discarded (a reply that came after its window, or noise).
        """
        self._port.is_using = False
        self._abandoned = False
        quiet_s = (2.0 * self._port.latency_timer_ms + 2.0) / 1000.0
        discarded = 0
        try:
            if self._port.settle_device():  # a virtual device on simulated time: all it sends is on the line now
                discarded = self._port.getBytesAvailable()
                self._port.clearPort()
                return discarded
            discarded = self._port.getBytesAvailable()
            self._port.clearPort()
            # A line that never goes quiet is noise: stop after a while, the retry's CRC check handles it.
            limit = time.monotonic() + 20 * quiet_s
            fd = self._port.ser.fileno()
            while True:
                left = min(quiet_s, limit - time.monotonic())
                if left <= 0 or not select.select([fd], [], [], left)[0]:
                    return discarded  # quiet for quiet_s (or noisy for too long)
                discarded += len(self._port.ser.read(max(self._port.getBytesAvailable(), 1)))
        except _PORT_FAILURES as exc:
            self._abandoned = True
            where = self.port_name
            raise LinkError(f"{where}: the port failed ({exc}); is the cable or the adapter unplugged?") from exc

    def _check_status(self, servo_id: int, what: str, error: int) -> None:
        if error & ~ALERT_BIT:
            raise ServoStatusError(f"servo {servo_id}: {what}: {describe_status_error(error)}", servo_id, error)

    def ping(self, servo_id: int) -> int:
        """Model number of servo ``servo_id``; raises CommunicationError if it does not answer."""
        model, _ = self._transact(f"ping servo {servo_id}", lambda: self._ph.ping(self._port, servo_id))
        return int(model)

    def try_ping(self, servo_id: int) -> int | None:
        """Model number of servo ``servo_id``, or None if nothing answers (no patience: scans ping many ids)."""
        try:
            model, _ = self._transact(f"ping servo {servo_id}", lambda: self._ph.ping(self._port, servo_id),
                                      patient=False)  # fmt: skip
        except CommunicationError:
            return None
        return int(model)

    def broadcast_ping(self) -> dict[int, tuple[int, int]]:
        """Every servo answering a broadcast ping at the current baud: id -> (model number, firmware)."""
        with self._lock:
            if self._abandoned or self._port.is_using:
                self._drain()
            try:
                found, result = self._ph.broadcastPing(self._port)
            except _PORT_FAILURES as exc:
                raise LinkError(f"{self.port_name}: broadcast ping: the port failed ({exc})") from exc
            except BaseException:
                self._abandoned = True
                raise
        if result not in (sdk.COMM_SUCCESS, sdk.COMM_RX_TIMEOUT):
            raise CommunicationError(f"{self.port_name}: broadcast ping: {self._ph.getTxRxResult(result)}")
        return {int(i): (int(v[0]), int(v[1])) for i, v in found.items()}

    def scan(self, baudrates: Iterable[int] = (57600, 1_000_000), ids: Iterable[int] | None = None) -> list[Found]:
        """Find servos at each baud rate (by broadcast ping, or by pinging ``ids`` one by one)."""
        original = self.baudrate
        found: list[Found] = []
        try:
            for baud in baudrates:
                self.set_baudrate(baud)
                if ids is None:
                    for sid, (model, fw) in sorted(self.broadcast_ping().items()):
                        found.append(Found(baud, sid, model, fw))
                    continue
                for sid in ids:
                    number = self.try_ping(sid)
                    if number is not None:
                        found.append(Found(baud, sid, number, self.read(sid, 6, 1)))
        finally:
            self.set_baudrate(original)
        return found

    def read(self, servo_id: int, address: int, size: int, *, signed: bool = False) -> int:
        """Read a ``size``-byte register (little-endian) at ``address`` of one servo."""
        readers = {1: self._ph.read1ByteTxRx, 2: self._ph.read2ByteTxRx, 4: self._ph.read4ByteTxRx}
        what = f"read {size} bytes at address {address} of servo {servo_id}"
        value, error = self._transact(what, lambda: readers[size](self._port, servo_id, address))
        self._check_status(servo_id, what, error)
        raw = int(value)
        if signed and raw >= 1 << (8 * size - 1):
            raw -= 1 << (8 * size)
        return raw

    def write(self, servo_id: int, address: int, size: int, value: int) -> int:
        """Write a ``size``-byte register of one servo; returns the status error byte (Alert bit only)."""
        writers = {1: self._ph.write1ByteTxRx, 2: self._ph.write2ByteTxRx, 4: self._ph.write4ByteTxRx}
        raw = value & ((1 << (8 * size)) - 1)  # two's complement for signed goals
        what = f"write {value} ({size} bytes) at address {address} of servo {servo_id}"
        _, error = self._transact(what, lambda: (None, *writers[size](self._port, servo_id, address, raw)))
        self._check_status(servo_id, what, error)
        return error

    def reboot(self, servo_id: int) -> None:
        """Reboot one servo (clears a hardware-error shutdown; torque comes back off)."""
        what = f"reboot servo {servo_id}"
        _, error = self._transact(what, lambda: (None, *self._ph.reboot(self._port, servo_id)))
        self._check_status(servo_id, what, error)

    def sync_write(self, address: int, size: int, values: Mapping[int, int]) -> None:
        """Write one register on several servos in one SYNC_WRITE packet (no replies)."""
        group = sdk.GroupSyncWrite(self._port, self._ph, address, size)
        for sid, value in values.items():
            raw = (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")
            group.addParam(sid, list(raw))
        what = f"sync write of address {address} to servos {sorted(values)}"
        self._transact(what, lambda: (None, group.txPacket(), 0), replies=False)

    def _group_read(self, what: str, group: object, sizes: Mapping[int, int]) -> dict[int, Reading]:
        """Send a sync or bulk read ``group`` and collect each servo's status packet with its error byte."""

        def call() -> tuple[dict[int, Reading], int, int]:
            # The SDK groups' rxPacket drops the error byte, and with it the Alert bit: read replies ourselves.
            result = group.txPacket()  # type: ignore[attr-defined]
            out: dict[int, Reading] = {}
            if result != sdk.COMM_SUCCESS:
                return out, result, 0
            for sid, size in sizes.items():
                data, result, error = self._ph.readRx(self._port, sid, size)
                if result != sdk.COMM_SUCCESS:
                    self._failed_id = sid  # whose reply was missing: the retries judge each servo on its own
                    return out, result, 0
                out[sid] = Reading(bytes(data), int(error))
            return out, sdk.COMM_SUCCESS, 0

        readings, _ = self._transact(what, call)
        return readings

    def sync_read(self, address: int, size: int, ids: Sequence[int]) -> dict[int, Reading]:
        """Read one block from several servos with one SYNC_READ; keeps each servo's error byte."""
        group = sdk.GroupSyncRead(self._port, self._ph, address, size)
        for sid in ids:
            group.addParam(sid)
        what = f"sync read of {size} bytes at {address} from servos {list(ids)}"
        return self._group_read(what, group, dict.fromkeys(ids, size))

    def bulk_read(self, requests: Mapping[int, tuple[int, int]]) -> dict[int, Reading]:
        """Read a different block (address, size) from each servo with one BULK_READ."""
        group = sdk.GroupBulkRead(self._port, self._ph)
        for sid, (address, size) in requests.items():
            group.addParam(sid, address, size)
        sizes = {sid: size for sid, (_, size) in requests.items()}
        return self._group_read(f"bulk read from servos {sorted(requests)}", group, sizes)

    def table(self, servo_id: int) -> ControlTable:
        """The control table layout of servo ``servo_id``, from its model number."""
        return table_for_model(self.ping(servo_id), where=f"servo {servo_id} on {self.port_name}")
