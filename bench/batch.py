"""Batch analysis on a local Dask cluster against the same analyses one after the other, in the same run.

Inputs: ``--runs`` simulated runs (default 20) of varied materials (Lambertian, rough and polished metals,
glossy and satin plastics) on the simulated rig, each a 36-direction isotropic grid, made once (on the
cluster, not timed) and kept in ``--cache`` for the next time. Each is analysed with gonio analyze's defaults
(the full ladder, 4 starts, figures and exports).

1. Serial: ``analysis.analyze.analyze`` of every run in this process, one after the other (after one untimed
   analysis that pays the imports and the JIT), wall and CPU time per input.
2. Batch: ``batch_analyze`` of the same runs on a local cluster of ``--workers`` (default 2), whose workers
   were warmed the same way first; the wall time of the batch, each task's wall and CPU time on its worker.
   The anchor: speed-up = serial wall / batch wall (goal >= 1.8 on 2 workers).
3. What Dask adds per task: (a) ``--noop`` tasks that do nothing, through the same client: the scheduler's
   round trip per task; (b) in the batch, workers x batch wall - the sum of the tasks' own wall times,
   per task (scheduling, transfers, and the idle tail when the last tasks run alone).

On a shared machine wall times measure the neighbours too; CPU time per task (``time.process_time`` of the
worker process) does not, so the projection to bigger clusters is made from it: T(W) = sum of task CPU / W
+ N x the no-op cost + the start-up, and per task on several machines the bytes read and written through the
shared file system. Run: ``.venv/bin/python -m bench.batch [--runs N] [--workers W] [--no-write]``; writes
the ``batch`` section of docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import datetime
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from analysis.analyze import analyze
from analysis.batch.analyze_batch import batch_analyze
from analysis.batch.cluster import ClusterSettings, cluster_client
from bench._common import BENCHMARKS_MD, DEFAULT_OUT, format_table, machine_description, markdown_table, write_section

GOLD = {"eta": [0.18, 0.42, 1.37], "k": [3.42, 2.35, 1.77]}
COPPER = {"eta": [0.27, 0.68, 1.22], "k": [3.61, 2.63, 2.29]}
ALUMINIUM = {"eta": [1.66, 0.88, 0.52], "k": [9.22, 6.27, 4.84]}


def materials(n: int) -> list[dict[str, Any]]:
    """n simulated materials cycling through five families with varied parameters."""
    out: list[dict[str, Any]] = []
    for i in range(n):
        family, step = i % 5, i // 5
        if family == 0:
            out.append({"model": "Lambert", "rho_d": [0.2 + 0.15 * step, 0.5, 0.7 - 0.1 * step]})
        elif family in (1, 2):
            metal = (GOLD, COPPER, ALUMINIUM)[(i // 2) % 3]
            alpha = (0.35 + 0.1 * step) if family == 1 else (0.08 + 0.03 * step)
            out.append({"model": "CookTorrance", "alpha": alpha, "fresnel": "conductor", **metal})
        else:
            alpha = (0.1 + 0.05 * step) if family == 3 else (0.3 + 0.05 * step)
            out.append({"model": "CookTorrance", "alpha": alpha, "fresnel": "dielectric", "eta": 1.5,
                        "rho_d": [0.5 - 0.05 * step, 0.2, 0.1 + 0.05 * step]})  # fmt: skip
    return out


def make_run(material: dict[str, Any], seed: int, out: str) -> str:
    """One finished run of ``material`` on the simulated rig at ``out`` (a task: runs on a worker)."""
    from rig.run.config.files import parse, rig_config, sweep_config
    from rig.run.config.schema import RigFile, SweepFile
    from rig.run.session import start_run

    rig = rig_config(parse({"name": "bench rig", "simulation": {"material": material, "seed": seed},
                            "reference": {"every": 12}}, RigFile, "<bench rig>"), "<bench rig>")  # fmt: skip
    sweep = sweep_config(parse({"name": "bench grid", "sweep": {
        "kind": "grid", "theta_i_deg": [15.0, 35.0, 55.0], "theta_o_deg": [0.0, 20.0, 40.0, 60.0],
        "phi_o_deg": [90.0, 135.0, 180.0], "isotropic": True}}, SweepFile, "<bench grid>"), "<bench grid>")  # fmt: skip
    shutil.rmtree(out, ignore_errors=True)
    start_run(rig, sweep, out, progress=False)
    return out


def warm_up(run: str) -> float:
    """Analyse one run into a scratch directory: imports, JIT and caches, as a first input would pay (s)."""
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        analyze(run, tmp)
    return time.perf_counter() - t0


def noop() -> None:
    """A task that does nothing: what is left is Dask's own cost."""


def rss_bytes() -> int:
    """Resident memory of this (worker) process, bytes."""
    import psutil  # installed with distributed

    return int(psutil.Process().memory_info().rss)


def busy_s() -> float:
    """CPU seconds the whole machine has spent busy since boot (all processes, from /proc/stat); NaN elsewhere."""
    try:
        fields = Path("/proc/stat").read_text().splitlines()[0].split()[1:]
    except OSError:
        return float("nan")
    user, nice, system, _idle, _iowait, irq, softirq, steal = (int(x) for x in fields[:8])
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


def _dir_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())


def _runs(client: Any, cache: Path, n: int) -> list[str]:
    """The n runs, made on the cluster where the cache lacks them (finished runs are reused)."""
    wanted = [str(cache / f"run-{i:02d}") for i in range(n)]
    missing = [(m, i, p) for i, (m, p) in enumerate(zip(materials(n), wanted, strict=True))
               if not (Path(p) / "status.json").is_file()]  # fmt: skip
    if missing:
        print(f"making {len(missing)} simulated runs in {cache} (not timed)", file=sys.stderr, flush=True)
        client.gather([client.submit(make_run, m, 100 + i, p, pure=False) for m, i, p in missing])
    return wanted


def main(argv: list[str] | None = None) -> int:
    """Time the serial and the batch analyses; print the table and write the docs section."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20, help="simulated runs to analyse (default 20)")
    ap.add_argument("--workers", type=int, default=2, help="workers of the local cluster (default 2)")
    ap.add_argument("--noop", type=int, default=400, help="no-op tasks for Dask's own cost (default 400)")
    ap.add_argument("--cache", type=Path, default=DEFAULT_OUT / "batch-runs", help="where the runs are kept")
    ap.add_argument("--no-write", action="store_true", help="print only; leave docs/ alone")
    args = ap.parse_args(argv)
    command = " ".join(["python -m bench.batch", *(sys.argv[1:] if argv is None else argv)])
    load_before = os.getloadavg()
    args.cache.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    with cluster_client(ClusterSettings(workers=args.workers, dashboard_address="127.0.0.1:0"),
                        lambda line: print(line, file=sys.stderr)) as client:  # fmt: skip
        start_s = time.perf_counter() - t0
        runs = _runs(client, args.cache, args.runs)
        t1 = time.perf_counter()
        client.run(warm_up, runs[0])  # every worker pays imports and JIT before the clock starts
        worker_warm_s = time.perf_counter() - t1

        serial_warm_s = warm_up(runs[0])
        serial_wall, serial_cpu = [], []
        with tempfile.TemporaryDirectory() as tmp:
            busy = busy_s()
            for run in runs:
                w, c = time.perf_counter(), time.process_time()
                analyze(run, Path(tmp) / Path(run).name)
                serial_wall.append(time.perf_counter() - w)
                serial_cpu.append(time.process_time() - c)
            # What the rest of the machine ran meanwhile, in cores: the neighbours' share of the cores.
            others_serial = (busy_s() - busy - sum(serial_cpu)) / sum(serial_wall)
            print(f"serial: {sum(serial_wall):.1f} s for {len(runs)} runs", file=sys.stderr, flush=True)

            out = Path(tmp) / "batch"
            busy, w = busy_s(), time.perf_counter()
            result = batch_analyze(runs, out, client=client, progress=True)
            batch_wall = time.perf_counter() - w
            batch_busy = busy_s() - busy
            assert not result.failed, result.failed
            tasks = [result.records[k]["timing"] for k in result.analysed]
            out_bytes = statistics.mean(_dir_bytes(out / k) for k in result.analysed)
            in_bytes = statistics.mean(_dir_bytes(Path(r)) for r in runs)

        w = time.perf_counter()
        client.gather([client.submit(noop, pure=False) for _ in range(args.noop)])
        noop_s = (time.perf_counter() - w) / args.noop
        rss_mb = max(client.run(rss_bytes).values()) / 1e6
    load_after = os.getloadavg()

    n, workers = len(runs), args.workers
    task_wall, task_cpu = [t["wall_s"] for t in tasks], [t["cpu_s"] for t in tasks]
    speedup = sum(serial_wall) / batch_wall
    overhead = (workers * batch_wall - sum(task_wall)) / n
    cpu_speedup = sum(serial_cpu) / (sum(task_cpu) / workers)
    others_batch = (batch_busy - sum(task_cpu)) / batch_wall
    rows = [
        ["serial (this process)", f"{sum(serial_wall):.1f}", f"{statistics.mean(serial_wall):.2f}",
         f"{statistics.mean(serial_cpu):.2f}", "1.00"],
        [f"batch, {workers} workers", f"{batch_wall:.1f}", f"{statistics.mean(task_wall):.2f}",
         f"{statistics.mean(task_cpu):.2f}", f"{speedup:.2f}"],
    ]  # fmt: skip
    headers = ["path", "wall (s)", "wall per input (s)", "CPU per input (s)", "speed-up (goal >= 1.8)"]
    costs = [["Dask round trip of a no-op task (ms)", f"{noop_s * 1e3:.2f}"],
             ["batch: workers x wall - task walls, per task (s)", f"{overhead:.2f}"],
             ["speed-up from CPU times: serial CPU / (task CPU / workers)", f"{cpu_speedup:.2f}"],
             ["share of a task's wall time: fitting / the report (figures, page, exports)",
              f"{sum(t['fit_s'] for t in tasks) / sum(task_wall):.0%} / "
              f"{sum(t['report_s'] for t in tasks) / sum(task_wall):.0%}"],
             ["cluster start (s)", f"{start_s:.1f}"], ["worker warm-up (s), serial warm-up (s)",
                                                        f"{worker_warm_s:.1f}, {serial_warm_s:.1f}"],
             ["largest worker's resident memory after the batch (MB)", f"{rss_mb:.0f}"],
             ["input read / outputs written per task (MB)", f"{in_bytes / 1e6:.2f} / {out_bytes / 1e6:.2f}"],
             ["other processes' CPU during the serial / the batch phase (cores)",
              f"{others_serial:.2f} / {others_batch:.2f}"],
             ["load average before / after (1 min)", f"{load_before[0]:.1f} / {load_after[0]:.1f}"]]  # fmt: skip
    print(format_table(headers, rows))
    print(format_table(["what Dask adds, and the context", "value"], costs))
    cpu = statistics.mean(task_cpu)
    projection = []
    for w_, label in ((16, "one 16-core machine (16 workers)"), (64, "four 16-core machines (64 workers)")):
        compute = n * cpu / w_
        per_1000 = 1000 * cpu / w_ + 1000 * noop_s
        io = (in_bytes + out_bytes) / 100e6  # a shared file system at 100 MB/s (1 GbE NFS)
        projection.append([label, f"{compute:.1f}", f"{per_1000 / 60:.1f}",
                           f"{1000 * io / 60:.1f}" if w_ > 16 else "local disk"])  # fmt: skip
    p_headers = [f"cluster ({n} inputs here)", f"{n} inputs (s)", "1000 inputs (min)", "1000 inputs: I/O (min)"]
    print(format_table(p_headers, projection))
    if not args.no_write:
        body = (
            "## Batch analysis on a Dask cluster (`bench/batch.py`)\n\n"
            f"Measured {datetime.date.today()} on {machine_description()}; `{command}`. The machine was shared "
            f"(1-minute load average {load_before[0]:.1f} before and {load_after[0]:.1f} after, on "
            f"{os.cpu_count()} cores, and the other processes' CPU during each phase is in the second table): wall "
            "times and the speed-up include the neighbours' work; the CPU times less so (with every core busy a "
            "task's CPU time grows too: caches and memory bandwidth are shared). Each input is one simulated "
            "run (36-direction grid) analysed with gonio analyze's defaults "
            "(4 candidates, 4 starts, figures and exports); serial is the same call in one process, one input "
            "after another; both warmed first.\n\n" + markdown_table(headers, rows) + "\n\n"
            + markdown_table(["what Dask adds, and the context", "value"], costs) + "\n\n"
            "On paper, from the CPU time per task in the batch (with both cores busy, so it includes what "
            "sharing caches and memory costs), one worker per core, the no-op round trip charged to every task "
            "one after the other (an upper bound: the scheduler is the only serial part), start-up excluded; "
            "several machines read the runs and write the reports through a shared file system, charged at "
            "100 MB/s for the whole batch:\n\n" + markdown_table(p_headers, projection) + "\n\n"
            f"A task costs {cpu:.1f} s of CPU against a Dask round trip of {noop_s * 1e3:.1f} ms: the scheduler "
            f"would become the bottleneck only near {cpu / noop_s:.0f} workers. Most of a task is the report (its "
            "figures are drawn by matplotlib), not the fit (second table).\n"
        )  # fmt: skip
        write_section(BENCHMARKS_MD, "batch", body)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
