"""``gonio servo scan|ping|status|move``: look at and move Dynamixel servos on a real (or virtual) bus.

These talk to the bus directly, for commissioning a rig: which servos answer at which baud rate, what
state they are in, and moving one joint of a rig file to an angle (limits and tolerance from the file).
"""

from __future__ import annotations

import argparse

from rig.instrument.links.dynamixel_bus import SDK_BAUDRATES, DynamixelBus
from rig.instrument.links.dynamixel_table import MODELS, describe_hardware_error


def _model(number: int) -> str:
    return MODELS[number][0] if number in MODELS else f"model {number}"


def _bus(args: argparse.Namespace) -> DynamixelBus:
    return DynamixelBus(args.port, args.baud, retries=args.retries, latency_timer_ms=args.latency_ms)


def _scan(args: argparse.Namespace) -> int:
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
    with _bus(args) as bus:
        for sid in args.ids:
            print(f"id {sid:3d}: {_model(bus.ping(sid))}")
    return 0


def _status(args: argparse.Namespace) -> int:
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
    from rig.instrument.clock import SystemClock
    from rig.instrument.links.dynamixel import DynamixelLink
    from rig.run.config import load_rig

    rig = load_rig(args.rig)
    link_cfg = rig.file.link
    if link_cfg.kind != "dynamixel":
        raise ValueError(f"{rig.path}: link.kind = {link_cfg.kind!r}: `gonio servo move` needs a dynamixel rig file")
    port = args.port or link_cfg.port
    assert port is not None
    with DynamixelLink.open(port, rig.axes, baudrate=link_cfg.baudrate, retries=link_cfg.retries,
                            latency_timer_ms=link_cfg.latency_timer_ms, clock=SystemClock()) as link:  # fmt: skip
        link.move_to({args.joint: args.degrees})
        held = link.wait_in_position(timeout_s=link_cfg.move_timeout_s)
        print(", ".join(f"{k} {v:.2f} deg" for k, v in held.items()))
        if not args.keep_torque:
            return 0
        link.shutdown(keep_torque=True)
    return 0


def _common(p: argparse.ArgumentParser, port_required: bool = True) -> None:
    p.add_argument("--port", required=port_required, help="serial device, e.g. /dev/ttyUSB0")
    p.add_argument("--baud", type=int, choices=SDK_BAUDRATES, default=1_000_000, metavar="BAUD",
                   help="baud rate (default 1000000)")  # fmt: skip
    p.add_argument("--retries", type=int, default=2, help="retries of a lost reply (default 2)")
    p.add_argument("--latency-ms", type=float, default=16.0, help="USB adapter latency timer in ms (default 16)")


def add_servo_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``gonio servo`` and its actions."""
    servo = sub.add_parser("servo", help="scan, ping, inspect or move Dynamixel servos on a bus",
                           description="Commissioning tools for a Dynamixel Protocol 2.0 bus.")  # fmt: skip
    acts = servo.add_subparsers(dest="servo_action", required=True, metavar="ACTION")
    scan = acts.add_parser("scan", help="find servos at one or more baud rates",
                           epilog="Example: gonio servo scan --port /dev/ttyUSB0 --bauds 57600 1000000")  # fmt: skip
    _common(scan)
    scan.add_argument("--bauds", type=int, nargs="+", choices=SDK_BAUDRATES, default=[57600, 1_000_000],
                      metavar="BAUD", help="baud rates to try (default 57600 1000000)")  # fmt: skip
    scan.add_argument("--ping-each", action="store_true", help="ping ids one by one instead of a broadcast ping")
    scan.add_argument("--max-id", type=int, default=20, help="highest id for --ping-each (default 20)")
    scan.set_defaults(func=_scan)
    for name, helptext, func in (("ping", "ping servos by id", _ping),
                                 ("status", "position, torque, motion and hardware errors", _status)):  # fmt: skip
        p = acts.add_parser(name, help=helptext, epilog=f"Example: gonio servo {name} --port /dev/ttyUSB0 1 2 3 4")
        _common(p)
        p.add_argument("ids", type=int, nargs="+", help="servo ids")
        p.set_defaults(func=func)
    move = acts.add_parser("move", help="move one joint of a rig file to an angle and wait until in position",
                           epilog="Example: gonio servo move --rig examples/rig_dynamixel.toml light 30")  # fmt: skip
    move.add_argument("--rig", required=True, help="rig file (TOML) with a dynamixel link")
    move.add_argument("--port", help="override the rig file's port")
    move.add_argument("--keep-torque", action="store_true", help="leave the servos holding afterwards")
    move.add_argument("joint", help="joint name (light, camera, tilt, roll, yaw)")
    move.add_argument("degrees", type=float, help="target angle of the joint in degrees")
    move.set_defaults(func=_move)
