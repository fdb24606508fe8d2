"""What several gonio commands declare alike, said once: registering a subcommand, --rig, --quiet, a count.

Each command group's module (gonio.cli_run, cli_sim, ...) builds its parsers from these, so an option that
means the same in every command also reads the same in every --help, and a rig file is loaded one way. A
command's own texts (its line in the list, its description, its example) are its handler's docstring, beside
what the handler does.
"""

from __future__ import annotations

import argparse
import inspect
import re
from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from rig.run.config.files import RigConfig


def add_command(sub: argparse._SubParsersAction[argparse.ArgumentParser], name: str,
                func: Callable[[argparse.Namespace], int]) -> argparse.ArgumentParser:  # fmt: skip
    """Register subcommand ``name``, which runs ``func(args)`` for its exit code; its --help texts are func's docstring.

    The docstring's first line is the command's line in its group's list, the paragraphs after it its description,
    and a last paragraph that begins ``Example`` its epilog (argparse folds the lines of each).
    """
    help_line, description, epilog = command_texts(func)
    parser = sub.add_parser(name, help=help_line, description=description, epilog=epilog)
    parser.set_defaults(func=func)
    return parser


def command_texts(func: Callable[..., object]) -> tuple[str | None, str | None, str | None]:
    """A command handler's help line, description and example, from its docstring (None for what it lacks)."""
    paragraphs = [p for p in re.split(r"\n\s*\n", inspect.cleandoc(func.__doc__ or "")) if p.strip()]
    if not paragraphs:  # no docstring: python -OO strips them
        return None, None, None
    example = paragraphs.pop() if len(paragraphs) > 1 and paragraphs[-1].startswith("Example") else None
    return paragraphs[0], "\n\n".join(paragraphs[1:]) or None, example


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
