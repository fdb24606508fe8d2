"""Helpers benchmarks share: the machine description, wall-clock timers, tables, random directions, the record.

Tables are plain text for the terminal (``format_table``) or markdown for the docs (``markdown_table``);
``write_section`` rewrites one benchmark's section of docs/benchmarks.md, ``publish`` does and says so, and
``record`` writes it with the heading, command and machine lines every section opens with.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import re
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

# Re-exported for the benchmarks; they live in analysis because the simulation study's report writes them too.
from analysis.tables import format_table as format_table
from analysis.tables import markdown_table as markdown_table

if TYPE_CHECKING:
    from matplotlib.figure import Figure

#: Where benchmarks write figures unless told otherwise (git-ignored).
DEFAULT_OUT = Path("out/bench")

#: The page that records every benchmark's latest figures, a section each.
BENCHMARKS_MD = Path(__file__).resolve().parent.parent / "docs" / "benchmarks.md"


def _cpuinfo_field(name: str) -> str | None:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return None
    for line in text.splitlines():
        key, sep, value = line.partition(":")
        if sep and key.strip() == name:
            return value.strip()
    return None


def machine_description() -> str:
    """One line naming the CPU model, usable cores, vector extensions and the software versions."""
    cpu = _cpuinfo_field("model name") or platform.processor() or platform.machine()
    # Cores this process may run on (a container can see more than it gets).
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    flags = set((_cpuinfo_field("flags") or "").split())
    simd = next((name for flag, name in (("avx512f", "AVX-512"), ("avx2", "AVX2")) if flag in flags), "")
    simd_text = f", {simd}" if simd else ""
    return (
        f"{cpu}, {cores} cores{simd_text}; {platform.system()} {platform.release()}; "
        f"Python {platform.python_version()}, numpy {np.__version__}"
    )


def timed_calls(fn: Callable[[], object], repeats: int, warmup: int = 1) -> list[float]:
    """Wall-clock seconds of each of ``repeats`` calls of fn, after ``warmup`` untimed calls."""
    if repeats < 1:
        raise ValueError(f"repeats = {repeats}: need at least one timed call")
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return times


def median_time(fn: Callable[[], object], repeats: int = 5) -> float:
    """Median wall-clock seconds of ``repeats`` calls of fn, after one untimed warm-up call.

    The warm-up absorbs first-call costs (page faults of fresh buffers, imports, JIT compilation) that
    are not what a benchmark compares; the median ignores the odd call slowed by the rest of the machine.
    """
    return statistics.median(timed_calls(fn, repeats))


def best_time(fn: Callable[[], object], repeats: int = 5) -> float:
    """Fastest wall-clock seconds of ``repeats`` calls of fn, after one untimed warm-up call.

    On a machine shared with other work, noise only ever adds time, so the minimum is the most
    reproducible estimate of what the code itself costs (the advice of the ``timeit`` docs).
    """
    return min(timed_calls(fn, repeats))


def uniform_hemisphere(rng: np.random.Generator, n: int, dtype: type[np.floating] = np.float64) -> np.ndarray:
    """n unit directions (n, 3) uniform over the upper hemisphere (z > 0), in the given dtype."""
    z = rng.random(n)
    r = np.sqrt(1.0 - z * z)
    phi = 2.0 * np.pi * rng.random(n)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1).astype(dtype)


def write_section(path: Path, name: str, body: str) -> None:
    """Replace (or append) the ``<!-- section: name -->`` ... ``<!-- end: name -->`` block of a markdown file.

    Each benchmark owns one named section of docs/benchmarks.md and rewrites only that one, so benchmarks
    run in any order leave the others' sections alone. The file is created if missing; the new text is
    written to a temporary file beside it and renamed over it, so a reader never sees half a file.
    """
    text = path.read_text() if path.exists() else ""
    block = f"<!-- section: {name} -->\n{body.rstrip()}\n<!-- end: {name} -->"
    pattern = re.compile(rf"<!-- section: {re.escape(name)} -->.*?<!-- end: {re.escape(name)} -->", re.S)
    if pattern.search(text):
        text = pattern.sub(lambda _: block, text)
    else:
        text = text.rstrip("\n") + "\n\n" + block + "\n"
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(text)
    tmp.replace(path)


def bench_parser(doc: str) -> argparse.ArgumentParser:
    """A benchmark's command line, described by the first line of its ``doc``, with --no-docs."""
    parser = argparse.ArgumentParser(description=doc.split("\n")[0])
    parser.add_argument("--no-docs", action="store_true", help="do not rewrite docs/benchmarks.md")
    return parser


def record(name: str, title: str, options: str, machine: str, *paragraphs: str) -> None:
    """Write benchmark ``name``'s section of docs/benchmarks.md and say so on stdout.

    The section opens with ``title``, the command (``python -m bench.<name>`` and its ``options`` as run), today's
    date and the ``machine`` line; ``paragraphs`` (text, tables) follow, a blank line between each.
    """
    head = (f"## {title} (`bench/{name}.py`)\n\n"
            f"Command: `.venv/bin/python -m bench.{name}{options}`. Run on {datetime.date.today()}.\n"
            f"Machine: {machine}")  # fmt: skip
    publish(name, "\n\n".join([head, *paragraphs]))


def publish(name: str, body: str) -> None:
    """Write ``body`` as benchmark ``name``'s section of docs/benchmarks.md and say so on stdout."""
    write_section(BENCHMARKS_MD, name, body)
    print(f"\nSection '{name}' written to {BENCHMARKS_MD}")


def save_figure(fig: Figure, path: Path, dpi: int = 110) -> None:
    """Lay out matplotlib figure ``fig``, write it to ``path`` (its folder made if missing) and close it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def load_average() -> str:
    """The 1, 5 and 15 minute load averages, for the record: figures from a shared machine need them."""
    if not hasattr(os, "getloadavg"):
        return "load average unknown"
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f} / {five:.2f} / {fifteen:.2f} (1 / 5 / 15 min)"


def installed_env(env: dict[str, str] | None = None) -> tuple[dict[str, str], bool]:
    """The environment for timing gonio commands as an installed gonio runs them, and whether it was changed.

    Python's bytecode cache is part of a warm start: an installed gonio has its .pyc files, and a shell that
    forbids writing them (some sandboxes set PYTHONDONTWRITEBYTECODE) would recompile gonio's ~200 modules at
    every launch, which an installed gonio never does.
    """
    out = dict(os.environ if env is None else env)
    return out, out.pop("PYTHONDONTWRITEBYTECODE", None) is not None
