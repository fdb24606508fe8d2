"""How soon ``gonio run`` delivers its first reading, on a cold kernel cache and on a warm one.

``gonio run`` on the simulated rig for a few points, timed from launch to the first record in the journal (the
reference reading taken before the first point) and to the first point, with the journal polled every
10 ms. Cold: fresh numba and Dr.Jit caches (``NUMBA_CACHE_DIR`` and ``HOME``, where Dr.Jit keeps its kernel
cache, point at empty directories), so every kernel compiles; warm: the same command again on those
caches. Goal: the first reading within 2 s on a warm cache. Anchor, measured in the same run: the start-up of
a bare interpreter importing numpy (what any Python tool pays before doing anything). Python's bytecode cache
is left on for both runs (an installed gonio has its .pyc files), even where the calling shell turns it off.

The example rig reads a 4 x 4 ROI crop, which the HDR merge takes in numpy, so nothing compiles there. A
camera delivering larger frames (a wider ROI, a whole frame) merges in numba's compiled passes: the same
pair of runs on a 64 x 64 ROI, with caches of its own, measures that one-time compilation and checks its
notice is shown.

Run: ``.venv/bin/python -m bench.first_reading [--no-docs]``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench._common import (
    bench_parser,
    format_table,
    installed_env,
    load_average,
    machine_description,
    markdown_table,
    record,
)

RIG = Path(__file__).resolve().parent.parent / "examples" / "rig_simulated.toml"
GOAL_S = 2.0
SWEEP = """name = "first reading"
[sweep]
kind = "grid"
theta_i_deg = [15.0, 45.0]
theta_o_deg = [20.0, 40.0]
phi_o_deg = [180.0]
isotropic = true
[capture]
target_snr = 100.0
"""


def first_records(journal: Path) -> set[str]:
    """Kinds of the records in ``journal`` so far (none for an absent file)."""
    if not journal.exists():
        return set()
    kinds: set[str] = set()
    for line in journal.read_text().splitlines():
        try:
            kinds.add(str(json.loads(line).get("kind", "?")))
        except json.JSONDecodeError:
            break  # a line being written
    return kinds


LARGE_ROI = "roi = [224, 224, 288, 288]"


def large_roi_rig(work: Path) -> Path:
    """The example rig with a 64 x 64 px ROI: frames large enough for the merge's compiled passes."""
    text = RIG.read_text()
    line = next(ln for ln in text.splitlines() if ln.startswith("roi = "))
    rig = work / "rig_large_roi.toml"
    rig.write_text(text.replace(line, LARGE_ROI))
    return rig


def timed_run(work: Path, name: str, env: dict[str, str], rig: Path = RIG) -> dict[str, float | str]:
    """Launch ``gonio run``; seconds to the first record, to the first point and to the end; the stderr."""
    sweep = work / "sweep.toml"
    sweep.write_text(SWEEP)
    out = work / name
    cmd = [sys.executable, "-m", "gonio.cli", "run", str(sweep), "--rig", str(rig), "--out", str(out)]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    seen: dict[str, float] = {}
    while proc.poll() is None:
        for kind in first_records(out / "journal.jsonl"):
            seen.setdefault(kind, time.perf_counter() - t0)
        time.sleep(0.01)  # a benchmark's poll of a file, not a test waiting on hardware
    total = time.perf_counter() - t0
    err = proc.stderr.read() if proc.stderr else ""
    if proc.returncode != 0:
        raise RuntimeError(f"gonio run failed ({proc.returncode}): {err[-2000:]}")
    for kind in first_records(out / "journal.jsonl"):
        seen.setdefault(kind, total)
    first = min((seen[k] for k in ("reference", "point") if k in seen), default=total)
    return {"first": first, "point": seen.get("point", total), "total": total, "stderr": err}


def interpreter_start(env: dict[str, str]) -> float:
    """Seconds for ``python -c 'import numpy'``: the floor any Python command starts from."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", "import numpy"], env=env, check=True)
    return time.perf_counter() - t0


def main() -> None:
    """Measure cold and warm, print and record."""
    parser = bench_parser(__doc__)
    args = parser.parse_args()
    machine = machine_description()
    print(machine, flush=True)
    rows = []
    with tempfile.TemporaryDirectory(prefix="gonio-first-") as tmp:
        work = Path(tmp)
        anchor = 0.0
        bytecode_off = False
        for caches, rig, roi in (("", RIG, "4 x 4 (numpy merge)"), ("-large", large_roi_rig(work),
                                                                     "64 x 64 (compiled merge)")):
            env, bytecode_off = installed_env(dict(os.environ, NUMBA_CACHE_DIR=str(work / f"numba{caches}"),
                                                   HOME=str(work / f"home{caches}")))  # fmt: skip
            (work / f"home{caches}").mkdir()
            anchor = anchor or interpreter_start(env)
            for label in ("cold", "warm"):
                load = load_average()
                r = timed_run(work, label + caches, env, rig)
                compiling = "compiling kernels (first run only)" in str(r["stderr"])
                first = float(r["first"])
                rows.append([roi, label, f"{first:.1f}", f"{float(r['point']):.1f}", f"{float(r['total']):.1f}",
                             "yes" if compiling else "no", f"{first / GOAL_S:.2f}", f"{first / anchor:.1f}",
                             load])  # fmt: skip
                print(rows[-1], flush=True)
    head = ["ROI", "cache", "first reading (s)", "first point (s)", "whole run (s)", "'compiling kernels' shown",
            f"ratio to {GOAL_S:g} s goal", "ratio to anchor", "load before"]  # fmt: skip
    print(f"anchor: `python -c 'import numpy'` took {anchor:.2f} s")
    print(format_table(head, rows))
    warm = float(rows[1][2])
    compile_s = float(rows[2][2]) - float(rows[3][2])
    print(f"\nfirst reading on a warm cache: {warm:.1f} s; goal <= {GOAL_S:g} s; ratio {warm / GOAL_S:.2f} "
          f"({'met' if warm <= GOAL_S else 'not met'} on this machine, {rows[1][-1]} before the run)")
    print(f"one-time compilation of the merge's passes (64 x 64 ROI, cold minus warm first reading): "
          f"{compile_s:.1f} s; the notice shown on the cold run: {rows[2][5]}, on the warm one: {rows[3][5]}")
    if bytecode_off:
        print("(PYTHONDONTWRITEBYTECODE was set in this shell; the runs were given Python's bytecode cache)")
    if args.no_docs:
        return
    record(
        "first_reading", "First reading", "", f"{machine}, shared with other work (load averages in the table).",
        "`gonio run` of 4 points on the simulated rig (`examples/rig_simulated.toml`, its 4 x 4 px ROI; then the "
        "same rig with a 64 x 64 px ROI, whose frames the merge takes in numba's compiled passes, with caches of "
        "its own), from launch to the first journal record (the reference reading before the first point) and to "
        "the first point. Cold: empty numba and Dr.Jit kernel caches; warm: the same caches after the cold run. "
        "All runs may write and read Python's bytecode cache, as an installed gonio does"
        f"{' (this shell set PYTHONDONTWRITEBYTECODE; the runs did not inherit it)' if bytecode_off else ''}. "
        f"Anchor: `python -c 'import numpy'` in the same environment, {anchor:.2f} s.",
        markdown_table(head, rows),
        f"First reading on a warm cache: **{warm:.1f} s** against the goal of {GOAL_S:g} s (ratio "
        f"{warm / GOAL_S:.2f}; {rows[1][-1]} before the run). The merge's one-time compilation, where frames are "
        f"larger than an ROI crop: {compile_s:.1f} s (cold minus warm first reading, 64 x 64 ROI), after the notice "
        f"'compiling kernels (first run only)' (shown cold: {rows[2][5]}; warm: {rows[3][5]}).",
    )  # fmt: skip


if __name__ == "__main__":
    main()
