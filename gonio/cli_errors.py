"""How the command line reports a failure: one line that names what went wrong, and an exit code that says whose.

An error of gonio's own says whose it is by its kind (model/errors.py): input errors (a rig, sweep or table file, a
run directory, an argument) are exit 2, the user's to fix; a hardware fault 3, a camera fault 4; a stopped run the
code of its cause. A failing disk or a missing permission (OSError) is exit 74 with the path and the system's words
for it; anything else is a bug in gonio (exit 70), reported with where it was raised (``gonio --debug`` prints the
whole traceback). Output cut short by a closed pipe (``gonio plan ... | head``) ends quietly with 141, as a
program killed by SIGPIPE does.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import os
import re
import select
import sys
import traceback
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from model.errors import EXIT_INTERRUPTED, CameraFault, GonioError, HardwareFault, InputError
from model.spelling import did_you_mean

EXIT_OK = 0
# Whose an error is: the code its kind carries (model/errors.py), bad input, a hardware fault, a camera fault.
EXIT_BAD_INPUT, EXIT_HARDWARE, EXIT_CAMERA = InputError.exit_code, HardwareFault.exit_code, CameraFault.exit_code
# A prompt answered no; a bug (sysexits' EX_SOFTWARE); a file or device failed (EX_IOERR); stdout's reader left.
EXIT_DECLINED, EXIT_BUG, EXIT_OS_ERROR, EXIT_PIPE = 1, GonioError.exit_code, 74, 141

EXIT_CODES_HELP = (
    "Exit codes: 0 done; 1 declined at a confirmation prompt (nothing changed); 2 bad input (a rig, sweep or "
    "table file, a run or analysis directory, an argument); 3 hardware fault; 4 camera fault; 70 internal error "
    "(a bug: please report it with the output of `gonio --debug ...`); 74 operating-system error (a file or "
    "device: the path and the reason are printed); 130 interrupted (Ctrl-C, SIGTERM); 141 output pipe closed."
)


class CliError(InputError, ValueError):
    """An input error the command line itself finds (an unknown axis, an analysis it would overwrite): exit 2."""


#: How the line of an error of each kind begins (a stopped run's, of no kind, says what stopped it itself).
_HEADINGS: tuple[tuple[type[GonioError], str], ...] = (
    (InputError, "error: "), (HardwareFault, "hardware fault: "), (CameraFault, "camera fault: "),
)


def os_error_message(exc: OSError) -> str:
    """``path: reason [ENAME]`` for an OSError, naming both files of a failed rename."""
    name = errno.errorcode.get(exc.errno, "") if exc.errno is not None else ""
    reason = exc.strerror or str(exc)
    paths = [str(p) for p in (exc.filename, exc.filename2) if p is not None]
    where = " -> ".join(paths) + ": " if paths else ""
    return f"{where}{reason}" + (f" [{name}]" if name else "")


def _where(exc: BaseException) -> str:
    """The innermost frame of the traceback, as ``package/module.py:line in function``."""
    frames = traceback.extract_tb(exc.__traceback__)
    if not frames:
        return "an unknown place"
    last = frames[-1]
    path = Path(last.filename)
    root = Path(__file__).resolve().parent.parent
    try:
        shown = str(path.resolve().relative_to(root))
    except ValueError:
        shown = str(path)
    return f"{shown}:{last.lineno} in {last.name}"


def stdout_closed() -> bool:
    """Whether nobody reads stdout any more (a pipe whose reader exited): the poll reports an error on it."""
    try:
        fd = sys.stdout.fileno()
        poller = select.poll()
        poller.register(fd, select.POLLOUT)
        return any(event & (select.POLLERR | select.POLLHUP) for _, event in poller.poll(0))
    except (OSError, ValueError, AttributeError):
        return False


def quiet_broken_pipe() -> int:
    """Point stdout at /dev/null (so the interpreter's last flush cannot fail again) and give exit 141."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    return EXIT_PIPE


def report(exc: BaseException, debug: bool) -> int:
    """Print one line (or, with ``debug``, the traceback) for an exception a command raised; return the exit code."""
    if debug:
        traceback.print_exception(exc, file=sys.stderr)
    if isinstance(exc, KeyboardInterrupt):
        print("gonio: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    if isinstance(exc, GonioError) and exc.exit_code != EXIT_BUG:
        heading = next((words for kind, words in _HEADINGS if isinstance(exc, kind)), "")
        print(f"gonio: {heading}{exc}", file=sys.stderr)
        return exc.exit_code
    if isinstance(exc, OSError):
        print(f"gonio: operating-system error: {os_error_message(exc)}", file=sys.stderr)
        return EXIT_OS_ERROR
    print(f"gonio: internal error (a bug in gonio, not in your input): {type(exc).__name__}: {exc}\n"
          f"  raised at {_where(exc)}"
          + ("" if debug else "\n  run the same command as `gonio --debug ...` for the whole traceback, and please "
             "report it"), file=sys.stderr)  # fmt: skip
    return EXIT_BUG


@contextlib.contextmanager
def plain_warnings() -> Iterator[None]:
    """Warnings gonio raises for the user (a run store's repair) print as one ``gonio: warning:`` line.

    Python's own form names the source file and line that warned, which tells a user nothing; warnings from
    elsewhere (a library's) keep it, since there the place is what a bug report needs.
    """
    shown = warnings.showwarning

    def show(message: Warning | str, category: type[Warning], filename: str, lineno: int, *rest: Any,
             **kw: Any) -> None:  # fmt: skip
        if category.__name__ in _USER_WARNINGS:
            print(f"gonio: warning: {message}", file=sys.stderr)
        else:
            shown(message, category, filename, lineno, *rest, **kw)

    warnings.showwarning = show
    try:
        yield
    finally:
        warnings.showwarning = shown


#: Warning classes (by name: importing them would load the run store for every command) meant for the user.
_USER_WARNINGS = ("RunStoreWarning",)


def _option_strings(parser: argparse.ArgumentParser) -> list[str]:
    """Every option string of ``parser`` and of its subcommands' parsers, for a misspelt option's suggestion."""
    found: list[str] = []
    for action in parser._actions:
        found.extend(s for s in action.option_strings if s.startswith("--"))
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                found.extend(_option_strings(sub))
    return sorted(set(found))


class GonioParser(argparse.ArgumentParser):
    """An ArgumentParser that suggests the closest subcommand, choice or option for a misspelt one."""

    def error(self, message: str) -> None:  # type: ignore[override]
        """Print usage and the message with a "did you mean" where one is close; exit 2."""
        bad = re.search(r"invalid choice: '([^']*)'", message)
        if bad:
            choices = [str(c) for a in self._actions if a.choices for c in a.choices]
            message += did_you_mean(bad.group(1), choices)
        elif message.startswith("unrecognized arguments:"):
            known = _option_strings(self)
            for word in message.removeprefix("unrecognized arguments:").split():
                hint = did_you_mean(word.split("=", 1)[0], known) if word.startswith("--") else ""
                if hint:
                    message += f" ({word}: {hint.removeprefix('; ')})"
        super().error(message)
