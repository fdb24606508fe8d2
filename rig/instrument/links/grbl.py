"""GRBL 1.1 motion link over pyserial: one ``G1`` line per pose, ``?`` polling, character-counting streaming.

Units. GRBL's unit (its "millimetre") is one *motor* degree here:

- ``$100+i`` = steps per motor degree = ``Axis.units_per_degree`` (so ``Axis.to_units`` gives steps);
- a G-code coordinate is ``Axis.to_units(joint_deg) / units_per_degree`` = ``direction * (joint_deg -
  zero_offset_deg) * gear_ratio`` motor degrees, and a reported position converts back with ``Axis.to_degrees``;
- ``$110+i`` = max rate in motor degrees/min = ``max_speed_deg_s * gear_ratio * 60``, ``$120+i`` = acceleration
  in motor degrees/s^2 = ``max_accel_deg_s2 * gear_ratio``; ``configure_axes()`` writes these three from the Axis
  objects (only values that differ, to spare the EEPROM).

Keeping steps out of the G-code means the controller quantises to steps itself and a change of microstepping is a
``$100`` change only. With homing (``$22=1``) GRBL's machine space is ``[-$130, 0]`` motor degrees with the switch at
0: set ``zero_offset_deg`` to the joint angle at the switch and ``direction`` so the joint's range maps to negative
coordinates, and the Axis limits inside the travel; moves use ``G53`` (machine coordinates) so work offsets left on
the controller cannot shift them, and after every reset the link re-reads the position and restates ``G21 G90``
(startup blocks could have changed them). Reports in inches (``$13=1``) and as ``WPos`` + ``WCO`` are converted.

Time. Serial replies are awaited in real time (``reply_timeout_s``, ``banner_timeout_s``), but every wait for the
*machine* (acknowledgement of a queued line, in-position, homing, a feed hold) polls with ``?`` every
``poll_interval_s`` of the injected clock, so a link and a virtual controller sharing a ``ManualClock`` advance the
simulation by polling. Streaming counts the bytes of lines sent and not yet answered (``ok``/``error:N``) and never
lets them exceed GRBL's 128-byte receive buffer (the size ``$I`` reports, when it does).

Alarms and resets. ``ALARM:N`` raises a ``GrblAlarm`` subclass with the code's meaning; after ALARM:1/2 GRBL waits
for ``reset()``; after a homing failure it resets itself. ``stop()`` sends a feed hold, waits until the axes have
stopped (Hold:0), then soft-resets to flush the queue: GRBL keeps its position and comes back Idle. If the hold does
not complete in ``stop_timeout_s`` the reset happens during motion: GRBL answers ALARM:3 and comes back in Alarm
with its position untrusted (``position_lost``); ``home()`` (or ``unlock()`` at your own risk) is then required.

A lossy line. A reply GRBL sent and the line lost (``GrblReplyLost``, see ``grbl_serial``) never stalls a run: a
move's is settled by ``wait_in_position`` (the axes reached the target, or the move times out and is re-issued),
a homing's by GRBL being Idle (a failed homing ends in Alarm), and the link's own commands (``G21 G90``, ``$$``,
``$X``) are sent again; reports lost ``status_retries + 1`` times in a row are a ``GrblTimeoutError`` naming it.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Mapping, Sequence
from types import TracebackType

from rig.instrument.axis import Axis
from rig.instrument.clock import Clock, SystemClock
from rig.instrument.links.base import LinkError, MoveTimeout, Pose
from rig.instrument.links.grbl_protocol import GrblError, GrblReplyLost, GrblStatus, GrblTimeoutError
from rig.instrument.links.grbl_serial import GrblSession, format_number

log = logging.getLogger(__name__)

AXIS_LETTERS = "XYZABC"
MAX_STEP_RATE_HZ = 30_000  # GRBL refuses $100/$110 pairs that step faster than this


class GrblLink:
    """``MotionLink`` for axes on one GRBL 1.1 controller (``Axis.address`` = axis letter), over pyserial.

    Opens ``port`` and handshakes on the banner at construction (soft-resetting first if ``reset_on_connect``);
    with ``configure`` it writes ``$100..$12x`` from the axes. With ``require_home`` (what a run uses) every
    move first makes sure the position is known: it homes after a connect, a reset or an alarm, and refuses
    to move a controller without homing ($22=0), whose position after a reset is wherever the axes stood.
    ``banner_timeout_s`` and ``reply_timeout_s`` are wall-clock seconds for serial answers;
    ``command_timeout_s``, ``home_timeout_s``, ``stop_timeout_s`` and ``poll_interval_s`` are seconds of
    ``clock``. The ``session`` attribute is the raw GRBL connection.
    """

    def __init__(
        self,
        port: str,
        axes: Sequence[Axis],
        *,
        clock: Clock | None = None,
        baudrate: int = 115200,
        reset_on_connect: bool = False,
        configure: bool = False,
        banner_timeout_s: float = 3.0,
        reply_timeout_s: float = 0.5,
        status_retries: int = 3,
        poll_interval_s: float = 0.1,
        command_timeout_s: float = 30.0,
        home_timeout_s: float = 120.0,
        stop_timeout_s: float = 10.0,
        require_home: bool = False,
    ) -> None:
        self.port = port
        self.require_home = require_home
        self._homed_generation = -1
        self.axes: dict[str, Axis] = {}
        for axis in axes:
            if not (isinstance(axis.address, str) and len(axis.address) == 1 and axis.address in AXIS_LETTERS):
                raise ValueError(f"axis {axis.name!r}: address {axis.address!r} is not a GRBL axis letter (XYZABC)")
            if axis.name in self.axes or any(a.address == axis.address for a in self.axes.values()):
                raise ValueError(f"axis {axis.name!r}: name or letter {axis.address!r} used twice")
            self.axes[axis.name] = axis
        if not self.axes:
            raise ValueError("GrblLink needs at least one axis")
        self._home_timeout_s = home_timeout_s
        self._stop_timeout_s = stop_timeout_s
        self._planned: dict[str, float] = {}
        self._ready_generation = -1
        self._targets: dict[str, float] = {}
        self._closed = False
        self._speed_caps: dict[str, float] = {}  # set_speed's caps (deg/s of joint); none: the axes' top speeds
        self.session = GrblSession(
            port,
            clock if clock is not None else SystemClock(),
            baudrate=baudrate,
            reset_on_connect=reset_on_connect,
            banner_timeout_s=banner_timeout_s,
            reply_timeout_s=reply_timeout_s,
            status_retries=status_retries,
            poll_interval_s=poll_interval_s,
            command_timeout_s=command_timeout_s,
        )
        if configure:
            try:
                self.configure_axes()
            except BaseException:
                self.session.close()
                raise

    @property
    def position_lost(self) -> bool:
        """Whether an alarm (hard limit, reset in motion, failed homing) left GRBL's position untrusted."""
        return self.session.position_lost

    @property
    def last_alarm(self) -> int | None:
        """The code of the last ``ALARM:N`` since the last successful homing or unlock."""
        return self.session.last_alarm

    # ---- MotionLink ----------------------------------------------------------------------------------------
    def move_to(self, pose: Pose) -> None:
        """Queue one ``G90 G53 G1`` move of the named axes to their targets in degrees (limits checked first)."""
        self.queue_moves([pose])
        try:
            self.session.wait_acknowledged()
        except GrblReplyLost as exc:
            # Only this move was in flight. Whether it ran is what wait_in_position checks (the targets, reached
            # within tolerance): a move GRBL refused, its error lost, times out there instead of passing.
            log.warning("%s; wait_in_position checks the axes reached the target", exc)

    def wait_in_position(self, timeout_s: float) -> dict[str, float]:
        """Poll until Idle with every commanded axis within tolerance; joint degrees, or ``MoveTimeout``."""
        self._check_open()
        clock = self.session.clock
        deadline = clock.now() + timeout_s
        while True:
            status = self.session.status()
            positions = self._positions_from(status)
            if status.state == "Alarm":
                raise self.session.alarm_state_error()
            if (
                status.state == "Idle"
                and not self.session.in_flight
                and all(self.axes[n].in_position(positions[n], t) for n, t in self._targets.items())
            ):
                return positions
            if clock.now() >= deadline:
                off = ", ".join(f"{n} {positions[n]:.3f} deg (target {t:.3f})" for n, t in self._targets.items())
                raise MoveTimeout(
                    f"GRBL on {self.port}: not in position after {timeout_s:g} s, state {status.state}: {off}",
                    positions,
                )
            clock.sleep(self.session.poll_interval_s)

    def read_positions(self) -> dict[str, float]:
        """Actual joint angles in degrees from one status report."""
        self._check_open()
        return self._positions_from(self.session.status())

    def stop(self) -> None:
        """Feed hold, wait for the axes to stop (Hold:0), then soft-reset to drop queued moves (see module doc)."""
        if self._closed:
            return
        self._targets.clear()
        session = self.session
        session.write_realtime(b"!")
        try:
            session.wait_for(lambda: not session.last_status.moving, self._stop_timeout_s, "feed hold", fresh=True)
        except GrblTimeoutError as exc:
            log.warning("%s; resetting during motion (GRBL will raise ALARM:3)", exc)
        session.reset()

    def shutdown(self, keep_torque: bool = False) -> None:
        """Stop any motion, leave the controller idle and close the port; safe to call twice.

        ``keep_torque`` is accepted for the MotionLink interface; whether idle steppers stay energised is
        the controller's own setting ($1, step idle delay), not something a closing link can change.
        """
        if self._closed:
            return
        try:
            status = self.session.status()
            if status.moving or status.state in ("Hold", "Door") or self.session.in_flight:
                self.stop()
        except (LinkError, OSError) as exc:
            log.warning("GRBL on %s: could not stop cleanly before closing: %s", self.port, exc)
        finally:
            self._closed = True
            self.session.close()

    # ---- more than MotionLink ------------------------------------------------------------------------------
    def queue_moves(self, poses: Iterable[Pose]) -> None:
        """Stream one move line per pose (a sweep) with character counting; every target is checked first."""
        self._check_open()
        poses = [dict(p) for p in poses]
        coords = [self._coords_for(p) for p in poses]  # AxisLimitError here, before anything is sent
        self._ensure_ready()
        planned = dict(self._planned)
        lines = []
        for c in coords:
            lines.append(self._move_line(c, planned))
            planned.update(c)
        for pose, c, line in zip(poses, coords, lines, strict=True):
            self.session.send(line)
            self.session.last_motion_line = line
            self._planned.update(c)
            self._targets.update({n: float(v) for n, v in pose.items()})

    def home(self, timeout_s: float | None = None) -> None:
        """Run the homing cycle ``$H`` (needs ``$22=1``); waits up to ``timeout_s`` clock seconds."""
        self._check_open()
        try:
            self.session.command("$H", timeout_s if timeout_s is not None else self._home_timeout_s)
        except GrblReplyLost as exc:
            # A homing cycle that fails ends in Alarm, never Idle: Idle after '$H' means it homed.
            log.warning("%s; GRBL is Idle after '$H', so it homed", exc)
        self.session.last_alarm = None
        self.session.position_lost = False
        self._targets.clear()

    def unlock(self) -> None:
        """Clear an alarm lock with ``$X`` (GRBL warns the position may be wrong; prefer ``home()``)."""
        self._check_open()
        self.session.command("$X", repeatable=True)
        self.session.last_alarm = None

    def reset(self) -> GrblStatus:
        """Soft reset (0x18) and re-handshake; the status after it (Alarm, position lost, if it was moving)."""
        self._check_open()
        self._targets.clear()
        return self.session.reset()

    def feed_hold(self) -> None:
        """Real-time ``!``: decelerate to a stop and hold (resume with ``resume()``)."""
        self.session.write_realtime(b"!")

    def resume(self) -> None:
        """Real-time ``~``: continue after a feed hold."""
        self.session.write_realtime(b"~")

    def status(self) -> GrblStatus:
        """One fresh status report."""
        self._check_open()
        return self.session.status()

    def configure_axes(self) -> dict[int, float]:
        """Write steps/motor degree, max rate (motor deg/min), accel (motor deg/s^2) from the axes where different."""
        self._check_open()
        current = self.session.settings()
        ordered: dict[int, float] = {}
        for axis in self.axes.values():
            i = AXIS_LETTERS.index(str(axis.address))
            steps = round(axis.units_per_degree, 3)
            rate = round(axis.max_speed_deg_s * axis.gear_ratio * 60.0, 3)
            accel = round(axis.max_accel_deg_s2 * axis.gear_ratio, 3)
            wanted = [(100 + i, steps), (110 + i, rate), (120 + i, accel)]
            if steps * current.get(110 + i, 0.0) > MAX_STEP_RATE_HZ * 60:
                wanted[0], wanted[1] = wanted[1], wanted[0]  # lower the rate before raising the steps
            for key, value in wanted:
                if not math.isclose(current.get(key, math.nan), value, abs_tol=5e-4):
                    ordered[key] = value
        self.session.write_settings(ordered)
        return ordered

    def __enter__(self) -> GrblLink:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.shutdown()

    # ---- units ---------------------------------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._closed or not self.session.is_open:
            raise LinkError(f"GRBL link on {self.port} is shut down")

    def _coords_for(self, pose: Pose) -> dict[str, float]:
        unknown = [n for n in pose if n not in self.axes]
        if unknown:
            raise LinkError(f"GRBL on {self.port}: unknown axis {unknown[0]!r}; axes are {sorted(self.axes)}")
        return {n: self.axes[n].to_units(float(deg)) / self.axes[n].units_per_degree for n, deg in pose.items()}

    def _move_line(self, coords: Mapping[str, float], planned: Mapping[str, float]) -> str:
        """``G90 G53 G1`` to ``coords`` (motor degrees) at the feed that lets the slowest axis run at its max speed."""
        speeds = {n: min(self.axes[n].max_speed_deg_s, self._speed_caps.get(n, math.inf)) * self.axes[n].gear_ratio
                  for n in coords}  # motor deg/s  # fmt: skip
        deltas = {n: coords[n] - planned.get(n, coords[n]) for n in coords}
        duration = max(abs(d) / speeds[n] for n, d in deltas.items())
        length = math.hypot(*deltas.values())
        feed = length / duration * 60.0 if duration > 0 else min(speeds.values()) * 60.0
        order = sorted(coords, key=lambda n: AXIS_LETTERS.index(str(self.axes[n].address)))
        words = " ".join(f"{self.axes[n].address}{format_number(coords[n])}" for n in order)
        return f"G90 G53 G1 {words} F{format_number(feed)}"

    def set_speed(self, speeds_deg_s: Mapping[str, float] | None) -> dict[str, float]:
        """Cap the named axes' speed (deg/s of joint) in the feed of the moves that follow (None: top speeds)."""
        self._speed_caps = {n: float(v) for n, v in (speeds_deg_s or {}).items()}
        return {n: min(v, self.axes[n].max_speed_deg_s) for n, v in self._speed_caps.items()}

    def stops_at(self, pose: Pose) -> dict[str, float]:
        """The joint angles (deg) the axes stop at for ``pose`` (deg): GRBL rounds each G-code target to whole steps."""
        coords = self._coords_for(pose)
        steps = {n: round(float(format_number(c)) * self.axes[n].units_per_degree) for n, c in coords.items()}
        return {n: self.axes[n].to_degrees(s) for n, s in steps.items()}

    def ensure_position_known(self) -> None:
        """Home unless GRBL's position is known since the last reset, alarm or reconnect; refuse without homing.

        Opening the port resets an Arduino-based GRBL, and every reset or alarm may leave its position
        reported from where it restarted (0 wherever the axes stand), so only homing makes it known again.
        """
        self._check_open()
        if self._homed_generation == self.session.generation and not self.position_lost:
            return
        if self.session.in_flight or self.session.last_status.moving:
            raise GrblError(f"GRBL on {self.port}: cannot home while moving")
        homing = self.session.settings().get(22, 0.0)
        if homing != 1.0:
            raise GrblError(
                f"GRBL on {self.port}: the axes' position is not known (after a connect, reset or alarm GRBL "
                "counts from wherever they stand) and homing is disabled ($22=0): fit homing switches and set "
                "$22=1, so a run can home before it measures; refusing to move"
            )
        log.info("GRBL on %s: homing, since the position is not known", self.port)
        self.home()
        self._homed_generation = self.session.generation

    def _ensure_ready(self) -> None:
        """After any reset or alarm: re-read the planned position and put GRBL back in G21 G90."""
        self.session.check_not_halted()
        if self.require_home:
            self.ensure_position_known()
        if self._ready_generation == self.session.generation:
            return
        self._planned = self._machine_coords(self.session.status())
        self.session.command("G21 G90", repeatable=True)  # millimetre mode (= motor degrees), absolute distances
        self._ready_generation = self.session.generation

    def _machine_coords(self, status: GrblStatus) -> dict[str, float]:
        mpos = status.machine_position(self.session.work_offset)
        if mpos is None:
            raise GrblError(f"GRBL on {self.port}: status report without a position")
        scale = 25.4 if self.session.report_inches else 1.0
        coords: dict[str, float] = {}
        for name, axis in self.axes.items():
            i = AXIS_LETTERS.index(str(axis.address))
            if i >= len(mpos):
                raise GrblError(f"GRBL on {self.port} reports {len(mpos)} axes; axis {name!r} is {axis.address}")
            coords[name] = mpos[i] * scale
        return coords

    def _positions_from(self, status: GrblStatus) -> dict[str, float]:
        coords = self._machine_coords(status)
        return {n: self.axes[n].to_degrees(c * self.axes[n].units_per_degree) for n, c in coords.items()}
