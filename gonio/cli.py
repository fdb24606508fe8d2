"""The ``gonio`` command. Subcommands arrive with their issues; each explains itself with --help."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import cast

from gonio.cli_adaptive import add_adaptive_parser
from gonio.cli_analyze import add_analyze_parser
from gonio.cli_batch import add_batch_parser
from gonio.cli_calibrate import add_calibrate_parser
from gonio.cli_errors import EXIT_CODES_HELP, GonioParser, plain_warnings, quiet_broken_pipe, report, stdout_closed
from gonio.cli_options import add_command
from gonio.cli_run import EXIT_OK, add_run_parsers
from gonio.cli_servo import add_servo_parser
from gonio.cli_sim import add_sim_parser


class _Version(argparse.Action):
    """``--version``: the version is looked up when asked for (model's package is slow to import)."""

    def __call__(self, parser: argparse.ArgumentParser, *_: object) -> None:
        from model.version import gonio_version

        print(f"gonio {gonio_version()}")
        parser.exit()


def _models(args: argparse.Namespace) -> int:
    """plot in-plane BRDF slices of a few materials and check their physics

    Writes brdf_slices.png and brdf_slices.csv (f_r in 1/sr) and prints each material's reciprocity, energy and
    finiteness checks.

    Example: gonio models --out out/models
    """
    from gonio.models_demo import check_table, write_slices

    png, table = write_slices(Path(args.out))
    print(f"wrote {png}\nwrote {table}")
    print("\nPhysical checks (reciprocity: worst relative asymmetry; albedo: importance-sampled, 20k samples):")
    print("\n".join(check_table()))
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the gonio command and its subcommands."""
    parser = GonioParser(
        prog="gonio",
        description="Drive, simulate and analyse a gonioreflectometer.",
        epilog=f"Example: gonio demo --out out/demo. {EXIT_CODES_HELP}",
    )
    parser.add_argument("--version", action=_Version, nargs=0, help="print gonio's version and exit")
    parser.add_argument("--debug", action="store_true", help="print the whole traceback of any error")
    # Every subcommand's parser is a GonioParser too (argparse makes them of the parent's class).
    sub = cast("argparse._SubParsersAction[argparse.ArgumentParser]",
               parser.add_subparsers(dest="command", required=True, metavar="COMMAND"))  # fmt: skip
    add_run_parsers(sub)
    models = add_command(sub, "models", _models)
    models.add_argument("--out", default="out/models", help="output directory (default: out/models)")
    add_analyze_parser(sub)
    add_batch_parser(sub)
    add_adaptive_parser(sub)
    add_calibrate_parser(sub)
    add_servo_parser(sub)
    add_sim_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the gonio console script; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    with plain_warnings():
        return _call(args)


def _call(args: argparse.Namespace) -> int:
    try:
        code = int(args.func(args))
        sys.stdout.flush()  # here, not at exit, so that a closed pipe is met where it can be handled
        return code
    except BrokenPipeError as exc:
        if stdout_closed():
            return quiet_broken_pipe()
        return report(exc, args.debug)
    except (Exception, KeyboardInterrupt) as exc:
        if isinstance(exc, OSError) and stdout_closed():
            return quiet_broken_pipe()
        return report(exc, args.debug)


if __name__ == "__main__":
    sys.exit(main())
