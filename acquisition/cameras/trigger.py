"""Triggers for the tethered-folder camera: something run once per frame that makes the camera shoot.

A tethering program watches no rig; gonio has to tell it when to shoot and at what exposure. A rig file's
``[camera] trigger`` is either

- a command (a list of arguments, run without a shell), with placeholders for the frame's settings:
  ``{exposure_s}`` (seconds), ``{exposure_ms}``, ``{exposure_us}``, ``{shutter}`` (the way cameras write
  it: ``1/250``, ``0.5``, ``2``), ``{gain}`` (linear), ``{iso}`` (100 x gain) and ``{index}`` (frames
  triggered so far), e.g. ``["gphoto2", "--set-config", "shutterspeed={shutter}", "--capture-image-and-download"]``;
- or a Python callable ``"package.module:function"`` taking the frame's ``ExposureSettings`` (a vendor
  SDK's shoot call, or another backend's).

A command that fails (non-zero exit, not found, or running past ``timeout_s``) is a ``CameraError`` naming
the command, what it printed and its exit code, so a run stops on the camera fault instead of waiting
for a file that will never come.
"""

from __future__ import annotations

import importlib
import math
import os
import string
import subprocess
from collections.abc import Callable, Sequence

from acquisition.cameras import CameraError
from acquisition.frame import ExposureSettings

#: The placeholders a trigger command may use.
TRIGGER_FIELDS = ("exposure_s", "exposure_ms", "exposure_us", "shutter", "gain", "iso", "index")


def check_command(argv: Sequence[str]) -> None:
    """Raise ValueError naming a placeholder of a trigger command that is not one of ``TRIGGER_FIELDS``."""
    if len(argv) == 0:
        raise ValueError("a trigger command needs at least the program to run")
    for arg in argv:
        try:
            fields = [f for _, f, _, _ in string.Formatter().parse(arg) if f is not None]
        except ValueError as exc:
            raise ValueError(f"trigger argument {arg!r}: {exc} (write a literal brace as {{{{ or }}}})") from None
        unknown = [f for f in fields if f.split("!")[0].split(":")[0] not in TRIGGER_FIELDS]
        if unknown:
            raise ValueError(
                f"trigger argument {arg!r} has placeholder {{{unknown[0]}}}; expected one of "
                + ", ".join("{" + f + "}" for f in TRIGGER_FIELDS)
            )


def check_callable(spec: str) -> None:
    """Raise ValueError unless ``spec`` has the form ``"package.module:function"`` (not imported here)."""
    module, _, name = spec.partition(":")
    if not module or not name or not all(p.isidentifier() for p in (*module.split("."), *name.split("."))):
        raise ValueError(f"trigger {spec!r}: expected a command (a list of arguments) or 'package.module:function'")


def shutter_text(exposure_s: float) -> str:
    """An exposure as cameras write it: ``1/250`` below a third of a second where that is within 1 %, else seconds."""
    if exposure_s < 0.3:
        den = round(1.0 / exposure_s)
        if den > 0 and abs(1.0 / den - exposure_s) <= 0.01 * exposure_s:
            return f"1/{den}"
    return f"{exposure_s:g}"


def placeholders(settings: ExposureSettings, index: int) -> dict[str, str]:
    """The values of ``TRIGGER_FIELDS`` for one frame."""
    t, g = settings.exposure_s, settings.gain
    return {"exposure_s": f"{t:.9g}", "exposure_ms": f"{t * 1e3:.9g}", "exposure_us": f"{t * 1e6:.9g}",
            "shutter": shutter_text(t), "gain": f"{g:.6g}", "iso": f"{round(100 * g)}",
            "index": str(index)}  # fmt: skip


class CommandTrigger:
    """Runs a command per frame with the frame's settings filled in; see the module docstring."""

    def __init__(self, argv: Sequence[str], *, timeout_s: float = 60.0, cwd: str | os.PathLike[str] | None = None):
        check_command(argv)
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"trigger timeout_s = {timeout_s!r}: expected a positive number of seconds")
        self.argv = tuple(argv)
        self.timeout_s = float(timeout_s)
        self.cwd = cwd
        self.count = 0

    def command(self, settings: ExposureSettings) -> list[str]:
        """The command line for the next frame."""
        values = placeholders(settings, self.count)
        return [arg.format(**values) for arg in self.argv]

    def __call__(self, settings: ExposureSettings) -> None:
        """Run the command for one frame; CameraError if it cannot run, fails or overruns ``timeout_s``."""
        argv = self.command(settings)
        self.count += 1
        shown = " ".join(argv)
        try:
            done = subprocess.run(argv, capture_output=True, text=True, timeout=self.timeout_s, cwd=self.cwd,
                                  check=False)  # fmt: skip
        except FileNotFoundError:
            raise CameraError(f"trigger command `{shown}`: program {argv[0]!r} not found") from None
        except subprocess.TimeoutExpired:
            raise CameraError(f"trigger command `{shown}` did not finish within {self.timeout_s:g} s") from None
        if done.returncode != 0:
            said = (done.stderr or done.stdout or "").strip().splitlines()[-3:]
            raise CameraError(f"trigger command `{shown}` exited with status {done.returncode}"
                              + (": " + " | ".join(said) if said else ""))  # fmt: skip


def load_callable(spec: str) -> Callable[[ExposureSettings], None]:
    """The Python callable ``"package.module:function"`` names; CameraError if it cannot be imported."""
    check_callable(spec)
    module, _, name = spec.partition(":")
    try:
        target: object = importlib.import_module(module)
        for part in name.split("."):
            target = getattr(target, part)
    except (ImportError, AttributeError) as exc:
        raise CameraError(f"trigger {spec!r} cannot be loaded: {exc}") from exc
    if not callable(target):
        raise CameraError(f"trigger {spec!r} is a {type(target).__name__}, not a callable")
    return target
