"""No measurement of gonio's speed in a source file's comments or docstrings: such figures live in docs/benchmarks.md.

A comment says why, briefly; a timing of our code, a speed ratio or the CPU it was taken on ages with the code and the
machine, so it belongs beside its bench command and machine, not in the source. Read here: every COMMENT token
(tokenize) and every string statement (docstrings, attribute docstrings: ast) of the packages, bench/ and tests/.
Code is never read, so a timeout constant or a protocol's window is free to be a number of milliseconds.

What fails, naming file:line and the rule: a time in ns/us/µs/ms (or CPU seconds, or seconds a call took) with a word
of cost or speed near it and no word of a device's timing (a window, a timer, an exposure...); a speed ratio
("3x faster", "a tenth of the cost"); a throughput ("evals per second"); a CPU model's name; "measured on" a machine.
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCANNED = ("acquisition", "analysis", "gonio", "model", "rig", "simulator", "bench", "tests")

_NUM = r"~?\d[\d,]*(?:\.\d+)?"
_RANGE = rf"{_NUM}(?:\s?(?:-|->|to|/)\s?{_NUM})?"
#: A time of the kind a timing gives, and what makes it a measurement of the code rather than a device's timing.
TIME = re.compile(rf"(?<![\w.]){_RANGE}\s?(?:ns|us|µs|ms)\b|(?<![\w.]){_RANGE}\s?CPU[ -]?s\b", re.I)
COST = re.compile(r"\b(?:costs?|took|spent|faster|slower|quicker|speed-?ups?|per call|a call|median|CPU|measured|"
                  r"against|vs)\b", re.I)  # fmt: skip
DEVICE = re.compile(r"\b(?:window|timer|timeout|latency|interval|poll(?:s|ed|ing)?|exposures?|shutter|delay|ramps?|"
                    r"steps?|dump|goal|deadline|baud|wire|sleep|clock)\b", re.I)  # fmt: skip
RULES: tuple[tuple[str, re.Pattern[str]], ...] = (
    ("a speed ratio", re.compile(r"\d+(?:\.\d+)?\s?x\s+(?:faster|slower|quicker|the throughput)|"
                                 r"\b(?:faster|slower|quicker)\s*\(?\s*\d+(?:\.\d+)?\s?x\b|"
                                 r"\bspeed-?up of \d|"
                                 r"\b(?:a tenth|a third|a quarter|a fifth|half)\b[^.;:]{0,25}\b(?:the |its )?"
                                 r"(?:cost|time)\b", re.I)),
    ("a throughput", re.compile(r"\d\s?(?:k|M|million)?\s+evals?\s?(?:per second|/\s?s)\b|\bevals/s\b", re.I)),
    ("a CPU model", re.compile(r"\b(?:EPYC|Xeon|Ryzen|Threadripper|Opteron|Zen ?[1-6]|Core i[3579]|Skylake|"
                               r"Ice ?Lake|Cascade ?Lake|Sapphire ?Rapids|Graviton|Neoverse)\b")),
    ("measured on a machine", re.compile(r"\bmeasured\b[^.;]{0,40}(?:\b\d+-(?:v?CPU|core)s?\b|\b\d+ (?:shared )?"
                                         r"(?:v?CPUs|cores)\b|\b(?:machine|host|VM|laptop)\b)", re.I)),
    ("a time taken", re.compile(r"\b(?:costs?|took|takes|spent)\s+(?:about\s+|~|most of\s+|nearly\s+)?"
                                rf"(?:{_RANGE}\s?s\b|(?:a|half a|a few|tens of|hundreds of)\s+(?:milli|micro|nano)?"
                                r"seconds?\b|(?:milli|micro|nano)?seconds\b)", re.I)),
)  # fmt: skip


def _units(path: Path) -> list[list[tuple[int, str]]]:
    """The commented and documented text of a file: runs of comment lines, and string statements, line by line."""
    src = path.read_text(encoding="utf-8")
    lines = src.splitlines()
    units: list[list[tuple[int, str]]] = []
    last = -2
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        if tok.type == tokenize.COMMENT:
            row = tok.start[0]
            if row == last + 1 and units and units[-1][-1][0] == last:
                units[-1].append((row, tok.string.lstrip("#: ")))
            else:
                units.append([(row, tok.string.lstrip("#: "))])
            last = row
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str):
            first, end = node.value.lineno, node.value.end_lineno or node.value.lineno
            units.append([(row, lines[row - 1]) for row in range(first, end + 1)])
    return units


def findings(path: Path) -> list[str]:
    """``file:line: rule: text`` for every measurement in ``path``'s comments and docstrings."""
    found: list[str] = []
    for unit in _units(path):
        text, starts = "", []
        for row, line in unit:
            starts.append((len(text), row))
            text += line.strip() + " "

        hits: list[tuple[int, str]] = []
        for m in TIME.finditer(text):
            near, close = text[max(0, m.start() - 90) : m.end() + 90], text[max(0, m.start() - 40) : m.end() + 40]
            if COST.search(near) and not DEVICE.search(close):
                hits.append((m.start(), "a timing"))
        hits += [(m.start(), rule) for rule, pattern in RULES for m in pattern.finditer(text)]
        for pos, rule in sorted(set(hits)):
            row = max((start, row) for start, row in starts if start <= pos)[1]
            line = next(line for r, line in unit if r == row)
            found.append(f"{path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}:{row}: {rule}: "
                         f"{line.strip()}")  # fmt: skip
    return found


def scanned_files() -> list[Path]:
    """The .py files of the packages, bench/ and tests/, but this file."""
    me = Path(__file__).resolve()
    return [p for d in SCANNED for p in sorted((ROOT / d).rglob("*.py")) if p.resolve() != me]


def test_no_comment_or_docstring_holds_a_measurement() -> None:
    found = [f for path in scanned_files() for f in findings(path)]
    assert not found, ("measurements in comments or docstrings (say why without the figure; the figure goes to "
                       "docs/benchmarks.md with its machine):\n" + "\n".join(found))  # fmt: skip


SYNTHETIC = '''"""A module whose kernel took 10-25 ms where numpy took 95 ms, measured on the 2-core machine."""

TIMEOUT_MS = 16  # the adapter's latency timer is 16 ms by default: a device's timing, not ours
EXPOSURES_S = (0.001, 0.256)  # 1 ms .. 256 ms, 2 stops apart


def f(x):
    """Finite and > 0."""
    # numpy's call costs ~3 us,
    # twelve times a point.
    # The scalar path is 5x faster on an AMD EPYC.
    return x > 0


class C:
    """Fits at a tenth of the cost."""

    table = "took 3 ms"  # a string in code is code: not read
    """Evaluates 24k evals per second; importing it costs about a second."""
'''


def test_the_check_names_each_measurement_in_a_comment_or_docstring_and_nothing_else(tmp_path: Path) -> None:
    path = tmp_path / "synthetic.py"
    path.write_text(SYNTHETIC, encoding="utf-8")
    got = [f.split(": ", 2)[:2] for f in findings(path)]
    rows = {(int(where.rsplit(":", 1)[1]), rule) for where, rule in got}
    assert rows == {
        (1, "a timing"),
        (1, "measured on a machine"),
        (9, "a timing"),
        (11, "a speed ratio"),
        (11, "a CPU model"),
        (16, "a speed ratio"),
        (19, "a throughput"),
        (19, "a time taken"),
    }, got
    assert all(f.startswith(f"{path}:") for f in findings(path))


@pytest.mark.parametrize("legit", [
    "# A 1 ms latency timer gives a ~4 ms reply window; a servo answers after 30 ms.",
    "# Each lost reply costs one reply window (122 ms) and a retry.",
    "# 250 x 2 us = 0.5 ms per reply, in real time",
    '"""Goal: at most 2 ms a plan."""',
    "# measured within 3.5 % (gold) and 0.6 % (Lambert)",
    "# Clock seconds GRBL has to answer a line it took in while Idle: the ~50 ms of a '$$' dump",
])  # fmt: skip
def test_a_devices_timing_or_an_accuracy_figure_is_not_a_measurement(tmp_path: Path, legit: str) -> None:
    path = tmp_path / "legit.py"
    path.write_text(legit + "\n", encoding="utf-8")
    assert findings(path) == []
