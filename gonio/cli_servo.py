"""``gonio servo scan|ping|status|check|move|set-id|set-baud``: commission Dynamixel servos on a real (or virtual) bus.

These talk to the bus directly, for commissioning a rig: which servos answer at which baud rate, what
state they are in, whether the port and its USB adapter are set up (permissions, latency timer), moving
one joint of a rig file to an angle (limits and tolerance from the file), and giving a servo its id and
baud rate. The last two write the servo's EEPROM, so they ask first (``--yes`` skips the question) and
check afterwards that the servo answers at its new id or rate. docs/hardware.md walks through all of it.
"""

from __future__ import annotations

import argparse
import grp
import os
import stat
import sys
import termios
from pathlib import Path

from gonio.cli_errors import EXIT_DECLINED, EXIT_HARDWARE, EXIT_OK, CliError
from gonio.cli_options import add_command
from model.spelling import did_you_mean
from rig.instrument.links.dynamixel_bus import SDK_BAUDRATES, CommunicationError, DynamixelBus
from rig.instrument.links.dynamixel_table import (
    BAUD_RATE_VALUES,
    MODELS,
    baud_rate_value,
    describe_hardware_error,
    table_for_model,
)
from rig.instrument.links.usb_serial import latency_advice, read_latency_timer

#: Rates both the servos (Baud Rate register) and dynamixel_sdk's port handler take.
SETTABLE_BAUDRATES = tuple(b for b in SDK_BAUDRATES if b in BAUD_RATE_VALUES)


def _sysfs() -> Path:
    # A container or a test points this at another tree; Linux keeps the adapters' settings in /sys.
    return Path(os.environ.get("GONIO_SYSFS", "/sys"))


def _warn_latency(port: str, configured_ms: float) -> None:
    try:
        advice = latency_advice(read_latency_timer(port, _sysfs()), configured_ms)
    except ValueError as exc:
        advice = f"warning: {exc}"
    if advice:
        print(advice, file=sys.stderr)


def _model(number: int) -> str:
    return MODELS[number][0] if number in MODELS else f"model {number}"


def _bus(args: argparse.Namespace) -> DynamixelBus:
    bus = DynamixelBus(args.port, args.baud, retries=args.retries, latency_timer_ms=args.latency_ms)
    _warn_latency(args.port, args.latency_ms)
    return bus


def _scan(args: argparse.Namespace) -> int:
    """find servos at one or more baud rates

    Example: gonio servo scan --port /dev/ttyUSB0 --bauds 57600 1000000
    """
    with _bus(args) as bus:
        found = bus.scan(baudrates=args.bauds, ids=range(args.max_id + 1) if args.ping_each else None)
    if not found:
        print(f"no servo answered on {args.port} at {', '.join(map(str, args.bauds))} baud "
              "(check power, wiring, baud rate; `gonio servo scan --bauds 57600 115200 1000000 2000000`)")  # fmt: skip
        return 3
    for f in found:
        print(f"id {f.servo_id:3d}  {f.baudrate:8d} baud  {_model(f.model_number)}  firmware {f.firmware}")
    return 0


def _ping(args: argparse.Namespace) -> int:
    """ping servos by id

    Example: gonio servo ping --port /dev/ttyUSB0 1 2 3 4
    """
    missing = []
    with _bus(args) as bus:
        for sid in args.ids:
            try:
                print(f"id {sid:3d}: found, {_model(bus.ping(sid))}", flush=True)
            except CommunicationError:
                missing.append(sid)
                print(f"id {sid:3d}: missing (no reply at {args.baud} baud)", flush=True)
    if not missing:
        return EXIT_OK
    print(f"{len(args.ids) - len(missing)} of {len(args.ids)} servos answered on {args.port}; missing: "
          f"{', '.join(map(str, missing))} (check power, the daisy chain, and each id and baud rate with "
          "`gonio servo scan`)", file=sys.stderr)  # fmt: skip
    return EXIT_HARDWARE


def _status(args: argparse.Namespace) -> int:
    """position, torque, motion and hardware errors

    Example: gonio servo status --port /dev/ttyUSB0 1 2 3 4
    """
    with _bus(args) as bus:
        for sid in args.ids:
            table = bus.table(sid)
            pos = bus.read(sid, table.present_position, 4, signed=True)
            torque = bus.read(sid, table.torque_enable, 1)
            moving = bus.read(sid, table.moving, 1)
            hw = bus.read(sid, table.hardware_error_status, 1)
            deg = pos / table.ticks_per_degree
            state = f"torque {'on' if torque else 'off'}, {'moving' if moving else 'still'}"
            health = describe_hardware_error(hw) if hw else "ok"
            print(f"id {sid:3d}: position {pos} ticks ({deg:.2f} deg of the shaft), {state}, hardware: {health}")
    return 0


def _move(args: argparse.Namespace) -> int:
    """move one joint of a rig file to an angle and wait until in position

    Example: gonio servo move --rig examples/rig_dynamixel.toml light 30
    """
    from rig.instrument.clock import SystemClock
    from rig.instrument.links.dynamixel import DynamixelLink
    from rig.run.config.files import load_rig

    rig = load_rig(args.rig)
    link_cfg = rig.file.link
    if link_cfg.kind != "dynamixel":
        raise CliError(f"{rig.path}: link.kind = {link_cfg.kind!r}: `gonio servo move` needs a dynamixel rig file")
    names = [a.name for a in rig.axes]
    if args.joint not in names:
        raise CliError(f"joint {args.joint!r}: {rig.path} has no such axis; its axes are {', '.join(names)}"
                       + did_you_mean(args.joint, names))  # fmt: skip
    port = args.port or link_cfg.port
    assert port is not None
    _warn_latency(port, link_cfg.latency_timer_ms)
    with DynamixelLink.open(port, rig.axes, baudrate=link_cfg.baudrate, retries=link_cfg.retries,
                            latency_timer_ms=link_cfg.latency_timer_ms, clock=SystemClock()) as link:  # fmt: skip
        link.move_to({args.joint: args.degrees})
        held = link.wait_in_position(timeout_s=link_cfg.move_timeout_s)
        print(", ".join(f"{k} {v:.2f} deg" for k, v in held.items()))
        if not args.keep_torque:
            return 0
        link.shutdown(keep_torque=True)
    return 0


def _confirm(question: str, yes: bool) -> bool:
    """Ask on the terminal (stderr, so stdout stays the result); anything but y/yes, or no answer, is no."""
    if yes:
        return True
    print(f"{question} [y/N] ", end="", file=sys.stderr, flush=True)
    try:
        answer = input()
    except EOFError:
        answer = ""
    if answer.strip().lower() in ("y", "yes"):
        return True
    print("nothing changed", file=sys.stderr)
    return False


def _find(bus: DynamixelBus, sid: int, args: argparse.Namespace) -> int:
    """The model number of servo ``sid``, or a hardware fault that says how to find it."""
    try:
        return bus.ping(sid)
    except CommunicationError:
        raise CommunicationError(f"no servo answers at id {sid} on {args.port} at {args.baud} baud; `gonio servo "
                                 "scan --ping-each` lists the ids and rates that answer") from None  # fmt: skip


def _torque_off_note(bus: DynamixelBus, ids: list[int], models: dict[int, int]) -> str:
    held = [sid for sid in ids if bus.read(sid, table_for_model(models[sid]).torque_enable, 1)]
    if not held:
        return ""
    return (f" Torque goes off first on {', '.join(map(str, held))} (its EEPROM is locked while torque is on): "
            "support what it holds.")  # fmt: skip


def _set_id(args: argparse.Namespace) -> int:
    """give one servo a new id (asks first; --yes skips the question)

    Pings the servo at ID, makes sure NEW_ID is free, asks, switches its torque off (the EEPROM is locked while torque
    is on), writes ID (7) and checks that it answers at NEW_ID and nothing at ID. Connect new servos one at a time: they
    all leave the factory as id 1.

    Example: gonio servo set-id --port /dev/ttyUSB0 --baud 57600 1 3
    """
    old, new = args.id, args.new_id
    if old == new:
        raise CliError(f"new id {new} is the servo's id already; nothing to change")
    with _bus(args) as bus:
        model = _find(bus, old, args)
        other = bus.try_ping(new)
        if other is not None:
            raise CliError(f"id {new} is taken on {args.port} (a {_model(other)} answers there): two servos with "
                           "one id garble each other's replies; choose a free id (`gonio servo scan` lists those "
                           "in use)")  # fmt: skip
        note = _torque_off_note(bus, [old], {old: model})
        question = f"Change servo {old} ({_model(model)} on {args.port} at {args.baud} baud) to id {new}?{note}"
        if not _confirm(question, args.yes):
            return EXIT_DECLINED
        table = table_for_model(model)
        bus.write(old, table.torque_enable, 1, 0)
        try:
            bus.write(old, table.id, 1, new)
        except CommunicationError:
            pass  # some firmware replies from the new id, which the SDK does not take for the answer; check below
        try:
            bus.ping(new)
        except CommunicationError:
            raise CommunicationError(f"servo {old} did not answer at id {new} after the change; "
                                     "`gonio servo scan --ping-each` shows where it is") from None  # fmt: skip
        if bus.try_ping(old) is not None:
            raise CommunicationError(f"a servo still answers at id {old} after the change: two servos had id {old}? "
                                     "Connect one servo at a time to give each its id")  # fmt: skip
    print(f"servo {old} is now id {new} ({_model(model)} answers at id {new} on {args.port}); "
          f"a rig file names it as [axes.<joint>] id = {new}")  # fmt: skip
    return EXIT_OK


def _set_baud(args: argparse.Namespace) -> int:
    """move servos to a new baud rate (asks first; --yes skips the question)

    Pings each servo at --baud, asks, switches torque off, writes Baud Rate (8), then talks at NEW_BAUD and checks that
    each answers there. Change every servo of a bus together: one bus has one rate.

    Example: gonio servo set-baud --port /dev/ttyUSB0 --baud 57600 1 2 3 4 1000000
    """
    new = args.new_baud
    if new not in SETTABLE_BAUDRATES:
        raise CliError(f"baud rate {new}: expected one of {', '.join(map(str, SETTABLE_BAUDRATES))} (rates both the "
                       "servos and dynamixel_sdk take)")  # fmt: skip
    if new == args.baud:
        raise CliError(f"new baud rate {new} is the rate the servos answer at already (--baud); nothing to change")
    ids = list(dict.fromkeys(args.ids))
    with _bus(args) as bus:
        models = {sid: _find(bus, sid, args) for sid in ids}
        note = _torque_off_note(bus, ids, models)
        which = ", ".join(f"{sid} ({_model(m)})" for sid, m in models.items())
        question = (f"Change servo{'s' if len(ids) > 1 else ''} {which} on {args.port} from {args.baud} to {new} baud? "
                    f"Servos not listed keep {args.baud} baud, and one bus needs one rate.{note}")  # fmt: skip
        if not _confirm(question, args.yes):
            return EXIT_DECLINED
        for sid in ids:
            table = table_for_model(models[sid])
            bus.write(sid, table.torque_enable, 1, 0)
            try:
                bus.write(sid, table.baud_rate, 1, baud_rate_value(new))
            except CommunicationError:
                pass  # the reply may come at the new rate already; the ping at that rate below decides
        bus.set_baudrate(new)
        silent = [sid for sid in ids if bus.try_ping(sid) is None and _retry_ping(bus, sid)]
    if silent:
        raise CommunicationError(f"servo{'s' if len(silent) > 1 else ''} {', '.join(map(str, silent))} did not answer "
                                 f"at {new} baud after the change; `gonio servo scan --bauds {args.baud} {new}` shows "
                                 "where each one is")  # fmt: skip
    print(f"servo{'s' if len(ids) > 1 else ''} {', '.join(map(str, ids))} now answer at {new} baud on {args.port}; "
          f"a rig file says [link] baudrate = {new}, and gonio servo commands --baud {new}")  # fmt: skip
    return EXIT_OK


def _retry_ping(bus: DynamixelBus, sid: int) -> bool:
    """True if ``sid`` stays silent also to a patient ping (a slow host), after a quick one found nothing."""
    try:
        bus.ping(sid)
    except CommunicationError:
        return True
    return False


def _check(args: argparse.Namespace) -> int:
    """is the port there and yours, is its USB latency timer right; optionally ping ids

    Checks the serial port (present, readable and writable by you, else which group to join), the USB adapter's latency
    timer in /sys/bus/usb-serial/devices/<tty>/latency_timer (above 1 ms every reply waits for it; above --latency-ms
    replies look lost) and, with ids, pings them. Exit 0 when all is well, 3 if not.

    Example: gonio servo check --port /dev/ttyUSB0 --latency-ms 1 1 2 3 4
    """
    problems = 0
    port = Path(args.port)
    if not port.exists():
        print(f"{port}: no such device (is the adapter plugged in? `ls /dev/serial/by-id/` lists USB serial ports)")
        return EXIT_HARDWARE
    real = Path(os.path.realpath(port))
    not_serial = serial_port_problem(real)
    if not_serial:
        print(f"{port}: {not_serial}; expected a serial port (a terminal device such as /dev/ttyUSB0; "
              "`ls /dev/serial/by-id/` lists USB serial ports)")  # fmt: skip
        return EXIT_HARDWARE
    print(f"{port}: {'-> ' + str(real) + ', a serial port' if real != port else 'present, a serial port'}")
    if not os.access(real, os.R_OK | os.W_OK):
        try:
            group = grp.getgrgid(real.stat().st_gid).gr_name
        except KeyError:
            group = str(real.stat().st_gid)
        print(f"{real}: you may not open it (owned by group {group}): `sudo usermod -aG {group} $USER`, then log "
              "in again (docs/hardware.md: serial-port permissions)")  # fmt: skip
        problems += 1
    else:
        print(f"{real}: readable and writable by you")
    try:
        timer = read_latency_timer(port, _sysfs())
    except ValueError as exc:
        print(f"warning: {exc}")
        timer = None
        problems += 1
    if timer is None:
        print(f"{real}: no USB latency timer (not an FTDI-style USB serial adapter, e.g. a CDC-ACM board or a "
              "pseudo-terminal): nothing to set")  # fmt: skip
    else:
        advice = latency_advice(timer, args.latency_ms)
        print(advice or f"{timer.tty}: USB latency timer {timer.value_ms} ms ({timer.path}): good")
        problems += advice is not None
    if args.ids and not problems:
        return _ping(args)
    return EXIT_HARDWARE if problems else EXIT_OK


def serial_port_problem(path: Path) -> str | None:
    """Why ``path`` is no serial port (what it is instead), or None for a terminal device termios accepts."""
    mode = path.stat().st_mode
    if not stat.S_ISCHR(mode):
        kinds = ((stat.S_ISDIR, "a directory"), (stat.S_ISREG, "a regular file"), (stat.S_ISBLK, "a block device"),
                 (stat.S_ISFIFO, "a named pipe"), (stat.S_ISSOCK, "a socket"))  # fmt: skip
        return f"is {next((name for test, name in kinds if test(mode)), 'not a device')}"
    try:
        # O_NONBLOCK: a modem port must not wait for carrier; O_NOCTTY: never become our controlling terminal.
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except PermissionError:
        return None  # may be a serial port; the permission check below says what to do
    except OSError as exc:
        return f"is a character device that cannot be opened ({exc.strerror})"
    try:
        termios.tcgetattr(fd)
    except termios.error:
        return "is a character device but not a terminal (termios refuses it: no baud rate, no line settings)"
    finally:
        os.close(fd)
    return None


def _common(p: argparse.ArgumentParser, port_required: bool = True) -> None:
    p.add_argument("--port", required=port_required, help="serial device, e.g. /dev/ttyUSB0")
    p.add_argument("--baud", type=int, choices=SDK_BAUDRATES, default=1_000_000, metavar="BAUD",
                   help="baud rate (default 1000000)")  # fmt: skip
    p.add_argument("--retries", type=int, default=2, help="retries of a lost reply (default 2)")
    p.add_argument("--latency-ms", type=float, default=16.0, help="USB adapter latency timer in ms (default 16)")


def _add_yes(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--yes", action="store_true", help="do not ask for confirmation")


def _servo_id(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= 252:
        raise argparse.ArgumentTypeError(f"servo id {text!r}: expected a whole number 0..252 (253+ are reserved)")
    return value


def add_servo_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``gonio servo`` and its actions."""
    servo = sub.add_parser("servo", help="scan, ping, check, inspect, move, set the id or baud of Dynamixel servos",
                           description="Commissioning tools for a Dynamixel Protocol 2.0 bus.")  # fmt: skip
    acts = servo.add_subparsers(dest="servo_action", required=True, metavar="ACTION")
    scan = add_command(acts, "scan", _scan)
    _common(scan)
    scan.add_argument("--bauds", type=int, nargs="+", choices=SDK_BAUDRATES, default=[57600, 1_000_000],
                      metavar="BAUD", help="baud rates to try (default 57600 1000000)")  # fmt: skip
    scan.add_argument("--ping-each", action="store_true", help="ping ids one by one instead of a broadcast ping")
    scan.add_argument("--max-id", type=int, default=20, help="highest id for --ping-each (default 20)")
    for name, func in (("ping", _ping), ("status", _status)):
        p = add_command(acts, name, func)
        _common(p)
        p.add_argument("ids", type=int, nargs="+", help="servo ids")
    check = add_command(acts, "check", _check)
    _common(check)
    check.add_argument("ids", type=int, nargs="*", help="servo ids to ping once the port looks right")
    set_id = add_command(acts, "set-id", _set_id)
    _common(set_id)
    set_id.add_argument("id", type=_servo_id, help="the servo's id now")
    set_id.add_argument("new_id", type=_servo_id, help="its new id (0..252)")
    _add_yes(set_id)
    set_baud = add_command(acts, "set-baud", _set_baud)
    _common(set_baud)
    set_baud.add_argument("ids", type=_servo_id, nargs="+", help="servo ids to change")
    set_baud.add_argument("new_baud", type=int, metavar="NEW_BAUD",
                          help=f"the new rate, one of {', '.join(map(str, SETTABLE_BAUDRATES))}")  # fmt: skip
    _add_yes(set_baud)
    move = add_command(acts, "move", _move)
    move.add_argument("--rig", required=True, help="rig file (TOML) with a dynamixel link")
    move.add_argument("--port", help="override the rig file's port")
    move.add_argument("--keep-torque", action="store_true", help="leave the servos holding afterwards")
    move.add_argument("joint", help="joint name (light, camera, tilt, roll, yaw)")
    move.add_argument("degrees", type=float, help="target angle of the joint in degrees")
