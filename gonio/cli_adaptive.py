"""``gonio adaptive``: a sweep that chooses its own points, round by round, where the fit is least certain."""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable
from pathlib import Path

from gonio.cli_errors import CliError
from gonio.cli_options import add_command, add_quiet_option, add_rig_option, load_rig_option
from gonio.cli_run import _sigterm_as_interrupt, _stopped, _summary, resume_adaptive_dir


def _metadata(pairs: list[str] | None) -> dict[str, str]:
    """--metadata KEY=VALUE options as the sweep's [metadata] (an adaptive sweep has no sweep file)."""
    out = {}
    for pair in pairs or []:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise CliError(f"--metadata {pair!r}: expected KEY=VALUE, e.g. sample='gold foil #7'")
        out[key.strip()] = value
    return out


def _check_options(args: argparse.Namespace) -> None:
    """The sweep's options, each blamed by its own name (AdaptiveSettings' words are the Python API's)."""

    def bad(option: str, value: object, expected: str) -> CliError:
        shown = f"{value:g}" if isinstance(value, float) else repr(value)  # as typed: 120, not 120.0
        return CliError(f"{option} {shown}: expected {expected}")

    if args.budget < 1:
        raise bad("--budget", args.budget, "a positive number of captures")
    if not 1 <= args.initial <= args.budget:
        raise bad("--initial", args.initial, f"1 to --budget ({args.budget}) captures in the first round")
    if args.batch < 1:
        raise bad("--batch", args.batch, "a positive number of captures per round")
    if not (math.isfinite(args.max_theta) and 0 < args.max_theta <= 90):
        raise bad("--max-theta", args.max_theta, "a zenith in degrees, > 0 and at most 90")
    if not (math.isfinite(args.snr) and args.snr > 0):
        raise bad("--snr", args.snr, "a positive signal-to-noise ratio")
    if args.reference_snr is not None and not (math.isfinite(args.reference_snr) and args.reference_snr > 0):
        raise bad("--reference-snr", args.reference_snr, "a positive signal-to-noise ratio")
    if not 0 <= args.seed < 2**32:
        raise bad("--seed", args.seed, "a whole number from 0 to 4294967295")
    _check_mode_options(args, bad)


def _check_mode_options(args: argparse.Namespace, bad: Callable[[str, object, str], CliError]) -> None:
    """--mode, --tile-px, --motion and --scan-speed, by the sweep file's [capture] rules (argparse checks the names)."""
    from rig.run.adaptive.settings import MAX_SCAN_SPEED_DEG_S, MAX_TILE_PX

    if args.tile_px is not None:
        if not 1 <= args.tile_px <= MAX_TILE_PX:
            raise bad("--tile-px", args.tile_px, f"a tile side in pixels, 1 to {MAX_TILE_PX}")
        if args.mode == "point":
            raise CliError(f"--tile-px {args.tile_px}: has no meaning with --mode point (each capture reads the "
                           "camera's ROI): use --mode image or auto, or leave --tile-px out")  # fmt: skip
    if args.scan_speed is not None:
        if not (math.isfinite(args.scan_speed) and 0 < args.scan_speed <= MAX_SCAN_SPEED_DEG_S):
            raise bad("--scan-speed", args.scan_speed, f"deg/s of joint, > 0 and at most {MAX_SCAN_SPEED_DEG_S:g}")
        if args.motion != "continuous":
            raise CliError(f"--scan-speed {args.scan_speed:g}: has no meaning with --motion stop (every capture at "
                           "rest): use --motion continuous, or leave --scan-speed out")  # fmt: skip


def _adaptive(args: argparse.Namespace) -> int:
    """measure where the current fit is least certain, round by round

    An adaptive sweep: a space-filling first round, then rounds chosen from reachable candidates to lower the fitted
    BRDF's expected error the most (first order, from the fit's Jacobian). Each round is an ordinary run in
    OUT/round-NN; OUT/samples.csv holds every round's rows and OUT/adaptive.json the settings and fits. An interrupted
    sweep continues with --resume OUT (or gonio resume OUT); gonio analyze OUT analyses every round together.

    --budget counts captures (poses). --mode image makes each capture a sample per tile of the sample's footprint
    (the sweep file's [capture] mode); --mode auto measures the first round in image mode where the camera resolves
    the sample into many tiles and later rounds in point mode, scanning a round continuously where its plan has long
    runs in one joint and --motion continuous allows it. Each round's mode and motion, and why, are in the round's
    line and in OUT/adaptive.json.

    Example: gonio adaptive --rig examples/rig_simulated.toml --out runs/gold-adaptive --model ggx_conductor
    --budget 100
    """
    from tqdm.auto import tqdm

    from analysis.ladder import parse_models
    from rig.run.adaptive.sweep import AdaptiveSettings, Round, run_adaptive
    from rig.run.measuring.runner import RunStopped

    if args.resume:
        if args.out or args.rig:
            raise CliError("--resume DIR continues a sweep with the rig and settings it started with; "
                           "give no --out or --rig with it")  # fmt: skip
        return resume_adaptive_dir(args.resume)
    if not args.out:
        raise CliError("gonio adaptive: --out DIR is required (or --resume DIR to continue a sweep)")
    _check_options(args)
    spec = None if args.model == "auto" else parse_models(args.model)[0]
    try:
        settings = AdaptiveSettings(budget=args.budget, initial=args.initial, batch=args.batch,
                                    max_theta_deg=args.max_theta, target_snr=args.snr,
                                    reference_snr=args.reference_snr, seed=args.seed, mode=args.mode,
                                    tile_px=args.tile_px, motion=args.motion,
                                    scan_speed_deg_s=args.scan_speed)  # fmt: skip
    except ValueError as exc:  # the settings are the command line's options
        raise CliError(str(exc)) from None
    rig = load_rig_option(args.rig)
    print(f"adaptive sweep into {args.out}: {settings.budget} captures, model {args.model}, mode {settings.mode}, "
          f"motion {settings.motion}", file=sys.stderr)  # fmt: skip
    # A bar over the captures (rounds differ in size), its ETA from the rounds done; round lines print above it.
    bar = tqdm(total=settings.budget, desc="adaptive", unit="capture", disable=args.quiet, dynamic_ncols=True)

    def on_round(rnd: Round) -> None:
        bar.update(rnd.captures - bar.n)
        bar.set_postfix_str(f"round {rnd.index}", refresh=True)

    def say(line: str) -> None:
        tqdm.write(line, file=sys.stderr)

    try:
        with _sigterm_as_interrupt(), bar:
            result = run_adaptive(rig, Path(args.out), spec, settings, metadata=_metadata(args.metadata),
                                  on_round=on_round, log=say)  # fmt: skip
    except RunStopped as exc:
        return _stopped(exc)
    return _summary(result)


def add_adaptive_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Register ``gonio adaptive``."""
    p = add_command(sub, "adaptive", _adaptive)
    add_rig_option(p)
    p.add_argument("--out", help="directory to create (must not exist or be empty)")
    p.add_argument("--resume", metavar="DIR", help="continue the interrupted adaptive sweep in DIR with the rig, "
                   "model and settings it started with (no other options)")  # fmt: skip
    p.add_argument("--model", default="auto", help="model fitted between rounds (a name gonio analyze --models "
                   "accepts), or auto: the model selection's choice each round (default)")  # fmt: skip
    p.add_argument("--budget", type=int, default=100, help="captures in all (default 100)")
    p.add_argument("--initial", type=int, default=20, help="captures of the first round (default 20)")
    p.add_argument("--batch", type=int, default=10, help="captures per later round (default 10)")
    p.add_argument("--snr", type=float, default=100.0,
                   help="SNR goal of each sample: a point's reading, or in image mode each tile's (default 100)")
    p.add_argument("--reference-snr", type=float, default=None,
                   help="SNR goal of the reference readings (default: the rig's [reference] target_snr); each "
                   "round is its own run with about two, so a matte sample, whose fit is all calibration, "
                   "wants them about 2.5x the SNR a single long run would use")  # fmt: skip
    p.add_argument("--max-theta", type=float, default=70.0, help="largest zenith of any capture, deg (default 70)")
    p.add_argument("--mode", choices=("point", "image", "auto"), default="point",
                   help="point: each capture one reading of the camera's ROI (default); image: every tile of the "
                   "sample's footprint a sample; auto: the first round in image mode where the camera resolves the "
                   "sample into many tiles, later rounds in point mode")  # fmt: skip
    p.add_argument("--tile-px", type=int, default=None,
                   help="image mode's tile side in pixels (default 8; with --mode image or auto)")  # fmt: skip
    p.add_argument("--motion", choices=("stop", "continuous"), default="stop",
                   help="stop: every capture at rest (default); continuous: runs of points in one joint scanned at "
                   "constant speed (with --mode auto: only the rounds whose plan has long runs)")  # fmt: skip
    p.add_argument("--scan-speed", type=float, default=None,
                   help="the scanning joint's speed in continuous motion, deg/s (default 2)")  # fmt: skip
    p.add_argument("--seed", type=int, default=0, help="seed of the candidate pool (default 0)")
    p.add_argument("--metadata", action="append", metavar="KEY=VALUE",
                   help="what the sweep is about (sample=..., operator=..., notes=..., or a key of your own; "
                   "repeat for more), laid over the rig file's [metadata]: into every round, the tables and the "
                   "report")  # fmt: skip
    add_quiet_option(p)
