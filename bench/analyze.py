"""Time of ``gonio analyze`` end to end, against the goals: 3 s for the 32-point example run, 5 s for 1,000
samples, 15 s for a MERL table (its default 20,000 random bins), and under 1 s to import the command line.

Sources: the shipped example (examples/sweep_in_plane.toml on examples/rig_simulated.toml: 32 reachable
points, measured first on the simulated rig, which takes a minute or two and is not timed), and a MERL file
tabulated from a known plastic (``MerlTable.from_model``; no MERL file ships with gonio) analysed with
``--samples 1000`` and with the default 20,000. Each is analysed by the ``gonio`` console script in a fresh
process (``--quiet``, the default ladder, PNG only), so the time includes the imports; the best of
``--repeats`` runs is kept (noise on a shared machine only ever adds time). Anchors measured in the same run:
``python -c pass`` (the interpreter's start) and, per source, the fit alone in this process
(``load_and_fit``), so "ratio to fit" reads as how much the report adds on top of the fitting; on a loaded
machine wall time says little, so CPU time (user + system, forked figure workers included) is printed beside
it, and the ratio is of CPU times. The first
analysis of each source is untimed: it fills numba's on-disk kernel cache, as any earlier analysis would have.

Run: ``.venv/bin/python -m bench.analyze [--repeats R] [--no-write]``.
"""

from __future__ import annotations

import argparse
import datetime
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench._common import format_table, machine_description, markdown_table, write_section

ROOT = Path(__file__).resolve().parent.parent
GONIO = Path(sys.executable).with_name("gonio")
GOALS_S = {"run": 3.0, "merl-1000": 5.0, "merl-20000": 15.0}


def _timed(argv: list[str]) -> tuple[float, float]:
    """Wall-clock and CPU seconds (user + system, of the process and any it forked) of one run of argv."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(argv, check=True, cwd=ROOT, stdout=subprocess.DEVNULL, timeout=1800)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _wall(argv: list[str]) -> float:
    return _timed(argv)[0]


def _best(argv: list[str], repeats: int) -> tuple[float, float]:
    """The fastest wall time and the least CPU time of ``repeats`` runs."""
    runs = [_timed(argv) for _ in range(repeats)]
    return min(w for w, _ in runs), min(c for _, c in runs)


def _sources(tmp: Path, run: Path | None) -> dict[str, tuple[Path, list[str]]]:
    """The example run (measured now unless given) and the MERL file, with the extra options of each case."""
    from model import CookTorrance
    from model.merl import MerlTable, write_merl

    if run is None:
        run = tmp / "run"
        print("measuring the example run on the simulated rig (untimed) ...", flush=True)
        subprocess.run([str(GONIO), "run", "examples/sweep_in_plane.toml", "--rig", "examples/rig_simulated.toml",
                        "--out", str(run), "--quiet"], check=True, cwd=ROOT, timeout=3600)  # fmt: skip
    merl = tmp / "plastic.binary"
    write_merl(MerlTable.from_model(CookTorrance(alpha=0.2, fresnel="dielectric", eta=1.5, rho_d=(0.2, 0.3, 0.4))),
               merl)  # fmt: skip
    return {"run": (run, []), "merl-1000": (merl, ["--samples", "1000"]), "merl-20000": (merl, [])}


def main(argv: list[str] | None = None) -> None:
    """Print the figures and (unless --no-write) rewrite the section of docs/benchmarks.md."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--no-write", action="store_true")
    p.add_argument("--run", type=Path, help="an example run measured before (default: measure one now)")
    args = p.parse_args(argv)
    from analysis.analyze import load_and_fit

    load = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="bench-analyze-") as d:
        tmp = Path(d)
        sources = _sources(tmp, args.run)
        python_pass = _best([sys.executable, "-c", "pass"], 3)[0]
        imports = _best([sys.executable, "-c", "import gonio.cli"], 3)[0]
        rows, md = [], []
        for case, (src, extra) in sources.items():
            cmd = [str(GONIO), "analyze", str(src), "--out", str(tmp / f"out-{case}"), "--quiet", "--force", *extra]
            _wall(cmd)  # warm-up: numba's disk cache, the page cache
            total, cpu = _best(cmd, args.repeats)
            samples = int(extra[1]) if extra else None
            t0, c0 = time.perf_counter(), time.process_time()
            load_and_fit(src, samples=samples)
            fit, fit_cpu = time.perf_counter() - t0, time.process_time() - c0
            goal = GOALS_S[case]
            cells = [case, f"{total:.2f}", f"{cpu:.2f}", f"{fit:.2f}", f"{fit_cpu:.2f}", f"{cpu / fit_cpu:.1f}",
                     f"{total / python_pass:.0f}", f"{goal:g}", "yes" if total <= goal else "no"]  # fmt: skip
            rows.append(cells)
            md.append(cells)
            print(f"{case}: gonio analyze {total:.2f} s wall, {cpu:.2f} s CPU (fit alone {fit:.2f} s wall, "
                  f"{fit_cpu:.2f} s CPU)", flush=True)  # fmt: skip
    after = os.getloadavg()
    headers = ["source", "gonio analyze wall (s)", "its CPU (s)", "fit alone wall (s)", "its CPU (s)",
               "CPU ratio to fit", "wall ratio to python -c pass", "goal, wall (s)", "met"]  # fmt: skip
    print(format_table(headers, rows))
    imp = (f"import gonio.cli: {imports:.2f} s (goal 1 s; python -c pass {python_pass:.3f} s, ratio "
           f"{imports / python_pass:.1f})")  # fmt: skip
    print(imp)
    loaded = f"load average {load[0]:.1f} before, {after[0]:.1f} after (1 min)"
    print(loaded)
    if args.no_write:
        return
    body = "\n".join([
        "## `gonio analyze` end to end (`bench/analyze.py`)", "",
        f"Measured {datetime.date.today().isoformat()} on {machine_description()}; {loaded}: a shared machine, "
        "so these are upper bounds of what an idle one gives.", "",
        markdown_table(headers, md), "", imp + ".", "",
        "Sources: the shipped in-plane example (32 points), a MERL table of a plastic with `--samples 1000` and "
        "with the default 20,000 bins; default ladder, PNG figures only (`--svg` adds the SVGs).",
    ])  # fmt: skip
    write_section(ROOT / "docs" / "benchmarks.md", "analyze", body)


if __name__ == "__main__":
    main()
