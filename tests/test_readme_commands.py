"""Every command in the README runs as written on a fresh clone, in order, in a temporary copy of the tracked files.

Each command the README's shell blocks hold is classified below, and a command added to the README without a
class fails the suite. The classes:

- ``run``: run as written with bash in the copy (outputs of earlier commands are there); it must exit 0.
- ``serve``: a simulator that serves until Ctrl-C: started as written, its first line (the device path) must
  name a device that exists; ``sim rig`` is also asked for a frame on stdin. Then Ctrl-C (or end of input).
- ``dry``: parsed by gonio's own parser and its inputs checked where they will be, in order (rig and sweep files
  loaded and validated, sources a run directory or a MERL file, a Makefile target dry-run by ``make -n``),
  because running it would take long; the reason is given for each. ``GONIO_README_FULL=1`` runs these too,
  except those marked ``never`` (a placeholder host, the test suite itself, a study of many minutes).
- ``rehearse``: a hardware workflow (a ``gonio servo`` command, or one naming ``examples/rig_dynamixel.toml`` or
  ``examples/rig_grbl.toml``): run as written against a rehearsal of that rig file (``gonio sim rig --speed 20``,
  one per rig file for the module), with ``/dev/ttyUSB0`` / ``/dev/ttyACM0`` its port and the rig file a copy
  pointed at it (port and frames folder); it must exit 0. Every such command must be in this class.
- ``help``: not gonio's (Dask's servers on a lab's machines, with a placeholder address): the program and its
  subcommand must exist (``--help`` exits 0).

The full run (``GONIO_README_FULL=1 .venv/bin/pytest tests/test_readme_commands.py``) takes a few minutes.
"""

from __future__ import annotations

import contextlib
import glob
import os
import re
import select
import shlex
import shutil
import signal
import subprocess
import sys
import tomllib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from tests.rehearsal.harness import Operator, Rehearsal

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
FULL = os.environ.get("GONIO_README_FULL") == "1"
SLOW_S = 900.0  # generous: the suite runs on shared machines loaded several times over

HOW: dict[str, tuple[str, str]] = {
    "make demo": ("dry", "bootstraps .venv, then renders the demo; tests/gonio/test_cli.py runs the demo itself"),
    "make test": ("never", "is the test suite that runs this test"),
    ".venv/bin/gonio plan examples/sweep_in_plane.toml --rig examples/rig_simulated.toml": ("run", ""),
    ".venv/bin/gonio run examples/sweep_in_plane.toml --rig examples/rig_simulated.toml --out runs/gold": ("run", ""),
    ".venv/bin/gonio resume runs/gold": ("run", ""),
    ".venv/bin/gonio calibrate camera --rig examples/rig_simulated_raw.toml --out calib/": ("run", ""),
    ".venv/bin/gonio analyze runs/gold": ("run", ""),
    ".venv/bin/gonio analyze runs/gold --models lambert,ggx_conductor --merl --out runs/gold/analysis-ggx":
        ("dry", "a second analysis with a 35 MB MERL export, ~30 s; tests/analysis runs both"),
    ".venv/bin/gonio sim merl --out paint.binary": ("run", ""),
    ".venv/bin/gonio analyze paint.binary --samples 20000": ("run", ""),  # ~30 s of CPU: the MERL path as written
    ".venv/bin/gonio adaptive --rig examples/rig_simulated.toml --out runs/gold-adaptive --budget 100":
        ("dry", "100 captures in 9 rounds, ~35 s; tests/gonio/test_cli.py runs a budget of 12"),
    ".venv/bin/gonio adaptive --resume runs/gold-adaptive":
        ("dry", "continues the adaptive sweep above, not run; tests/rig/run/adaptive/test_adaptive.py resumes one"),
    ".venv/bin/gonio analyze runs/gold-adaptive":
        ("never", "analyses the adaptive sweep above, which is not run (dry), so there is nothing to check it on; "
                  "tests/analysis/test_sources.py analyses one"),
    ".venv/bin/gonio batch analyze runs/gold paint.binary --out batch/june --models lambert,lambert_ggx,ggx_conductor":
        ("dry", "a local Dask cluster and two analyses, a minute; tests/analysis/test_batch.py runs batches"),
    ".venv/bin/gonio batch study --out studies/tradeoff --seeds 5":
        ("never", "the whole sweep_tradeoff study, many minutes; tests/analysis/test_study.py runs a quick one"),
    ".venv/bin/gonio batch study --rig examples/rig_simulated.toml --sweep examples/sweep_grid.toml "
    "examples/sweep_rusinkiewicz.toml --out studies/gold":
        ("dry", "ten simulated runs and their fits on a Dask cluster; tests/analysis/test_study.py runs studies"),
    ".venv/bin/dask scheduler": ("help", "a long-lived server on a lab's machine"),
    ".venv/bin/dask worker tcp://HOST:8786 --nworkers 16 --nthreads 1": ("help", "HOST is a placeholder"),
    ".venv/bin/gonio batch analyze runs/* --out /shared/batch/june --scheduler tcp://HOST:8786":
        ("never", "HOST is a placeholder for a lab's scheduler, /shared a shared file system"),
    ".venv/bin/gonio sim servos --ids 1-4 --baud 1000000": ("serve", ""),
    ".venv/bin/gonio sim grbl --axes XYZ": ("serve", ""),
    ".venv/bin/gonio sim grbl --axes XYZA --homing": ("serve", ""),
    ".venv/bin/gonio sim rig --rig examples/rig_simulated.toml": ("serve", ""),
    ".venv/bin/gonio sim rig --rig examples/rig_dynamixel.toml --frames /tmp/tether --speed 10": ("serve", ""),
    ".venv/bin/gonio sim rig --rig examples/rig_misaligned.toml --link grbl --frames /tmp/tether "
    "--write-rig /tmp/lab.toml": ("serve", ""),
    ".venv/bin/gonio sim rig --rig examples/rig_simulated_grbl.toml": ("serve", ""),
    ".venv/bin/gonio sim rig --rig examples/rig_dynamixel.toml --frames out/rehearsal --speed 20": ("serve", ""),
    ".venv/bin/gonio servo check --port /dev/ttyUSB0 1 2 3 4": ("rehearse", ""),
    ".venv/bin/gonio servo move --rig examples/rig_dynamixel.toml light 0": ("rehearse", ""),
    ".venv/bin/gonio run examples/sweep_in_plane.toml --rig examples/rig_simulated_grbl.toml --out runs/gold-grbl":
        ("run", ""),
}  # fmt: skip
HOW[".venv/bin/gonio calibrate geometry --rig examples/rig_misaligned.toml --out calib"] = (
    "dry",
    "a ChArUco round of rendered HDR whole frames, minutes; issue 17's tests run the calibration",
)


#: The hardware rig files, and the ports they name: a command using one runs against a rehearsal of it.
HARDWARE_RIGS = {"examples/rig_dynamixel.toml": "/dev/ttyUSB0", "examples/rig_grbl.toml": "/dev/ttyACM0"}


def _blocks(lang: tuple[str, ...]) -> list[str]:
    text = README.read_text()
    return [m.group(2) for m in re.finditer(r"^```(\w*)\n(.*?)^```", text, re.S | re.M) if m.group(1) in lang]


def readme_commands() -> list[str]:
    """Each command line of the README's shell blocks, without its trailing comment, in README order."""
    lines = [line for block in _blocks(("", "sh", "shell", "bash")) for line in block.splitlines() if line.strip()]
    return [shlex.join(shlex.split(line, comments=True)) for line in lines]


def _key(command: str) -> str:
    return " ".join(shlex.split(command))


COMMANDS = readme_commands()


def test_every_readme_command_is_classified_and_every_class_is_used():
    unknown = [c for c in COMMANDS if _key(c) not in HOW]
    assert not unknown, f"README commands without a class in {Path(__file__).name}: {unknown}"
    stale = sorted(set(HOW) - {_key(c) for c in COMMANDS})
    assert not stale, f"classes for commands the README no longer has: {stale}"
    assert {how for how, _ in HOW.values()} == {"run", "serve", "dry", "never", "help", "rehearse"}
    # A hardware workflow is rehearsed, never only parsed (the rehearsal that serves it is no workflow).
    for command, (how, _reason) in HOW.items():
        words = command.split()
        hardware = words[1:2] == ["servo"] or any(w in HARDWARE_RIGS for w in words)
        assert (how == "rehearse") == (hardware and words[1:3] != ["sim", "rig"]), command


def test_the_readme_links_only_inside_the_repository():
    text = README.read_text()
    assert not re.findall(r"https?://", text), "the README points outside the repository"
    for target in re.findall(r"\]\(([^)]+)\)", text):
        assert (ROOT / target.split("#")[0]).exists(), target


def test_the_readme_toml_fragments_are_valid_rig_file_tables():
    from rig.run.config.files import parse
    from rig.run.config.schema import RigFile

    fragments = _blocks(("toml",))
    assert fragments
    for fragment in fragments:
        parse(tomllib.loads(fragment), RigFile, "README.md")  # ConfigError names the key if not


@pytest.fixture(scope="module")
def clone(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The tracked files (what a fresh clone holds) in a temporary directory, with this checkout's .venv."""
    dest = tmp_path_factory.mktemp("clone")
    files = None
    if (ROOT / ".git").exists() and shutil.which("git"):
        done = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=False)
        if done.returncode == 0:
            files = [f for f in done.stdout.decode().split("\0") if f]
    if files is None:  # not a git checkout: everything but what running gonio makes
        skip = {".venv", "runs", "out", "calib", "batch", "studies", ".git"}
        files = [str(p.relative_to(ROOT)) for p in ROOT.rglob("*") if p.is_file()
                 and not skip & set(p.relative_to(ROOT).parts) and "__pycache__" not in p.parts]  # fmt: skip
    for name in files:
        source = ROOT / name
        if source.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, dest / name)
    (dest / ".venv").symlink_to(Path(sys.prefix))
    return dest


def _run(command: str, cwd: Path) -> None:
    done = subprocess.run(["bash", "-c", command], cwd=cwd, capture_output=True, text=True, timeout=SLOW_S,
                          check=False)  # fmt: skip
    assert done.returncode == 0, f"{command}\nexit {done.returncode}\n{done.stderr[-3000:]}"


def _readline(proc: subprocess.Popen[str], timeout_s: float) -> str:
    assert proc.stdout is not None
    ready, _, _ = select.select([proc.stdout], [], [], timeout_s)
    assert ready, "no line from the simulator"
    return proc.stdout.readline().strip()


def _serve(command: str, cwd: Path) -> None:
    proc = subprocess.Popen(["bash", "-c", f"exec {command}"], cwd=cwd, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        port = _readline(proc, SLOW_S)
        assert Path(port).exists(), f"{command}: first line {port!r} is not a device"
        if " sim rig " in f" {command} ":
            assert proc.stdin is not None
            proc.stdin.write("capture 0.01\n")
            proc.stdin.flush()
            frame = _readline(proc, SLOW_S)
            assert frame.endswith(".dng") and (cwd / frame).stat().st_size > 0, frame
            proc.stdin.close()  # end of input stops it
        else:
            proc.send_signal(signal.SIGINT)
        code = proc.wait(timeout=SLOW_S)
        assert code in (0, 130), f"{command}: exit {code}\n{proc.stderr.read() if proc.stderr else ''}"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def _inputs(args: Any, cwd: Path) -> None:
    """The files a parsed gonio command reads must be where the README's earlier commands left them."""
    from rig.run.config.files import load_rig, load_sweep

    def listed(name: str) -> list[str]:
        value = getattr(args, name, None)
        return [] if value is None else [value] if isinstance(value, str) else list(value)

    for rig in listed("rig"):
        load_rig(cwd / rig)
    for sweep in listed("sweep"):
        load_sweep(cwd / sweep)
    for source in listed("source") + listed("sources") + listed("compare"):
        path = cwd / source
        if path.suffix == ".binary":
            assert path.is_file() and path.read_bytes()[:12] == bytes.fromhex("5a0000005a000000b4000000"), path
        else:
            assert (path / "manifest.json").is_file(), f"{source}: not a run directory where the command runs"


def _dry(command: str, cwd: Path) -> None:
    from gonio.cli import build_parser

    argv = shlex.split(command, comments=True)
    if argv[0] == "make":
        done = subprocess.run(["make", "-n", *argv[1:]], cwd=cwd, capture_output=True, text=True, check=False)
        assert done.returncode == 0, done.stderr
        return
    assert argv[0] == ".venv/bin/gonio" and (cwd / argv[0]).exists(), command
    words = [w for arg in argv[1:] for w in (sorted(glob.glob(arg, root_dir=cwd)) or [arg] if "*" in arg else [arg])]
    args = build_parser().parse_args(words)  # a bad option or subcommand exits: the test fails
    _inputs(args, cwd)


@pytest.fixture(scope="module")
def rehearsals(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, tuple[Rehearsal, Path]]]:
    """Per hardware rig file, started on first use: its rehearsal and the copy of the file pointed at it."""
    with contextlib.ExitStack() as stack:
        yield _Rehearsals(tmp_path_factory.mktemp("rehearsal"), stack)


class _Rehearsals(dict[str, tuple[Rehearsal, Path]]):
    def __init__(self, base: Path, stack: contextlib.ExitStack) -> None:
        super().__init__()
        self.base, self.stack = base, stack

    def __missing__(self, rig: str) -> tuple[Rehearsal, Path]:
        where = self.base / Path(rig).stem
        reh = self.stack.enter_context(Rehearsal(("--rig", str(ROOT / rig), "--speed", "20"), where / "frames"))
        self[rig] = (reh, reh.rig_file(ROOT / rig, where / Path(rig).name))
        return self[rig]


def _rehearse(command: str, cwd: Path, rehearsals: dict[str, tuple[Rehearsal, Path]]) -> None:
    """Run a hardware workflow as written against a rehearsal of its rig file (the Dynamixel one for a port)."""
    argv = shlex.split(command, comments=True)
    assert argv[0] == ".venv/bin/gonio", command
    rig = next((w for w in argv if w in HARDWARE_RIGS), None)
    if rig is None:
        port = next(w for w in argv if w in HARDWARE_RIGS.values())
        rig = next(r for r, p in HARDWARE_RIGS.items() if p == port)
    reh, copy = rehearsals[rig]
    words = [str(copy) if w == rig else reh.port if w in HARDWARE_RIGS.values() else w for w in argv[1:]]
    done = Operator(reh, cwd).run(*words, answer_yes=True)
    assert done.status == 0, f"{command} (on {reh.port})\nexit {done.status}\n{done.output[-3000:]}"


@pytest.mark.slow
@pytest.mark.mitsuba
@pytest.mark.parametrize("index", range(len(COMMANDS)), ids=[c[:70] for c in COMMANDS])
def test_readme_command_runs_as_written(index: int, clone: Path, rehearsals: dict[str, tuple[Rehearsal, Path]]) -> None:
    command = COMMANDS[index]
    how, _reason = HOW[_key(command)]
    if how == "run" or (how == "dry" and FULL):
        _run(command, clone)
    elif how == "serve":
        _serve(command, clone)
    elif how == "rehearse":
        _rehearse(command, clone, rehearsals)
    elif how in ("dry", "never"):
        if how == "never" and not command.startswith("make"):
            from gonio.cli import build_parser

            # It parses; its inputs are placeholders or come from a command that is not run.
            build_parser().parse_args(shlex.split(command, comments=True)[1:])
        else:
            _dry(command, clone)
    else:
        argv = shlex.split(command)
        done = subprocess.run([argv[0], argv[1], "--help"], cwd=clone, capture_output=True, check=False)
        assert done.returncode == 0, command


@pytest.mark.slow
@pytest.mark.mitsuba
def test_what_the_readme_commands_write_is_ignored_by_git(clone: Path) -> None:
    """After the commands above ran in the copy, everything they made there is in .gitignore."""
    if not ((ROOT / ".git").exists() and shutil.which("git")):
        pytest.skip("not a git checkout")
    listed = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout
    tracked = {line.split("/")[0] for line in listed.splitlines()}
    made = [p.name + ("/" if p.is_dir() else "") for p in clone.iterdir() if p.name not in tracked | {".venv"}]
    if not made:
        pytest.skip("run with the command tests: nothing was made in the copy yet")
    done = subprocess.run(["git", "check-ignore", "--no-index", *made], cwd=ROOT, capture_output=True, text=True,
                          check=False)  # fmt: skip
    ignored = set(done.stdout.split())
    assert ignored == set(made), f"made by the README's commands and not in .gitignore: {sorted(set(made) - ignored)}"
