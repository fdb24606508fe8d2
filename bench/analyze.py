"""Time of ``gonio analyze`` end to end, against the goals: 3 s for the 32-point example run, 5 s for a 1,000-point
run, 15 s for a MERL table (its default 20,000 random bins), and under 1 s to import the command line.

Sources: the shipped example (examples/sweep_in_plane.toml on examples/rig_simulated.toml: 32 reachable
points), a 1,000-point run (bench/sweep_1000.toml, a dense isotropic grid, every point reachable, on the same
rig), both measured first by ``gonio run`` on the simulated rig (a minute or two each, not timed; ``--run`` and
``--run-1000`` take runs measured before), and a MERL file tabulated from a known plastic
(``MerlTable.from_model``; no MERL file ships with gonio) analysed with the default 20,000 bins and, as the
stand-in the 1,000-sample goal had before there was a 1,000-point run, with ``--samples 1000``. Each is analysed
by the ``gonio`` console script in a fresh process (``--quiet``, the default ladder, PNG only, the default
``--jobs``), so the time includes the imports; the best of ``--repeats`` runs is kept (noise on a shared machine
only ever adds time). Anchors measured in the same run: ``python -c pass`` (the interpreter's start) and, per
source, the fit alone in this process (``load_and_fit``, its second call: the first loads scipy's solver, which
``model.fit`` imports when it first solves, and the sources' modules), so "ratio to fit" reads as how much the
report adds on top of the fitting; on a loaded machine wall time says little, so CPU time (user + system, forked
workers included) is printed beside it, with the load average before each case. The first analysis of each source is
untimed: it fills the page cache and Mitsuba's kernel cache, as any earlier analysis would have.

Run: ``.venv/bin/python -m bench.analyze [--repeats R] [--no-write] [--run DIR] [--run-1000 DIR]``.
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

from bench._common import BENCHMARKS_MD, format_table, installed_env, machine_description, markdown_table, write_section

ROOT = Path(__file__).resolve().parent.parent
GONIO = Path(sys.executable).with_name("gonio")
GOALS_S = {"run": 3.0, "run-1000": 5.0, "merl-20000": 15.0, "merl-1000": 5.0}
SWEEP_1000 = ROOT / "bench" / "sweep_1000.toml"
#: Every timed command runs as an installed gonio does, with Python's bytecode cache (bench/_common.py).
ENV, BYTECODE_OFF = installed_env()


def _timed(argv: list[str]) -> tuple[float, float]:
    """Wall-clock and CPU seconds (user + system, of the process and any it forked) of one run of argv."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(argv, check=True, cwd=ROOT, stdout=subprocess.DEVNULL, timeout=1800, env=ENV)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _wall(argv: list[str]) -> float:
    return _timed(argv)[0]


def _best(argv: list[str], repeats: int) -> tuple[float, float]:
    """The fastest wall time and the least CPU time of ``repeats`` runs."""
    runs = [_timed(argv) for _ in range(repeats)]
    return min(w for w, _ in runs), min(c for _, c in runs)


def _measured(tmp: Path, given: Path | None, name: str, sweep: str) -> Path:
    """A run of ``sweep`` on the simulated rig (measured now, untimed, unless ``given``)."""
    if given is not None:
        return given
    run = tmp / name
    print(f"measuring {sweep} on the simulated rig (untimed) ...", flush=True)
    subprocess.run([str(GONIO), "run", sweep, "--rig", "examples/rig_simulated.toml", "--out", str(run), "--quiet"],
                   check=True, cwd=ROOT, timeout=3600)  # fmt: skip
    return run


def _sources(tmp: Path, run: Path | None, run_1000: Path | None) -> dict[str, tuple[Path, list[str]]]:
    """The two runs (measured now unless given) and the MERL file, with the extra options of each case."""
    from model import CookTorrance
    from model.merl import MerlTable, write_merl

    example = _measured(tmp, run, "run", "examples/sweep_in_plane.toml")
    dense = _measured(tmp, run_1000, "run-1000", str(SWEEP_1000.relative_to(ROOT)))
    merl = tmp / "plastic.binary"
    write_merl(MerlTable.from_model(CookTorrance(alpha=0.2, fresnel="dielectric", eta=1.5, rho_d=(0.2, 0.3, 0.4))),
               merl)  # fmt: skip
    return {"run": (example, []), "run-1000": (dense, []), "merl-20000": (merl, []),
            "merl-1000": (merl, ["--samples", "1000"])}  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    """Print the figures and (unless --no-write) rewrite the section of docs/benchmarks.md."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--no-write", action="store_true")
    p.add_argument("--run", type=Path, help="an example run measured before (default: measure one now)")
    p.add_argument("--run-1000", type=Path, help="a 1000-point run measured before (default: measure "
                   f"{SWEEP_1000.relative_to(ROOT)} now)")  # fmt: skip
    args = p.parse_args(argv)
    from analysis.analyze import load_and_fit

    load = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="bench-analyze-") as d:
        tmp = Path(d)
        sources = _sources(tmp, args.run, args.run_1000)
        python_pass = _best([sys.executable, "-c", "pass"], 3)[0]
        imports = _best([sys.executable, "-c", "import gonio.cli"], 3)[0]
        rows, md = [], []
        for case, (src, extra) in sources.items():
            cmd = [str(GONIO), "analyze", str(src), "--out", str(tmp / f"out-{case}"), "--quiet", "--force", *extra]
            _wall(cmd)  # warm-up: the page cache, Mitsuba's kernel cache
            busy = os.getloadavg()[0]
            total, cpu = _best(cmd, args.repeats)
            samples = int(extra[1]) if extra else None
            load_and_fit(src, samples=samples)  # untimed: loads scipy's solver and the sources' modules here
            t0, c0 = time.perf_counter(), time.process_time()
            load_and_fit(src, samples=samples)
            fit, fit_cpu = time.perf_counter() - t0, time.process_time() - c0
            goal = GOALS_S[case]
            cells = [case, f"{total:.2f}", f"{cpu:.2f}", f"{fit:.2f}", f"{fit_cpu:.2f}", f"{cpu / fit_cpu:.1f}",
                     f"{total / python_pass:.0f}", f"{goal:g}", f"{total / goal:.2f}", "yes" if total <= goal else "no",
                     f"{busy:.1f}"]  # fmt: skip
            rows.append(cells)
            md.append(cells)
            print(f"{case}: gonio analyze {total:.2f} s wall (goal {goal:g} s, ratio {total / goal:.2f}), {cpu:.2f} s "
                  f"CPU (fit alone {fit:.2f} s wall, {fit_cpu:.2f} s CPU); load average {busy:.1f}", flush=True)
    after = os.getloadavg()
    headers = ["source", "gonio analyze wall (s)", "its CPU (s)", "fit alone wall (s)", "its CPU (s)",
               "CPU ratio to fit", "wall ratio to python -c pass", "goal, wall (s)", "wall / goal", "met",
               "load (1 min)"]  # fmt: skip
    print(format_table(headers, rows))
    imp = (f"import gonio.cli: {imports:.2f} s (goal 1 s; python -c pass {python_pass:.3f} s, ratio "
           f"{imports / python_pass:.1f})")  # fmt: skip
    print(imp)
    loaded = f"load average {load[0]:.1f} before, {after[0]:.1f} after (1 min)"
    print(loaded)
    pyc = ("Every command ran with Python's bytecode cache, as an installed gonio does"
           + (" (this shell set PYTHONDONTWRITEBYTECODE; the commands did not inherit it)" if BYTECODE_OFF else ""))
    print(pyc)
    if args.no_write:
        return
    body = "\n".join([
        "## `gonio analyze` end to end (`bench/analyze.py`)", "",
        f"Measured {datetime.date.today().isoformat()} on {machine_description()}; {loaded}"
        + (": a shared machine, so these are upper bounds of what an idle one gives." if load[0] > 1.0 else
           ": nothing else ran."), "",
        markdown_table(headers, md), "", imp + ".", "",
        "Sources: the shipped in-plane example (32 points); a 1,000-point run, `bench/sweep_1000.toml` (a dense "
        "isotropic grid: 10 incidences x 10 outgoing zenith angles x 10 azimuths, all reachable) measured by "
        "`gonio run` on `examples/rig_simulated.toml` like any run, untimed; a MERL table of a plastic with the "
        "default 20,000 bins and with `--samples 1000` (the 1,000-sample stand-in used before the 1,000-point run "
        "existed). Default ladder, PNG figures only (`--svg` adds the SVGs), default `--jobs` (the cores, here 2). "
        + pyc + ".",
    ])  # fmt: skip
    write_section(BENCHMARKS_MD, "analyze", body)


if __name__ == "__main__":
    main()
