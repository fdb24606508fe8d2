"""What several gonio commands declare alike, said once: registering a subcommand, --rig, --quiet, a count.

Each command group's module (gonio.cli_run, cli_sim, ...) builds its parsers from these, so an option that
means the same in every command also reads the same in every --help, and a rig file is loaded one way.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rig.run.config.files import RigConfig

def add_command(sub: argparse._SubParsersAction[argparse.ArgumentParser], name: str,
                func: Callable[[argparse.Namespace], int], *, help: str, description: str | None = None,
                epilog: str | None = None) -> argparse.ArgumentParser:  # fmt: skip
    """Register subcommand ``name``, which runs ``func(args)`` for its exit code, with its --help texts."""
    parser = sub.add_parser(name, help=help, description=description, epilog=epilog)
    parser.set_defaults(func=func)
    return parser


def add_rig_option(parser: argparse.ArgumentParser) -> None:
    """--rig FILE, optional: without it the command runs on the built-in simulated rig (see load_rig_option)."""
    parser.add_argument("--rig", help="rig file (TOML); default: the built-in simulated rig")


def load_rig_option(path: str | None) -> RigConfig:
    """The rig an --rig option names: its file's, or the built-in simulated rig for none."""
    # Imported here, not at the top: the configuration's schema (pydantic) is slow to import, and
    # `gonio --help` or `gonio analyze` need none of it.
    from rig.run.config.files import load_rig, rig_config
    from rig.run.config.schema import RigFile

    return load_rig(path) if path else rig_config(RigFile(), "<built-in simulated rig>")


def add_quiet_option(parser: argparse.ArgumentParser, what: str = "no progress bar") -> None:
    """--quiet: ``what`` the command then leaves out of stderr."""
    parser.add_argument("--quiet", action="store_true", help=what)


def positive_count(text: str) -> int:
    """An option's whole number of at least 1 (a count of jobs, workers, starts, samples)."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a positive whole number")
    return value
