"""gonio's errors share one base whose ``exit_code`` says whose a failure is: the command line reads it, not the class.

Each error class of gonio derives from one of these kinds (``tests/test_errors.py`` walks every module to hold this):

- :class:`InputError`, exit 2: the user's to fix, a rig, sweep or table file, a run or analysis directory, a model
  or MERL file, a command-line argument, data a fit cannot use;
- :class:`HardwareFault`, exit 3: a link, a servo or the motion controller failed;
- :class:`CameraFault`, exit 4: the camera failed;
- :class:`GonioError` itself, exit 70: an error that the code above it handles (a frame a capture retries, a G-code
  line the simulated controller answers with an error); reaching the command line unhandled, it is a bug in gonio.

A kind carries no builtin base: each class keeps its own beside its kind (ValueError, RuntimeError, LookupError,
ImportError, TimeoutError ...), so that an ``except ValueError`` catches what it always caught and no more.
"""

from __future__ import annotations

#: A run interrupted by the operator (Ctrl-C, SIGTERM): the shell's code for a process that SIGINT ended.
EXIT_INTERRUPTED = 130


class GonioError(Exception):
    """An error of gonio's own; ``exit_code`` is the command line's exit code when it ends a command (70: a bug)."""

    exit_code: int = 70


class InputError(GonioError):
    """Wrong input, the user's to fix (a file, a directory, an argument, data a fit cannot use): exit 2."""

    exit_code = 2


class HardwareFault(GonioError):
    """A link, a servo or the motion controller failed: exit 3."""

    exit_code = 3


class CameraFault(GonioError):
    """The camera failed (a capture, a confirmation, a calibration's frames): exit 4."""

    exit_code = 4
