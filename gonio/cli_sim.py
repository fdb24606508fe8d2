"""``gonio sim servos|grbl|rig``: serve simulated hardware on a pty until Ctrl-C; ``gonio sim merl``: a MERL file.

The simulator package is imported only when one of these commands runs (nothing in rig imports it at
module level), so the controller never depends on the stand-in hardware.
"""

from __future__ import annotations

import argparse
import math
import os
import select
import sys
from collections.abc import Iterator
from typing import Any

from gonio.cli_errors import EXIT_CAMERA, CliError
from gonio.cli_options import add_command, add_rig_option, load_rig_option
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


def _add_speed(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--speed", type=_speed, default=1.0, help="simulated time per real second (default 1)")


def _grbl_axes(text: str) -> str:
    """Parse --axes: a prefix of GRBL's axis letters XYZABC (the virtual controller has its axes in that order)."""
    letters = "XYZABC"  # simulator.grbl.settings.AXIS_LETTERS, spelt out: the simulator loads only when a command runs
    if not text or letters[: len(text)] != text:
        raise argparse.ArgumentTypeError(
            f"--axes {text!r}: expected the first 1 to {len(letters)} of GRBL's axis letters {letters} in that "
            f"order, e.g. X, XY, XYZ or XYZA"
        )
    return text


def _positive_number(text: str) -> float | None:
    """``text`` as a positive, finite number, or None."""
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) and value > 0 else None


def capture_seconds(text: str) -> float:
    """The exposure of a ``capture SECONDS`` line typed to ``gonio sim rig``; ValueError says what is expected."""
    value = _positive_number(text)
    if value is None:
        raise ValueError(f"'capture {text}': expected 'capture SECONDS' with SECONDS a positive number")
    return value


def _positive(what: str) -> Any:
    """A parser of a positive, finite number, its error naming ``what``."""

    def parse(text: str) -> float:
        value = _positive_number(text)
        if value is None:
            raise argparse.ArgumentTypeError(f"{what} {text!r}: expected a positive number")
        return value

    return parse


def _announce(line: str) -> None:
    print(line, flush=True)


def _servos(args: argparse.Namespace) -> int:
    """virtual Dynamixel Protocol 2.0 bus of XM430-W350 servos

    Example: gonio sim servos --ids 1-4 --baud 1000000
    """
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
    """virtual GRBL 1.1 motion controller

    Example: gonio sim grbl --axes XYZA --homing
    """
    from simulator.grbl.server import serve_grbl
    from simulator.grbl.settings import AXIS_DEFAULTS

    settings: dict[int, float] | None = None
    start: dict[str, float] | None = None
    if args.homing:
        # As a commissioned controller: locked at power-up until $H, the axes somewhere mid-travel ($130's half)
        # rather than on their switches, so homing has a way to go.
        settings = {22: 1.0}
        start = dict.fromkeys(args.axes, -AXIS_DEFAULTS[3] / 2)

    def ready(port: str) -> None:
        _announce(port)
        homing = "homing on ($22=1: in Alarm until $H)" if args.homing else "homing off"
        print(
            f"virtual GRBL 1.1h: axes {args.axes}, 115200 baud, {homing}, time x{args.speed:g}; Ctrl-C stops",
            file=sys.stderr,
            flush=True,
        )

    serve_grbl(ScaledClock(args.speed), axes=args.axes, settings=settings, start_position=start, on_ready=ready)
    return 0


def _resolution(text: str) -> tuple[int, int]:
    """Parse ``WIDTHxHEIGHT`` sensor pixels."""
    try:
        w, h = (int(p) for p in text.lower().split("x"))
    except ValueError:
        w = h = 0
    if not (8 <= w <= 16384 and 8 <= h <= 16384):
        raise argparse.ArgumentTypeError(f"resolution {text!r}: expected WIDTHxHEIGHT pixels, e.g. 640x480, 8..16384")
    return w, h


def _rig(args: argparse.Namespace) -> int:
    """a whole simulated rig for gonio's real backends: its link on a pty, a tethered RAW camera

    Rehearses a rig: serves the rig file's virtual servos (or virtual GRBL controller) on a pseudo-terminal (first
    stdout line: its path) and, in place of the camera, a tethering program that writes whole-sensor DNG frames into
    --frames, rendered by Mitsuba from the pose the axes physically hold. A hardware rig file (link kind dynamixel or
    grbl, camera backend folder) then runs against it as against the real rig, with [link] port and [camera] folder
    pointed here; a simulated rig file (its [simulation] hidden from the controller) is served on --link, and
    --write-rig writes the hardware rig file for it. Frames are shot when the folder camera leaves a shot request (a rig
    file without a trigger) or when 'capture SECONDS' is typed on stdin. What an operator puts on the stage is typed
    too: 'scene tile' (the reference tile), 'scene board' (the ChArUco board), 'scene flat' (a uniform light before the
    lens), 'scene dark' (the lens cap), 'scene sample'.

    Example: gonio sim rig --rig examples/rig_dynamixel.toml --frames out/tether --speed 10
    """
    import threading
    from pathlib import Path

    from simulator import rehearsal as r

    cfg = load_rig_option(args.rig)
    link = r.rehearsal_link(cfg, args.link)
    spec = r.rehearsal_spec(cfg, link, resolution=args.resolution, speed=args.speed)
    frames = Path(args.frames).resolve()
    frames.mkdir(parents=True, exist_ok=True)
    hardware = cfg.file.link.kind != "simulated"
    roi = cfg.file.camera.roi if hardware else r.controller_roi(cfg, spec.camera.resolution)
    with r.rehearsal_rig(cfg, link, spec) as sim:
        tether = r.Tether(sim, frames, roi)
        if args.write_rig:  # before the port is announced: a client reading that line may read the file next
            text = r.controller_rig_text(cfg, sim, link, frames, r.controller_roi(cfg, spec.camera.resolution))
            Path(args.write_rig).write_text(text)
        _announce(sim.port)
        ids = ",".join(str(a.address) for a in sim.axes)
        what = (f"GRBL 1.1h axes {ids}" if link == "grbl" else f"servos {ids}") + \
            f" ({', '.join(a.name for a in sim.axes)})"
        line = "115200 baud (home with $H first)" if link == "grbl" else f"{spec.baudrate} baud"
        w, h = spec.camera.resolution
        print(f"simulated rig {cfg.file.name!r}: {what} at {line}, time x{args.speed:g}; a {w} x {h} RAW camera "
              f"tethered to {frames} (it answers the folder camera's shot requests; type 'capture SECONDS' for a "
              f"frame, 'scene {'|'.join(SCENE_WORDS)}' for what is on the stage); Ctrl-D or Ctrl-C stops",
              file=sys.stderr, flush=True)  # fmt: skip
        stop = threading.Event()
        server = threading.Thread(target=tether.serve, args=(stop,), kwargs={"on_error": _announce}, daemon=True)
        server.start()
        try:
            for text in _lines(sys.stdin.fileno()):
                _answer(tether, text)
        finally:
            stop.set()
            server.join(timeout=10)
    return 0


def _lines(fd: int, wake_s: float = 0.2) -> Iterator[str]:
    """The lines typed on ``fd`` until its end, waking every ``wake_s`` seconds in between.

    Mitsuba's render puts SIGINT's handler back with glibc's ``signal()``, which adds SA_RESTART (measured: the
    sigaction flags go from SA_ONSTACK to SA_RESTART across one ``mi.render``), so the kernel restarts a read
    blocked on stdin after the handler has only noted Ctrl-C, and Python raised KeyboardInterrupt at the next
    line typed. A select returns to Python either way: waking keeps Ctrl-C (and SIGTERM's) prompt.
    """
    pending = b""
    while True:
        ready, _, _ = select.select([fd], [], [], wake_s)
        if not ready:
            continue
        chunk = os.read(fd, 65536)
        if not chunk:
            if pending:
                yield pending.decode(errors="replace")
            return
        pending += chunk
        *done, pending = pending.split(b"\n")
        for line in done:
            yield line.decode(errors="replace") + "\n"


#: What ``scene`` takes on the rehearsal's input (``simulator.rehearsal.SCENES``; listed here for --help).
SCENE_WORDS = ("sample", "tile", "board", "flat", "dark")


def _answer(tether: Any, text: str) -> None:
    """Do what one line of the rehearsal's input says, printing its answer (a frame's path, or an error)."""
    words = text.split()
    if not words:
        return
    if words[0] == "capture" and len(words) == 2:
        try:
            seconds = capture_seconds(words[1])
        except ValueError as exc:
            print(f"error: {exc}", flush=True)
            return
    try:
        if words[0] == "capture" and len(words) == 2:
            print(tether.shoot(seconds), flush=True)
        elif words[0] == "scene" and len(words) == 2:
            tether.set_scene(words[1])
            print(f"scene {words[1]}", flush=True)
        else:
            print(f"error: {text.strip()!r}: expected 'capture SECONDS' or 'scene {'|'.join(SCENE_WORDS)}'", flush=True)
    except ValueError as exc:
        print(f"error: {text.strip()!r}: {exc}", flush=True)


def _shoot(args: argparse.Namespace) -> int:
    """a tether trigger for the rehearsal: ask gonio sim rig for one frame and wait until it is shot

    Leaves a shot request in the rehearsal's hot folder and returns once gonio sim rig has taken it (the frame's file
    follows at once). As a rig file's [camera] trigger it stands where a tethering program's remote would:
    trigger = ["gonio", "sim", "shoot", "--folder", "/tmp/tether", "--exposure-s", "{exposure_s}", "--gain", "{gain}",
    "--index", "{index}"].

    Example: gonio sim shoot --folder /tmp/tether --exposure-s 0.01
    """
    import time
    from pathlib import Path

    from acquisition.cameras.shot_request import withdraw_request, write_request
    from acquisition.frame import ExposureSettings

    folder = Path(args.folder)
    if not folder.is_dir():
        raise CliError(f"--folder {args.folder}: no such directory (the hot folder gonio sim rig --frames serves)")
    # The controller that runs this trigger is the client: its frames' noise streams go on across its triggers.
    request = write_request(folder, ExposureSettings(args.exposure_s, args.gain), args.index, client=os.getppid())
    deadline = time.monotonic() + args.timeout_s
    while request.exists():
        if time.monotonic() > deadline:
            withdraw_request(request)
            print(f"gonio sim shoot: no rehearsal answered in {folder} within {args.timeout_s:g} s "
                  "(is gonio sim rig running with --frames there?)", file=sys.stderr)  # fmt: skip
            return EXIT_CAMERA
        time.sleep(0.005)
    return 0


#: The material of ``gonio sim merl`` without --rig: a glossy paint (a diffuse base under a GGX dielectric coat).
PAINT = {"model": "CookTorrance", "alpha": 0.2, "fresnel": "dielectric", "eta": 1.5, "rho_d": [0.2, 0.3, 0.4]}


def _merl(args: argparse.Namespace) -> int:
    """write a MERL .binary file of a known material, to try gonio analyze on

    Tabulates a material at the MERL bins (90 x 90 x 180 half/difference angles, three channels: a 35 MB file) and
    writes it in the MERL format: the rig file's [simulation.material], or a glossy paint (CookTorrance alpha 0.2,
    dielectric eta 1.5 over a diffuse base rho_d 0.2, 0.3, 0.4).

    Example: gonio sim merl --out paint.binary
    """
    from pathlib import Path

    from model.merl import MerlTable, write_merl
    from rig.run.config.files import load_rig, material_from, parse, rig_config
    from rig.run.config.schema import RigFile

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
    servos = add_command(kinds, "servos", _servos)
    servos.add_argument("--ids", type=_ids, default=(1, 2, 3, 4), help="servo ids, e.g. 1,2,3 or 1-4 (default 1-4)")
    servos.add_argument(
        "--baud",
        type=int,
        choices=SDK_BAUDRATES,
        default=1_000_000,
        metavar="BAUD",
        help="servos' baud rate, one dynamixel_sdk accepts (default 1000000)",
    )
    _add_speed(servos)
    servos.add_argument(
        "--return-delay", action="store_true", help="honour each servo's Return Delay Time in real time"
    )
    grbl = add_command(kinds, "grbl", _grbl)
    grbl.add_argument("--axes", type=_grbl_axes, default="XYZ",
                      help="axis letters, the first of XYZABC in order (default XYZ)")  # fmt: skip
    _add_speed(grbl)
    grbl.add_argument(
        "--homing",
        action="store_true",
        help="homing enabled ($22=1) as on a commissioned rig: at power-up (every port open) the controller is in "
        "Alarm until $H (or $X), with each axis's switch at machine 0 and the axes standing mid-travel; what a "
        "gonio run's GRBL link needs (it homes before it moves and refuses a controller without homing). "
        "Default: GRBL's factory settings (homing off, Idle at 0)",
    )
    rig = add_command(kinds, "rig", _rig)
    add_rig_option(rig)
    rig.add_argument("--link", choices=("dynamixel", "grbl"),
                     help="for a simulated rig file: the link to serve (default its [simulation] link)")  # fmt: skip
    rig.add_argument("--frames", default="out/sim-frames", help="hot folder for DNG frames (default out/sim-frames)")
    _add_speed(rig)
    rig.add_argument("--resolution", type=_resolution, metavar="WxH",
                     help="sensor pixels (default: a simulated file's camera.resolution; for a hardware file the "
                          "smallest sensor centred on its camera.roi)")  # fmt: skip
    rig.add_argument("--write-rig", metavar="PATH", help="write the hardware rig file a controller uses here (TOML)")
    shoot = add_command(kinds, "shoot", _shoot)
    shoot.add_argument("--folder", required=True, help="the hot folder gonio sim rig --frames serves")
    shoot.add_argument("--exposure-s", type=_positive("exposure"), required=True, help="exposure in seconds")
    shoot.add_argument("--gain", type=_positive("gain"), default=1.0, help="linear gain (default 1)")
    shoot.add_argument("--index", type=int, default=0, help="the frame's number, for the request's name (default 0)")
    shoot.add_argument("--timeout-s", type=_positive("timeout"), default=60.0,
                       help="seconds to wait for the rehearsal (default 60)")  # fmt: skip
    merl = add_command(kinds, "merl", _merl)
    merl.add_argument("--out", required=True, help="the .binary file to write (replaced)")
    merl.add_argument("--rig", help="rig file (TOML) whose [simulation.material] to tabulate; default: a paint")
