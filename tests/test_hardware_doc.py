"""docs/hardware.md quotes only what is real: its commands parse, its files load, its output is gonio's.

The commissioning guide's commands need hardware (a port such as /dev/ttyUSB0, a person at the rig), so
only ``gonio plan`` (which moves nothing) is run here. Each other gonio command of a shell block is parsed
by gonio's own parser, and the rig and sweep files it names are loaded and validated (a joint named must
be the rig's); each gonio command quoted inline names real subcommands (and parses, where it gives more
than the subcommand); the other programs of the shell blocks are the system tools the guide explains and
its sysfs path is where gonio reads; each line of a ``text`` block is a message gonio prints, generated
here from the code (a fake sysfs tree for the latency timer); the udev rule sets the timer gonio
recommends on the bus gonio reads it from; and every link leads to a file and heading of the repository.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import tomllib
from pathlib import Path
from types import SimpleNamespace

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "hardware.md"
TEXT = DOC.read_text()
GONIO = ".venv/bin/gonio"
#: The system tools the guide's shell blocks use besides gonio (what each is for is said beside it).
TOOLS = {"ls", "sudo", "cat", "echo", "tee", "udevadm", "usermod"}


def _blocks(lang: str) -> list[str]:
    return [m.group(2) for m in re.finditer(r"^```(\w*)\n(.*?)^```", TEXT, re.S | re.M) if m.group(1) == lang]


def _shell_lines() -> list[list[str]]:
    return [shlex.split(line, comments=True) for block in _blocks("") for line in block.splitlines() if line.strip()]


def _inline_gonio() -> list[list[str]]:
    spans = re.findall(r"`(gonio [^`]+)`", re.sub(r"```.*?```", "", TEXT, flags=re.S))
    return [shlex.split(" ".join(span.split()))[1:] for span in spans]


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
    from rig.run.config import load_rig, load_sweep

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

    # A pseudo-terminal stands in for the adapter: servo check refuses anything that is no terminal device.
    master, slave = os.openpty()
    port = Path(os.ttyname(slave))
    # Tests run as root here, who may open anything: the check is shown a port it may not open, owned by dialout.
    monkeypatch.setattr(cli_servo.os, "access", lambda *a, **k: False)
    monkeypatch.setattr(cli_servo.grp, "getgrgid", lambda gid: SimpleNamespace(gr_name="dialout"))
    monkeypatch.setenv("GONIO_SYSFS", str(tmp_path / "no-sysfs"))
    try:
        assert cli.main(["servo", "check", "--port", str(port)]) == 3
    finally:
        os.close(slave)
        os.close(master)
    line = next(x for x in capsys.readouterr().out.splitlines() if "you may not open it" in x)
    return line.replace(str(port), "/dev/ttyUSB0")


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
    from rig.run.config import parse
    from rig.run.config_schema import RigFile

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
