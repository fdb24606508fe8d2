"""``gonio run``, ``gonio plan``, ``gonio resume`` and ``gonio demo``: sweeps from files, on hardware or simulated.

Exit codes: 0 done; 2 bad input (a rig or sweep file, an argument, a run directory); 3 a hardware fault
(link or servo) stopped the run; 4 a camera fault stopped it; 130 interrupted (Ctrl-C or SIGTERM). A
stopped run keeps everything measured; ``gonio resume RUN`` continues it. The codes of every command
(1 declined, 70 a bug, 74 an operating-system error, 141 a closed output pipe too) are gonio.cli_errors'.
"""

from __future__ import annotations

import argparse
import datetime
import signal
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType
from typing import Any

# Re-exported: the exit codes have always been importable from here (see docs/architecture.md).
from gonio.cli_errors import EXIT_BAD_INPUT as EXIT_BAD_INPUT
from gonio.cli_errors import EXIT_CAMERA as EXIT_CAMERA
from gonio.cli_errors import EXIT_HARDWARE as EXIT_HARDWARE
from gonio.cli_errors import EXIT_INTERRUPTED as EXIT_INTERRUPTED
from gonio.cli_errors import EXIT_OK
from gonio.cli_options import add_command, add_quiet_option, add_rig_option, load_rig_option


@contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """SIGTERM (a scheduler or `kill`) stops a run the way Ctrl-C does: safely, journal intact."""

    def handler(signum: int, frame: FrameType | None) -> None:
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _stopped(exc: Exception) -> int:
    from rig.run.measuring.runner import RunStopped

    if isinstance(exc, RunStopped):
        print(f"gonio: {exc}", file=sys.stderr)
        return exc.exit_code  # its cause's: interrupted, a hardware fault, a camera fault
    raise exc


def _report(summary: object) -> None:
    from rig.run.measuring.runner import RunSummary

    assert isinstance(summary, RunSummary)
    print(f"measured {summary.measured} points ({summary.already} from before), {summary.references} reference "
          f"readings, {summary.drift_warnings} drift warnings")  # fmt: skip
    print(f"table: {summary.table}")


def _default_out(sweep: str) -> Path:
    stamp = datetime.datetime.now().strftime("%Y%m%d-%H%M%S")
    return Path("runs") / f"{Path(sweep).stem}-{stamp}"


def _run(args: argparse.Namespace) -> int:
    """measure a sweep (on the simulated rig unless --rig names hardware)

    Plan the sweep, then measure every reachable point: move, wait in position, read back the angles, capture an HDR
    bracket, reduce the ROI, journal the point. Reference readings and a drift check on the rig's schedule. Ctrl-C stops
    safely; `gonio resume RUN` continues. Exit codes: 0 done, 2 bad input, 3 hardware fault, 4 camera fault, 130
    interrupted.

    Example: gonio run examples/sweep_in_plane.toml --rig examples/rig_simulated.toml --out runs/gold
    """
    from rig.run.config.files import load_sweep
    from rig.run.measuring.runner import RunStopped
    from rig.run.session import start_run

    rig, sweep = load_rig_option(args.rig), load_sweep(args.sweep)
    out = Path(args.out) if args.out else _default_out(args.sweep)
    print(f"run directory: {out}", file=sys.stderr)
    for warning in rig.calibration_warnings():
        print(f"warning: {warning}", file=sys.stderr)
    try:
        with _sigterm_as_interrupt():
            _report(start_run(rig, sweep, out, progress=not args.quiet, log=lambda m: print(m, file=sys.stderr)))
    except RunStopped as exc:
        return _stopped(exc)
    return EXIT_OK


def resume_adaptive_dir(directory: str) -> int:
    """Continue the interrupted adaptive sweep in ``directory`` (``gonio adaptive --resume``, ``gonio resume``)."""
    from analysis.ladder import parse_models
    from rig.run.adaptive.sweep import resume_adaptive
    from rig.run.measuring.runner import RunStopped

    print(f"resuming the adaptive sweep in {directory}", file=sys.stderr)
    try:
        with _sigterm_as_interrupt():
            result = resume_adaptive(Path(directory), lambda name: parse_models(name)[0])
    except RunStopped as exc:
        return _stopped(exc)
    return _summary(result)


def _summary(result: Any) -> int:
    last = result.rounds[-1]
    print(f"{last.captures} captures in {len(result.rounds)} rounds, {result.rig_time_s / 60:.1f} min rig time; "
          f"table {result.table}")  # fmt: skip
    print(last.fit.summary())
    return EXIT_OK


def _resume(args: argparse.Namespace) -> int:
    """continue a stopped or killed run from its journal

    Reopen a run directory, rebuild its plan from the manifest and measure the points its journal lacks. The table at
    the end equals that of an uninterrupted run.

    Example: gonio resume runs/gold
    """
    from rig.run.adaptive.state import is_adaptive
    from rig.run.measuring.runner import RunStopped
    from rig.run.session import RunFinished, resume_run

    if is_adaptive(args.run):  # an adaptive sweep's directory: its rounds, not one run
        return resume_adaptive_dir(args.run)

    try:
        with _sigterm_as_interrupt():
            _report(resume_run(args.run, progress=not args.quiet))
    except RunStopped as exc:
        return _stopped(exc)
    except RunFinished as exc:
        # Resuming is idempotent: a script may resume whatever it finds, and a finished run is done, not wrong.
        print(f"gonio: {exc}", file=sys.stderr)
    return EXIT_OK


def _plan(args: argparse.Namespace) -> int:
    """print a sweep's plan and time estimate without moving anything

    Generate the sweep's points, solve the rig's kinematics, list unreachable points with their reasons, order the rest
    for the least move time and estimate the run time.

    Example: gonio plan examples/sweep_grid.toml --rig examples/rig_simulated.toml --list
    """
    from rig.run.config.files import load_sweep
    from rig.run.session import make_plan, resolve_mode

    rig, sweep = load_rig_option(args.rig), load_sweep(args.sweep)
    plan = make_plan(rig, sweep, progress=not args.quiet)
    print(f"rig: {rig.file.name} ({rig.path}); sweep: {sweep.file.name} ({sweep.path})")
    _, choice = resolve_mode(rig, sweep, plan) if plan.points else (sweep, None)
    if choice is not None:
        print(choice.describe())
    print(rig.calibration.describe() if rig.calibration else "geometry calibration: none (the rig as drawn)")
    for warning in rig.calibration_warnings():
        print(f"warning: {warning}", file=sys.stderr)
    if sweep.discarded:
        print(f"{sweep.discarded} half/difference combinations leave the hemisphere and are not measurable")
    print(plan.summary())
    if args.list:
        for pos, p in enumerate(plan.points):
            angles = ", ".join(f"{v:7.2f}" for v in p.directions_deg)
            joints = ", ".join(f"{k} {v:7.2f}" for k, v in p.joints.as_dict().items())
            print(f"{pos:5d}  #{p.index:<5d} ({angles})  ->  {joints}")
    return EXIT_OK


def _demo(args: argparse.Namespace) -> int:
    """measure a gold sample on the simulated rig and plot it against its true BRDF

    Brings up the simulated rig (virtual servos on a pty, Mitsuba camera), runs an in-plane sweep of a rough gold sample
    with reference readings, and writes the run, its table of BRDF samples and a plot of the measured BRDF (with error
    bars) against the material's model.

    Example: gonio demo --out out/demo
    """
    from gonio.demo import run_demo

    return run_demo(Path(args.out), points=args.points, progress=not args.quiet)


def _add_sweep_and_rig(parser: argparse.ArgumentParser) -> None:
    """What ``gonio run`` and ``gonio plan`` take alike: a sweep file, on the rig of --rig."""
    parser.add_argument("sweep", help="sweep file (TOML)")
    add_rig_option(parser)


def add_run_parsers(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``gonio run``, ``plan``, ``resume`` and ``demo``."""
    run = add_command(sub, "run", _run)
    _add_sweep_and_rig(run)
    run.add_argument("--out", help="run directory to create (default: runs/<sweep>-<date>-<time>)")
    add_quiet_option(run)
    plan = add_command(sub, "plan", _plan)
    _add_sweep_and_rig(plan)
    plan.add_argument("--list", action="store_true", help="also list every point in run order with its joints")
    add_quiet_option(plan, "no progress bar (shown on stderr for a plan of more than 10000 points)")
    resume = add_command(sub, "resume", _resume)
    resume.add_argument("run", help="run directory (or an adaptive sweep's directory)")
    add_quiet_option(resume)
    demo = add_command(sub, "demo", _demo)
    demo.add_argument("--out", default="out/demo", help="output directory (default: out/demo; replaced)")
    demo.add_argument("--points", type=int, default=13, help="view angles per incidence (default 13)")
    add_quiet_option(demo)
