"""The ``gonio`` command. Subcommands arrive with their issues; each explains itself with --help."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rig.cli_sim import add_sim_parser

EXIT_OK = 0
EXIT_BAD_INPUT = 2


def _demo(args: argparse.Namespace) -> int:
    from rig.demo import check_table, write_slices

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
        epilog="Example: gonio demo --out out/demo",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    demo = sub.add_parser(
        "demo",
        help="plot in-plane BRDF slices of a few materials and check their physics",
        description="Writes brdf_slices.png and brdf_slices.csv (f_r in 1/sr) and prints each "
        "material's reciprocity, energy and finiteness checks.",
        epilog="Example: gonio demo --out out/demo",
    )
    demo.add_argument("--out", default="out/demo", help="output directory (default: out/demo)")
    demo.set_defaults(func=_demo)
    add_sim_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the gonio console script; returns the process exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (ValueError, OSError) as exc:
        print(f"gonio: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT


if __name__ == "__main__":
    sys.exit(main())
