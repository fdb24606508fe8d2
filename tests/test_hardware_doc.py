"""docs/hardware.md quotes only what is real: its commands run on a rehearsal, its files load, its output is gonio's.

Every command of the guide's shell blocks has a class in ``HOW`` (one added to the guide without a class fails):

- ``serve``: a simulator the guide starts; the test starts it from that very line and keeps it for the module
  (``gonio sim rig`` with the shipped rig file replaced by a copy with a smaller ROI, see ``SMALL_ROI``, and
  its frames in a temporary folder; ``gonio sim servos`` as written).
- ``run``: run as written against what the ``serve`` line named beside it serves, in the guide's order, in a
  working directory where ``examples/rig_dynamixel.toml`` / ``examples/rig_grbl.toml`` are copies pointed at
  the rehearsal (its port and frames folder, the served file's ROI, and ``SNAPPY``: nothing else changed)
  and ``/dev/ttyUSB0`` / ``/dev/ttyACM0`` are the rehearsal's port, as section 0 tells a newcomer. Its
  prompts are answered as a person at the rig would (the harness sets the scene, then presses Enter; y to
  a question). Each must exit 0 and leave what the guide says it does.
- ``parsed``: needs a person with root on real hardware (sudo, a USB adapter's sysfs); the reason is given.
  Its programs must be the system tools the guide explains, its sysfs path where gonio reads.

The ``gonio servo`` commands quoted inline that name a port or a rig file run against the Dynamixel rehearsal
too (but those in ``INLINE_PARSED``, with the reason); the other inline quotes must name real subcommands
(and parse, where they give more than the name).
Each line of a ``text`` block is a message gonio prints, generated here from the code (a fake sysfs tree
for the latency timer); the udev rule sets the timer gonio recommends on the bus gonio reads it from; and
every link leads to a file and heading of the repository.

One file past 400 lines on purpose: it mirrors one document, docs/hardware.md, in its order.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import re
import selectors
import shlex
import shutil
import signal
import subprocess
import tomllib
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace

import pytest

from tests.rehearsal.harness import PROMPTS, START_TIMEOUT_S, Operator, Rehearsal, Result, gonio_argv, set_keys

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "hardware.md"
TEXT = DOC.read_text()
GONIO = ".venv/bin/gonio"
#: The system tools the guide's shell blocks use besides gonio (what each is for is said beside it).
TOOLS = {"ls", "sudo", "cat", "echo", "tee", "udevadm", "usermod"}
#: The ports the guide names, and the rig files: each stands for the rehearsal's.
PORTS = {"/dev/ttyUSB0": "dynamixel", "/dev/ttyACM0": "grbl"}
RIGS = {"dynamixel": "examples/rig_dynamixel.toml", "grbl": "examples/rig_grbl.toml"}
#: The rehearsal's sensor is sized from the rig file's ROI: the shipped [2000, 1300, 2200, 1500] makes it
#: 4200 x 2800, and the calibrations read whole frames (minutes each). The Dynamixel rehearsal runs the
#: geometry calibration, which wants >= 20 px per 6 mm board square: a 512 x 384 sensor. The GRBL one only
#: measures a sweep: 256 x 192. Section 0 of the guide says the same to a user.
SMALL_ROI = {"dynamixel": "[248, 184, 264, 200]", "grbl": "[120, 88, 136, 104]"}

#: The folder camera waits until a frame's size has held for ``stable_polls`` polls ``poll_interval_s`` apart
#: (2 and 0.1 s by default: ~0.2 s a frame, half a minute of a camera calibration's 156 frames). The
#: rehearsal writes each DNG under a temporary name and renames it, complete at once, for which the camera's
#: documentation says one poll is enough; so the copies poll once, every 20 ms, as section 0 allows.
SNAPPY = "stable_polls = 1\npoll_interval_s = 0.02"

_SUDO_ONLY = "needs root on the rig's computer"
_SYSFS = ("an FTDI adapter's sysfs file: the rehearsal's port is a pseudo-terminal, which has no latency timer "
          "(test_the_other_shell_commands_... reads a fake one where gonio reads it)")  # fmt: skip
#: Each shell command of the guide: (class, what it runs against or why it is only parsed).
HOW: dict[str, tuple[str, str]] = {
    f"{GONIO} sim rig --rig examples/rig_dynamixel.toml --frames rehearsal/frames --speed 20": ("serve", "dynamixel"),
    f"{GONIO} sim servos --ids 1 --baud 57600": ("serve", "new servo"),
    f"{GONIO} sim servos --ids 1-4 --baud 57600": ("serve", "new chain"),
    "ls -l /dev/ttyUSB0": ("run", "dynamixel"),
    "sudo usermod -aG dialout $USER": ("parsed", f"{_SUDO_ONLY}, and changes the user's groups"),
    f"{GONIO} servo check --port /dev/ttyUSB0": ("run", "dynamixel"),
    "sudo udevadm control --reload-rules": ("parsed", f"{_SUDO_ONLY} and a USB adapter for the rule to match"),
    "sudo udevadm trigger --action=add": ("parsed", f"{_SUDO_ONLY} and a USB adapter for the rule to match"),
    "cat /sys/bus/usb-serial/devices/ttyUSB0/latency_timer": ("parsed", _SYSFS),
    "echo 1 | sudo tee /sys/bus/usb-serial/devices/ttyUSB0/latency_timer": ("parsed", f"{_SUDO_ONLY}; {_SYSFS}"),
    f"{GONIO} servo scan --port /dev/ttyUSB0 --bauds 57600 1000000": ("run", "dynamixel"),
    f"{GONIO} servo set-id --port /dev/ttyUSB0 --baud 57600 1 2": ("run", "new servo"),
    f"{GONIO} servo set-baud --port /dev/ttyUSB0 --baud 57600 1 2 3 4 1000000": ("run", "new chain"),
    f"{GONIO} servo ping --port /dev/ttyUSB0 --baud 1000000 1 2 3 4": ("run", "dynamixel"),
    f"{GONIO} servo check --port /dev/ttyUSB0 --latency-ms 1 1 2 3 4": ("run", "dynamixel"),
    f"{GONIO} calibrate camera --rig examples/rig_dynamixel.toml --out calib/": ("run", "dynamixel"),
    f"{GONIO} calibrate geometry --rig examples/rig_dynamixel.toml --out calib/": ("run", "dynamixel"),
    f"{GONIO} plan examples/sweep_grid.toml --rig examples/rig_dynamixel.toml": ("run", "dynamixel"),
    f"{GONIO} run examples/sweep_grid.toml --rig examples/rig_dynamixel.toml --out runs/first": ("run", "dynamixel"),
    f"{GONIO} resume runs/first": ("run", "dynamixel"),
    f"{GONIO} run examples/sweep_image.toml --rig examples/rig_dynamixel.toml --out runs/image": ("run", "dynamixel"),
    f"{GONIO} analyze runs/first": ("run", "dynamixel"),
    f"{GONIO} sim rig --rig examples/rig_grbl.toml --frames rehearsal/frames --speed 20": ("serve", "grbl"),
    f"{GONIO} servo check --port /dev/ttyACM0": ("run", "grbl"),
    f"{GONIO} plan examples/sweep_grid.toml --rig examples/rig_grbl.toml": ("run", "grbl"),
    f"{GONIO} run examples/sweep_grid.toml --rig examples/rig_grbl.toml --out runs/first-grbl": ("run", "grbl"),
}  # fmt: skip


def _blocks(lang: str) -> list[str]:
    return [m.group(2) for m in re.finditer(r"^```(\w*)\n(.*?)^```", TEXT, re.S | re.M) if m.group(1) == lang]


def _shell_lines() -> list[list[str]]:
    return [shlex.split(line, comments=True) for block in _blocks("") for line in block.splitlines() if line.strip()]


def _inline_gonio() -> list[list[str]]:
    spans = re.findall(r"`(gonio [^`]+)`", re.sub(r"```.*?```", "", TEXT, flags=re.S))
    return [shlex.split(" ".join(span.split()))[1:] for span in spans]


def _key(argv: list[str]) -> str:
    return " ".join(argv)


def _parser() -> argparse.ArgumentParser:
    from gonio.cli import build_parser

    return build_parser()


def _commands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The subcommands a parser takes, by name (none for a leaf command)."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(subs[0].choices) if subs else {}


def _parse(words: list[str]) -> argparse.Namespace:
    try:
        return _parser().parse_args(words)
    except SystemExit as exc:
        raise AssertionError(
            f"docs/hardware.md: `gonio {shlex.join(words)}` does not parse (exit {exc.code})"
        ) from None


SHELL = _shell_lines()
GONIO_LINES = [argv[1:] for argv in SHELL if argv[0] == GONIO]


def test_the_guide_has_commands_for_each_step():
    assert len(GONIO_LINES) >= 10
    steps = {("servo", "scan"), ("servo", "set-id"), ("servo", "set-baud"), ("servo", "ping"), ("servo", "check"),
             ("calibrate", "camera"), ("calibrate", "geometry"), ("plan", "examples/sweep_grid.toml")}  # fmt: skip
    assert {tuple(w[:2]) for w in GONIO_LINES} >= steps


def _check_files(args: argparse.Namespace) -> None:
    from rig.run.config.files import load_rig, load_sweep

    if isinstance(getattr(args, "sweep", None), str):
        load_sweep(ROOT / args.sweep)  # ConfigError names the file and key if the guide's file is wrong
    if isinstance(getattr(args, "rig", None), str):
        rig = load_rig(ROOT / args.rig)
        if getattr(args, "joint", None) is not None:  # gonio servo move: a joint of that rig file
            assert args.joint in [a.name for a in rig.axes], f"{args.rig} has no joint {args.joint!r}"


@pytest.mark.parametrize("words", GONIO_LINES, ids=[" ".join(w)[:60] for w in GONIO_LINES])
def test_each_gonio_command_of_the_shell_blocks_parses_and_its_files_load(words: list[str], monkeypatch) -> None:
    _check_files(_parse(words))
    if words[0] == "plan":  # the one step that needs no hardware: it runs as written
        from gonio import cli

        monkeypatch.chdir(ROOT)
        assert cli.main(words) == 0


def test_the_other_shell_commands_are_the_system_tools_the_guide_explains(tmp_path):
    from rig.instrument.links.usb_serial import read_latency_timer

    others = [argv for argv in SHELL if argv[0] != GONIO]
    assert others
    for argv in others:
        programs = {argv[0]} | {argv[i + 1] for i, w in enumerate(argv[:-1]) if w in ("|", "&&", "sudo")}
        assert programs <= TOOLS, f"docs/hardware.md: {shlex.join(argv)} runs {programs - TOOLS}"
    # The sysfs file the guide reads and writes is the one gonio reads: a fake tree holding it there.
    sysfs = sorted({w for argv in others for w in argv if w.startswith("/sys/")})
    assert sysfs
    for path in sysfs:
        fake = tmp_path / path.removeprefix("/sys/")
        fake.parent.mkdir(parents=True, exist_ok=True)
        fake.write_text("16\n")
        timer = read_latency_timer(f"/dev/{fake.parent.name}", tmp_path)
        assert timer is not None and timer.path == fake and timer.value_ms == 16, path


INLINE = _inline_gonio()


@pytest.mark.parametrize("words", INLINE, ids=[" ".join(w)[:60] for w in INLINE])
def test_each_gonio_command_quoted_inline_is_real(words: list[str]) -> None:
    parser, depth = _parser(), 0
    for word in words:  # the command's name: each word a subcommand of the one before
        commands = _commands(parser)
        if not commands:
            break
        assert word in commands, f"docs/hardware.md: `gonio {' '.join(words)}`: no command {word!r}"
        parser, depth = commands[word], depth + 1
    if depth < len(words):  # more than a command's name: it must parse as given, and its files load
        _check_files(_parse(words))


def _doc_commands() -> list[tuple[int, list[str], bool]]:
    """Every command of the guide with its place in the text: (offset, argv, quoted inline)."""
    found: list[tuple[int, list[str], bool]] = []
    for block in re.finditer(r"^```(\w*)\n(.*?)^```", TEXT, re.S | re.M):
        if block.group(1) == "":
            for line in re.finditer(r"^.*\S.*$", block.group(2), re.M):
                found.append((block.start(2) + line.start(), shlex.split(line.group(0), comments=True), False))
    prose = re.sub(r"```.*?```", lambda m: " " * len(m.group(0)), TEXT, flags=re.S)  # offsets kept
    for span in re.finditer(r"`(gonio [^`]+)`", prose):
        found.append((span.start(), [GONIO, *shlex.split(" ".join(span.group(1).split()))[1:]], True))
    return sorted(found, key=lambda c: c[0])


#: Inline ``gonio servo`` commands that name a port or a rig file and are only parsed, each with the reason.
INLINE_PARSED = {
    f"{GONIO} servo scan --port /dev/ttyUSB0 --bauds 9600 57600 115200 1000000 2000000 --ping-each": (
        "5 rates x 20 ids, each silent one retried with doubling reply windows: ~35 s on the rehearsal; section 4's "
        "broadcast scan runs on it"
    ),
}


def _inline_where(argv: list[str]) -> str | None:
    """What an inline ``gonio servo`` command that names a port or a rig file runs against (None: not run)."""
    if argv[1] != "servo" or not {"--port", "--rig"} & set(argv) or _key(argv) in INLINE_PARSED:
        return None
    return "grbl" if "/dev/ttyACM0" in argv or RIGS["grbl"] in argv else "dynamixel"


def test_every_shell_command_of_the_guide_has_a_class_and_every_class_is_used():
    keys = [_key(argv) for argv in SHELL]
    unknown = [k for k in keys if k not in HOW]
    assert not unknown, f"docs/hardware.md commands without a class in {Path(__file__).name}: {unknown}"
    stale = sorted(set(HOW) - set(keys))
    assert not stale, f"classes for commands docs/hardware.md no longer has: {stale}"
    assert {how for how, _ in HOW.values()} == {"serve", "run", "parsed"}
    inline = {_key(argv) for _offset, argv, quoted in _doc_commands() if quoted}
    assert set(INLINE_PARSED) <= inline, f"parsed-only inline commands the guide no longer has: {INLINE_PARSED}"
    served = {where for how, where in HOW.values() if how == "serve"}
    assert {where for how, where in HOW.values() if how == "run"} <= served
    # Whatever needs a person with root, and only that, is left unrun.
    for key, (how, _why) in HOW.items():
        assert (how == "parsed") == (key.startswith(("sudo", "cat /sys", "echo")) or " sudo " in key), key


def _serve_line(where: str) -> list[str]:
    (line,) = [k for k, (how, w) in HOW.items() if how == "serve" and w == where]
    return shlex.split(line)


class Lab:
    """What the guide's ``serve`` lines start, each on first use and kept until the module ends."""

    def __init__(self, base: Path, stack: contextlib.ExitStack) -> None:
        self.base, self.stack = base, stack
        self.work = base / "work"  # where the guide's commands run, as from a checkout
        (self.work / "examples").mkdir(parents=True)
        for sweep in ("sweep_grid.toml", "sweep_image.toml"):
            shutil.copy(ROOT / "examples" / sweep, self.work / "examples")
        self.ports: dict[str, str] = {}
        self.rehearsals: dict[str, Rehearsal] = {}

    def port(self, where: str) -> str:
        if where not in self.ports:
            argv = _serve_line(where)
            if argv[1:3] == ["sim", "rig"]:
                self._rehearse(where, argv)
            else:
                self.ports[where] = self.stack.enter_context(_serving(argv[1:]))
        return self.ports[where]

    def _rehearse(self, link: str, argv: list[str]) -> None:
        args = dict(zip(argv[3::2], argv[4::2], strict=True))
        shipped = ROOT / args["--rig"]
        served = self.base / link / shipped.name  # the served file: the shipped one, with a smaller ROI
        served.parent.mkdir()
        served.write_text(set_keys(shipped.read_text(), {"roi": SMALL_ROI[link]}))
        reh = self.stack.enter_context(
            Rehearsal(("--rig", str(served), "--speed", args["--speed"]), self.base / link / "frames")
        )
        # Section 0: a copy of the rig file with its port and folder pointed at the rehearsal, and (SNAPPY) the
        # folder camera told how the rehearsal writes its frames.
        copy = reh.rig_file(served, self.work / args["--rig"])
        copy.write_text(re.sub(r"(?m)^folder = .*$", lambda m: f"{m.group(0)}\n{SNAPPY}", copy.read_text(), count=1))
        self.ports[link], self.rehearsals[link] = reh.port, reh

    def operator(self, where: str) -> Operator:
        self.port(where)
        return Operator(self.rehearsals.get(where), self.work)


@contextlib.contextmanager
def _serving(words: list[str]) -> Iterator[str]:
    """``gonio WORDS`` (a simulator that prints its port, then serves until Ctrl-C) for the ``with`` block."""
    proc = subprocess.Popen(gonio_argv(*words), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert proc.stdout is not None
        sel = selectors.DefaultSelector()
        sel.register(proc.stdout, selectors.EVENT_READ)
        assert sel.select(START_TIMEOUT_S), f"gonio {shlex.join(words)} printed no port"
        port = proc.stdout.readline().strip()
        assert port.startswith("/dev/") and Path(port).exists(), f"gonio {shlex.join(words)}: {port!r}"
        yield port
    finally:
        proc.send_signal(signal.SIGINT)
        try:
            proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()


@pytest.fixture(scope="module")
def lab(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Lab]:
    with contextlib.ExitStack() as stack:
        yield Lab(tmp_path_factory.mktemp("rehearsal"), stack)


def _sequence(wheres: set[str]) -> list[tuple[str, list[str], str]]:
    """The commands that run against ``wheres``, in the guide's order: (key, argv, where)."""
    out = []
    for _offset, argv, inline in _doc_commands():
        if inline:
            where = _inline_where(argv)
        else:
            how, where = HOW[_key(argv)]
            where = where if how == "run" else None
        if where in wheres:
            out.append((_key(argv), argv, where))
    return out


def _rows(table: Path) -> list[dict[str, str]]:
    with table.open(newline="") as f:
        return list(csv.DictReader(f))


def _scenes(done: Result) -> list[str]:
    """The scenes the operator set for a command's prompts, in order."""
    return [scene for p in done.prompts for key, scene in PROMPTS if key.lower() in p.lower()]


def _check(key: str, done: Result, work: Path) -> None:
    """What the guide says each command does, seen in what it printed and wrote."""
    out = done.output
    ids = range(1, 5)
    if " servo scan " in key:
        assert all(re.search(rf"id\s+{i}\s+1000000 baud", out) for i in ids), out
    elif " servo set-id " in key:
        assert "servo 1 is now id 2" in out, out
    elif " servo set-baud " in key:
        assert "servos 1, 2, 3, 4 now answer at 1000000 baud" in out, out
    elif " servo ping " in key or (" servo check " in key and key.endswith(" 1 2 3 4")):
        assert all(re.search(rf"id\s+{i}: found", out) for i in ids), out
    elif " servo check " in key:
        assert "readable and writable by you" in out and "no USB latency timer" in out, out
    elif " servo status " in key:
        listed = [int(w) for w in key.split()[key.split().index("--port") + 2 :]]
        assert all(re.search(rf"id\s+{i}: position", out) for i in listed), out
    elif " servo move " in key:
        from rig.run.config.files import load_rig

        joint, angle = key.split()[-2:]
        rig = load_rig(work / key.split()[key.split().index("--rig") + 1])
        (tolerance,) = [a.tolerance_deg for a in rig.axes if a.name == joint]
        reached = re.search(rf"\b{joint} (-?[\d.]+) deg", out)
        assert reached and abs(float(reached.group(1)) - float(angle)) <= tolerance, out
    elif " calibrate camera " in key:
        made = {p.name for p in (work / "calib").iterdir()}
        assert {"camera_calibration.json", "flat_field.npz", "photon_transfer.png"} <= made, out
        assert _scenes(done) == ["flat", "dark", "sample"], done.prompts
    elif " calibrate geometry " in key:
        calibration = json.loads((work / "calib" / "geometry_calibration.json").read_text())
        assert "light_zero_deg" in json.dumps(calibration), out
        assert _scenes(done) == ["board", "sample"], done.prompts
    elif " plan " in key:
        assert "Sweep of 20 points: 20 to measure, 0 unreachable" in out, out
    elif " analyze " in key:
        assert (work / key.split()[-1] / "analysis" / "index.html").is_file(), out
    elif " run examples/sweep_image.toml " in key:
        # One row per tile, on the sensor the run learnt from the camera's first whole frame.
        assert "measured 5 points (0 from before)" in out, out
        rows = _rows(work / "runs" / "image" / "samples.csv")
        points = [json.loads(line) for line in (work / "runs" / "image" / "journal.jsonl").read_text().splitlines()]
        sensors = {tuple(r["sensor_px"]) for r in points if r["kind"] == "point"}
        assert sensors == {(512, 384)} and len(rows) >= 5 * 20 and rows[0]["tile"], (sensors, len(rows))
    elif " run " in key or " resume " in key:
        out_dir = work / (key.split()[-1] if " resume " in key else key.split()[key.split().index("--out") + 1])
        counts = re.search(r"measured (\d+) points \((\d+) from before\)", out)
        assert counts and int(counts.group(1)) + int(counts.group(2)) == 20, out
        assert int(counts.group(2)) > 0 if " resume " in key else int(counts.group(2)) == 0, out
        assert len(_rows(out_dir / "samples.csv")) == 20
    else:
        raise AssertionError(f"{key}: no check of what it does")


def _run(lab: Lab, key: str, argv: list[str], where: str) -> None:
    port = lab.port(where)
    argv = [port if w in PORTS else w for w in argv]
    if argv[0] != GONIO:  # ls -l PORT: the port is there, a character device
        listed = subprocess.run(argv, capture_output=True, text=True, check=False, timeout=60)
        assert listed.returncode == 0 and listed.stdout.startswith("c") and port in listed.stdout, listed
        return
    words = argv[1:]
    op = lab.operator(where)
    if words[0] == "run" and where == "dynamixel" and "runs/first" in words:
        # Section 8: Ctrl-C halfway through the first sweep, then the guide's `gonio resume runs/first` ends it.
        stopped = op.run(*words, interrupt_after="5/20")
        assert stopped.status == 130, stopped.output[-3000:]
        journal = lab.work / words[words.index("--out") + 1] / "journal.jsonl"
        assert journal.is_file() and journal.read_text().strip(), stopped.output[-3000:]
        return
    done = op.run(*words, answer_yes=True)
    assert done.status == 0, f"{key} (on {port}): exit {done.status}\n{done.output[-3000:]}"
    _check(key, done, lab.work)


@pytest.mark.slow
@pytest.mark.mitsuba
def test_the_dynamixel_commissioning_runs_as_written_against_a_rehearsal(lab: Lab) -> None:
    sequence = _sequence({"dynamixel", "new servo", "new chain"})
    assert {(w, k.split()[2]) for k, _a, w in sequence if k.startswith(GONIO)} >= {
        ("dynamixel", "check"),
        ("dynamixel", "scan"),
        ("dynamixel", "ping"),
        ("dynamixel", "status"),
        ("dynamixel", "move"),
        ("new servo", "set-id"),
        ("new chain", "set-baud"),
    }
    for key, argv, where in sequence:
        _run(lab, key, argv, where)


@pytest.mark.slow
@pytest.mark.mitsuba
def test_the_grbl_section_runs_as_written_against_a_grbl_rehearsal(lab: Lab) -> None:
    sequence = _sequence({"grbl"})
    assert [k.split()[1] for k, _a, _w in sequence if not k.startswith(GONIO)] == []
    assert {k.split()[1] for k, _a, _w in sequence} == {"servo", "plan", "run"}
    for key, argv, where in sequence:
        _run(lab, key, argv, where)


def _latency_messages(tmp_path: Path) -> list[str]:
    from rig.instrument.links.usb_serial import latency_advice, read_latency_timer

    device = tmp_path / "sys" / "bus" / "usb-serial" / "devices" / "ttyUSB0"
    device.mkdir(parents=True)
    (device / "latency_timer").write_text("16\n")
    timer = read_latency_timer("/dev/ttyUSB0", tmp_path / "sys")
    messages = [latency_advice(timer, configured) for configured in (16.0, 1.0)]
    return [str(m).replace(str(tmp_path / "sys"), "/sys") for m in messages]


def _permission_message(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> str:
    from gonio import cli, cli_servo

    # A serial port (a pseudo-terminal: check refuses a plain file as no serial port).
    master, slave = os.openpty()
    try:
        port = os.ttyname(slave)
        # Tests run as root here, who may open anything: the check is shown a port it may not open, owned by dialout.
        monkeypatch.setattr(cli_servo.os, "access", lambda *a, **k: False)
        monkeypatch.setattr(cli_servo.grp, "getgrgid", lambda gid: SimpleNamespace(gr_name="dialout"))
        monkeypatch.setenv("GONIO_SYSFS", str(tmp_path / "no-sysfs"))
        assert cli.main(["servo", "check", "--port", port]) == 3
    finally:
        os.close(master)
        os.close(slave)
    line = next(x for x in capsys.readouterr().out.splitlines() if "you may not open it" in x)
    return line.replace(port, "/dev/ttyUSB0")


def test_every_output_line_the_guide_quotes_is_what_gonio_prints(tmp_path, monkeypatch, capsys):
    printed = [*_latency_messages(tmp_path), _permission_message(tmp_path, monkeypatch, capsys)]
    quoted = [line for block in _blocks("text") for line in block.splitlines() if line.strip()]
    assert len(quoted) == 3
    for line in quoted:
        shown = line.removesuffix("...")  # a quote may end early with "..."
        assert any(p.startswith(shown) if line.endswith("...") else p == line for p in printed), line
    # The fix each latency warning names is the guide's own command, and the udev rule it points to is here.
    for message in printed[:2]:
        fix = re.search(r"`(echo .*?)`", message)
        assert fix and fix.group(1) in TEXT and "udev rule in docs/hardware.md" in message


def test_the_udev_rule_sets_the_timer_gonio_recommends_where_gonio_reads_it():
    from rig.instrument.links.usb_serial import RECOMMENDED_MS

    (rules,) = _blocks("udev")
    latency = next(line for line in rules.splitlines() if "latency_timer" in line)
    assert 'SUBSYSTEM=="usb-serial"' in latency  # the bus of /sys/bus/usb-serial/devices/<tty>/latency_timer
    assert re.search(r'ATTR\{latency_timer\}="(\d+)"', latency).group(1) == str(RECOMMENDED_MS)  # type: ignore[union-attr]
    assert 'GROUP="dialout"' in rules


def test_the_toml_fragments_are_valid_rig_file_tables():
    from rig.run.config.files import parse
    from rig.run.config.schema import RigFile

    fragments = _blocks("toml")
    assert fragments
    for fragment in fragments:
        parse(tomllib.loads(fragment), RigFile, "docs/hardware.md")


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_every_link_leads_to_a_file_and_heading_of_the_repository():
    assert not re.findall(r"https?://", TEXT), "the guide points outside the repository"
    links = re.findall(r"\]\(([^)]+)\)", TEXT)
    assert links
    for link in links:
        target, _, anchor = link.partition("#")
        path = (DOC.parent / target).resolve()
        assert path.is_file() and ROOT in path.parents, link
        if anchor:
            slugs = {_slug(h) for h in re.findall(r"^#+ (.+)$", path.read_text(), re.M)}
            assert anchor in slugs, f"{link}: no such heading in {target}"
    readme = (ROOT / "README.md").read_text()
    assert "](docs/hardware.md)" in readme
