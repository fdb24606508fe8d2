"""The rehearsal driven as a lab drives its rig: ``gonio sim rig`` in one process, gonio's commands in others.

``Rehearsal`` starts ``gonio sim rig`` (the rig's link on a pty, the tethered camera on a hot folder) and
writes the controller's rig file: a hardware file with only ``[link] port`` and ``[camera] folder`` changed
(and whatever a test changes on purpose). ``Operator`` runs a gonio command and answers its prompts as a
person at the rig would: it puts on the stage what a prompt asks for (``scene ...`` on the rehearsal's input)
and then presses Enter. Every wait polls with a timeout; nothing sleeps for the hardware.
"""

from __future__ import annotations

import os
import re
import selectors
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: Generous bounds for a shared CI host loaded many times over: they end a hung process, never time a result.
START_TIMEOUT_S = 300.0
COMMAND_TIMEOUT_S = 900.0

#: What a prompt of gonio's asks for, and the scene the operator puts in view before pressing Enter.
PROMPTS: tuple[tuple[str, str], ...] = (
    ("place the reference tile", "tile"),
    ("Mount the ChArUco board", "board"),
    ("uniform, stable light", "flat"),
    ("cap the lens", "dark"),
    ("restore the rig for measuring", "sample"),
    ("Put the sample back", "sample"),
)


def gonio_argv(*args: str) -> list[str]:
    """The command line of ``gonio ARGS`` in this interpreter."""
    return [sys.executable, "-m", "gonio.cli", *args]


def set_keys(text: str, changes: dict[str, str]) -> str:
    """A TOML text with each ``key = value`` line whose key is in ``changes`` given the new (TOML) value."""
    out = text
    for key, value in changes.items():
        out, n = re.subn(rf"(?m)^({re.escape(key)}\s*=\s*)[^#\n]*?(\s*(#.*)?)$", rf"\g<1>{value}\g<2>", out, count=1)
        if n != 1:
            raise AssertionError(f"no line '{key} = ...' to change")
    return out


@dataclass
class Rehearsal:
    """A running ``gonio sim rig``; use as a context manager."""

    args: tuple[str, ...]
    frames: Path
    proc: subprocess.Popen[str] | None = None
    port: str = ""
    answers: list[str] = field(default_factory=list)

    def __enter__(self) -> Rehearsal:
        self.frames.mkdir(parents=True, exist_ok=True)
        self.proc = subprocess.Popen(
            gonio_argv("sim", "rig", *self.args, "--frames", str(self.frames)), stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, bufsize=1, cwd=ROOT,
        )  # fmt: skip
        self.port = self.read_line(START_TIMEOUT_S)
        if not self.port.startswith("/dev/"):
            raise AssertionError(f"gonio sim rig printed {self.port!r}, not a device path")
        return self

    def __exit__(self, *exc: object) -> None:
        assert self.proc is not None
        # Ctrl-D first (communicate closes its input): a shell without job control starts a background job
        # with SIGINT ignored, and a rehearsal started under one (a script run with `&`) would wait out the
        # timeout below at every stop if it were told with Ctrl-C only.
        try:
            self.proc.communicate(timeout=60)
            return
        except subprocess.TimeoutExpired:
            pass
        self.proc.send_signal(signal.SIGINT)
        try:
            self.proc.wait(timeout=60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        self.proc.communicate(timeout=60)

    def read_line(self, timeout_s: float) -> str:
        """The next stdout line of the rehearsal, waiting at most ``timeout_s`` seconds."""
        assert self.proc is not None and self.proc.stdout is not None
        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        if not sel.select(timeout_s):
            raise AssertionError(f"gonio sim rig said nothing within {timeout_s} s")
        line = self.proc.stdout.readline()
        if not line:
            err = self.proc.stderr.read() if self.proc.stderr else ""
            raise AssertionError(f"gonio sim rig ended (status {self.proc.poll()}): {err[-2000:]}")
        return line.strip()

    def say(self, command: str, timeout_s: float = START_TIMEOUT_S) -> str:
        """Type one line on the rehearsal's input and return its answer line."""
        assert self.proc is not None and self.proc.stdin is not None
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()
        answer = self.read_line(timeout_s)
        self.answers.append(answer)
        return answer

    def rig_file(self, template: Path | str, out: Path, **changes: str) -> Path:
        """The controller's rig file: ``template`` with port and folder pointed here (and ``changes``, TOML values)."""
        text = Path(template).read_text()
        text = set_keys(text, {"port": f'"{self.port}"', "folder": f'"{self.frames}"',
                               **{k: v for k, v in changes.items()}})  # fmt: skip
        out.write_text(text)
        return out


@dataclass
class Result:
    """What a gonio command did: its exit status, everything it printed, the prompts it asked."""

    status: int
    output: str
    prompts: list[str]


class Operator:
    """Runs gonio commands against a rehearsal and answers their prompts as a person at the rig."""

    def __init__(self, rehearsal: Rehearsal | None, cwd: Path) -> None:
        """``rehearsal`` None: a bare simulator (``gonio sim servos``), which has no scene to set."""
        self.rehearsal = rehearsal
        self.cwd = cwd

    def run(self, *args: str, interrupt_after: str | None = None, answer_yes: bool = False,
            timeout_s: float = COMMAND_TIMEOUT_S) -> Result:  # fmt: skip
        """Run ``gonio ARGS``; with ``interrupt_after``, send SIGINT once that text has been printed.

        ``answer_yes``: answer gonio's ``[y/N]`` questions (``gonio servo set-id`` ...) with y, as the person
        commissioning the rig does; otherwise they get Enter, which declines.
        """
        # This checkout's gonio whatever the working directory (an installed one elsewhere must not answer).
        path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONPATH": path}
        proc = subprocess.Popen(gonio_argv(*args), stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, cwd=self.cwd, env=env)  # fmt: skip
        assert proc.stdout is not None and proc.stdin is not None
        os.set_blocking(proc.stdout.fileno(), False)
        seen = b""
        answered = 0
        prompts: list[str] = []
        interrupted = False
        deadline = time.monotonic() + timeout_s
        sel = selectors.DefaultSelector()
        sel.register(proc.stdout, selectors.EVENT_READ)
        while True:
            if time.monotonic() > deadline:
                proc.kill()
                tail = seen.decode(errors="replace")[-3000:]
                raise AssertionError(f"gonio {' '.join(args)} did not end within {timeout_s} s:\n{tail}")
            sel.select(1.0)
            chunk = proc.stdout.read() or b""
            seen += chunk
            text = seen.decode(errors="replace")
            # A prompt ends its line with ": " and waits for Enter: one answer per prompt printed.
            asked = [m.group(0) for m in re.finditer(r"[^\n]*?(press Enter: |\[y/N\] )", text)]
            for prompt in asked[answered:]:
                scene = next((s for key, s in PROMPTS if key.lower() in prompt.lower()), None)
                if scene is not None:
                    assert self.rehearsal is not None, f"{prompt!r} asks for a scene, and no rehearsal serves one"
                    reply = self.rehearsal.say(f"scene {scene}")
                    assert reply == f"scene {scene}", reply
                prompts.append(prompt.strip())
                try:
                    proc.stdin.write(b"y\n" if answer_yes and prompt.endswith("[y/N] ") else b"\n")
                    proc.stdin.flush()
                except BrokenPipeError:
                    pass
                answered += 1
            if interrupt_after is not None and not interrupted and interrupt_after in text:
                proc.send_signal(signal.SIGINT)
                interrupted = True
            if not chunk and proc.poll() is not None:
                break
        return Result(proc.wait(), seen.decode(errors="replace"), prompts)
