"""``gonio sim servos|grbl|rig``: serve simulated hardware on a pty until Ctrl-C; ``gonio sim merl``: a MERL file.

The simulator package is imported only when one of these commands runs (nothing in rig imports it at
module level), so the controller never depends on the stand-in hardware.
"""

from __future__ import annotations

import argparse
import math
import sys

from rig.instrument.clock import ScaledClock
from rig.instrument.links.dynamixel_bus import SDK_BAUDRATES


def _ids(text: str) -> tuple[int, ...]:
    """Parse ``1,2,3`` or ``1-4`` into servo ids 0..252."""
    ids: list[int] = []
    for part in text.split(","):
        part = part.strip()
        try:
            if "-" in part:
                lo, hi = (int(p) for p in part.split("-", 1))
                ids.extend(range(lo, hi + 1))
            else:
                ids.append(int(part))
        except ValueError:
            raise argparse.ArgumentTypeError(f"servo ids {text!r}: expected e.g. 1,2,3 or 1-4") from None
    bad = [i for i in ids if not 0 <= i <= 252]
    if bad or not ids or len(set(ids)) != len(ids):
        raise argparse.ArgumentTypeError(f"servo ids {text!r}: expected distinct ids in 0..252")
    return tuple(ids)


def _speed(text: str) -> float:
    """Parse a positive time factor."""
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not value > 0:
        raise argparse.ArgumentTypeError(f"speed {text!r}: expected a positive factor (1 = real time)")
    return value


def _grbl_axes(text: str) -> str:
    """Parse --axes: a prefix of GRBL's axis letters XYZABC (the virtual controller has its axes in that order)."""
    letters = "XYZABC"  # simulator.grbl.settings.AXIS_LETTERS, spelt out: the simulator loads only when a command runs
    if not text or letters[: len(text)] != text:
        raise argparse.ArgumentTypeError(
            f"--axes {text!r}: expected the first 1 to {len(letters)} of GRBL's axis letters {letters} in that "
            f"order, e.g. X, XY, XYZ or XYZA"
        )
    return text


def capture_seconds(text: str) -> float:
    """The exposure of a ``capture SECONDS`` line typed to ``gonio sim rig``; ValueError says what is expected."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"'capture {text}': expected 'capture SECONDS' with SECONDS a positive number")
    return value


def _announce(line: str) -> None:
    print(line, flush=True)


def _servos(args: argparse.Namespace) -> int:
    from simulator.dynamixel import open_virtual_bus
    from simulator.dynamixel.bus import serve_forever

    clock = ScaledClock(args.speed)
    with open_virtual_bus(ids=args.ids, baudrate=args.baud, clock=clock, return_delay=args.return_delay) as bus:
        _announce(bus.port)
        print(
            f"virtual Dynamixel bus: XM430-W350 ids {','.join(map(str, args.ids))} at {args.baud} baud, "
            f"time x{args.speed:g}; Ctrl-C stops",
            file=sys.stderr,
            flush=True,
        )
        serve_forever(bus)
    return 0


def _grbl(args: argparse.Namespace) -> int:
    from simulator.grbl.server import serve_grbl

    def ready(port: str) -> None:
        _announce(port)
        print(
            f"virtual GRBL 1.1h: axes {args.axes}, 115200 baud, time x{args.speed:g}; Ctrl-C stops",
            file=sys.stderr,
            flush=True,
        )

    serve_grbl(ScaledClock(args.speed), axes=args.axes, on_ready=ready)
    return 0


def _rig(args: argparse.Namespace) -> int:
    from dataclasses import replace
    from pathlib import Path

    from rig.run.config import load_rig, rig_config
    from rig.run.config_schema import RigFile
    from simulator.camera.simulated import SimulatedCamera
    from simulator.from_config import rig_from, spec_from

    cfg = load_rig(args.rig) if args.rig else rig_config(RigFile(), "<built-in simulated rig>")
    spec = replace(spec_from(cfg), time_scale=args.speed)
    frames = Path(args.frames)
    with rig_from(cfg, spec=spec) as sim:
        # A RAW twin of the rig's camera: same scene and clock, frames written as DNG for any RAW reader.
        raw = SimulatedCamera(
            lambda: sim.radiance_now(full_frame=True), noise=spec.noise, optics=spec.optics, kind="raw",
            clock=sim.clock, seed=spec.seed, dng_dir=frames, camera_id="gonio simulated camera (RAW)",
        )  # fmt: skip
        _announce(sim.port)
        ids = ",".join(str(a.address) for a in sim.axes)
        what = (f"GRBL 1.1h axes {ids}" if cfg.file.simulation.link == "grbl"
                else f"servos {ids}") + f" ({', '.join(a.name for a in sim.axes)})"  # fmt: skip
        line = "115200 baud (home with $H first)" if cfg.file.simulation.link == "grbl" else f"{spec.baudrate} baud"
        print(f"simulated rig {cfg.file.name!r}: {what} at {line}, time x{args.speed:g}; type 'capture SECONDS' "
              f"for a DNG frame in {frames}, Ctrl-D or Ctrl-C stops", file=sys.stderr, flush=True)  # fmt: skip
        for line in sys.stdin:
            words = line.split()
            if len(words) == 2 and words[0] == "capture":
                try:
                    raw.set_exposure(capture_seconds(words[1]))
                    raw.capture()
                except ValueError as exc:
                    print(f"error: {exc}", flush=True)
                    continue
                print(sorted(frames.glob("frame_*.dng"))[-1], flush=True)
            elif words:
                print(f"error: {line.strip()!r}: expected 'capture SECONDS'", flush=True)
    return 0


#: The material of ``gonio sim merl`` without --rig: a glossy paint (a diffuse base under a GGX dielectric coat).
PAINT = {"model": "CookTorrance", "alpha": 0.2, "fresnel": "dielectric", "eta": 1.5, "rho_d": [0.2, 0.3, 0.4]}


def _merl(args: argparse.Namespace) -> int:
    from pathlib import Path

    from model.merl import MerlTable, write_merl
    from rig.run.config import load_rig, material_from, parse, rig_config
    from rig.run.config_schema import RigFile

    cfg = load_rig(args.rig) if args.rig else rig_config(parse({"simulation": {"material": PAINT}}, RigFile))
    material = material_from(cfg)
    out = Path(args.out)
    print(f"tabulating {material!r} at the 1,458,000 MERL bins", file=sys.stderr, flush=True)
    write_merl(MerlTable.from_model(material), out)
    print(out)
    return 0


def add_sim_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``gonio sim servos``, ``grbl``, ``rig`` and ``merl``."""
    sim = sub.add_parser(
        "sim",
        help="serve simulated hardware on a pseudo-terminal",
        description="Serve a virtual Dynamixel bus or GRBL controller on a pseudo-terminal. The first line on "
        "stdout is the device path; point any client at it (gonio, dynamixel_sdk, ROBOTIS tools, a G-code sender).",
    )
    kinds = sim.add_subparsers(dest="sim_kind", required=True, metavar="DEVICE")
    servos = kinds.add_parser(
        "servos",
        help="virtual Dynamixel Protocol 2.0 bus of XM430-W350 servos",
        epilog="Example: gonio sim servos --ids 1-4 --baud 1000000",
    )
    servos.add_argument("--ids", type=_ids, default=(1, 2, 3, 4), help="servo ids, e.g. 1,2,3 or 1-4 (default 1-4)")
    servos.add_argument(
        "--baud",
        type=int,
        choices=SDK_BAUDRATES,
        default=1_000_000,
        metavar="BAUD",
        help="servos' baud rate, one dynamixel_sdk accepts (default 1000000)",
    )
    servos.add_argument("--speed", type=_speed, default=1.0, help="simulated time per real second (default 1)")
    servos.add_argument(
        "--return-delay", action="store_true", help="honour each servo's Return Delay Time in real time"
    )
    servos.set_defaults(func=_servos)
    grbl = kinds.add_parser(
        "grbl", help="virtual GRBL 1.1 motion controller", epilog="Example: gonio sim grbl --axes XYZ"
    )
    grbl.add_argument("--axes", type=_grbl_axes, default="XYZ",
                      help="axis letters, the first of XYZABC in order (default XYZ)")  # fmt: skip
    grbl.add_argument("--speed", type=_speed, default=1.0, help="simulated time per real second (default 1)")
    grbl.set_defaults(func=_grbl)
    rig = kinds.add_parser(
        "rig", help="the whole simulated rig: servos on a pty and a rendered camera writing DNG frames",
        description="Brings up the rig file's virtual servos on a pseudo-terminal (first stdout line: its path) and "
        "a camera rendered by Mitsuba from the pose the servos hold. Drive the servos with any Dynamixel client; "
        "type 'capture 0.01' on stdin for a 10 ms RAW frame, written as DNG into --frames.",
        epilog="Example: gonio sim rig --rig examples/rig_simulated.toml --frames out/frames",
    )  # fmt: skip
    rig.add_argument("--rig", help="rig file (TOML); default: the built-in simulated rig")
    rig.add_argument("--frames", default="out/sim-frames", help="directory for DNG frames (default out/sim-frames)")
    rig.add_argument("--speed", type=_speed, default=1.0, help="simulated time per real second (default 1)")
    rig.set_defaults(func=_rig)
    merl = kinds.add_parser(
        "merl", help="write a MERL .binary file of a known material, to try gonio analyze on",
        description="Tabulates a material at the MERL bins (90 x 90 x 180 half/difference angles, three channels: "
        "a 35 MB file) and writes it in the MERL format: the rig file's [simulation.material], or a glossy paint "
        "(CookTorrance alpha 0.2, dielectric eta 1.5 over a diffuse base rho_d 0.2, 0.3, 0.4).",
        epilog="Example: gonio sim merl --out paint.binary",
    )  # fmt: skip
    merl.add_argument("--out", required=True, help="the .binary file to write (replaced)")
    merl.add_argument("--rig", help="rig file (TOML) whose [simulation.material] to tabulate; default: a paint")
    merl.set_defaults(func=_merl)
