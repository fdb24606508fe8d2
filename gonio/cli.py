"""The ``gonio`` command. Subcommands arrive with their issues; each explains itself with --help."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from gonio.cli_adaptive import add_adaptive_parser
from gonio.cli_analyze import add_analyze_parser
from gonio.cli_batch import add_batch_parser
from gonio.cli_calibrate import add_calibrate_parser
from gonio.cli_run import EXIT_BAD_INPUT, EXIT_HARDWARE, EXIT_INTERRUPTED, EXIT_OK, add_run_parsers
from gonio.cli_servo import add_servo_parser
from gonio.cli_sim import add_sim_parser


def _models(args: argparse.Namespace) -> int:
    from gonio.models_demo import check_table, write_slices

    png, table = write_slices(Path(args.out))
    print(f"wrote {png}\nwrote {table}")
    print("\nPhysical checks (reciprocity: worst relative asymmetry; albedo: importance-sampled, 20k samples):")
    print("\n".join(check_table()))
    return EXIT_OK


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the gonio command and its subcommands."""
    parser = argparse.ArgumentParser(
        prog="gonio",
        description="Drive, simulate and analyse a gonioreflectometer.",
        epilog="Example: gonio demo --out out/demo. Exit codes: 0 ok, 2 bad input, 3 hardware fault, "
        "4 camera fault, 130 interrupted.",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    add_run_parsers(sub)
    models = sub.add_parser(
        "models",
        help="plot in-plane BRDF slices of a few materials and check their physics",
        description="Writes brdf_slices.png and brdf_slices.csv (f_r in 1/sr) and prints each "
        "material's reciprocity, energy and finiteness checks.",
        epilog="Example: gonio models --out out/models",
    )
    models.add_argument("--out", default="out/models", help="output directory (default: out/models)")
    models.set_defaults(func=_models)
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
    # After parsing, so `gonio --help` does not pay for them (rig.run.store pulls in numpy and the models); every
    # command that can raise them imports them anyway.
    from rig.instrument.links.base import LinkError
    from rig.run.store import RunStoreError

    try:
        return int(args.func(args))
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except LinkError as exc:
        print(f"gonio: hardware fault: {exc}", file=sys.stderr)
        return EXIT_HARDWARE
    except (ValueError, OSError, RunStoreError) as exc:
        print(f"gonio: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
