"""A long simulated run on a machine kept busy: does ``gonio run`` finish its sweep when the CPU is contended?

Issue 21 saw a 1000-point run stop at point 500 with "There is no status packet!" at a load of 10 on 2 cores:
the SDK's receive loop spun with a zero timeout, holding the GIL against the virtual servos' thread. This
benchmark starts ``--spinners`` processes that each burn a core (``python -c 'while 1: pass'``), runs the
real ``gonio run`` command on the simulated rig for a sweep of ``--points`` points, samples the load average
every few seconds, and reports whether the run finished, its wall time per point and the load it ran under.

Anchor: a short run of the same rig and sweep kind without the spinners, measured in the same invocation
(the ratio is loaded per-point wall time over the anchor's). Simulated time stays machine-independent: the
rig runs on a ManualClock, so the load changes wall time only, never what is measured.

Run: ``.venv/bin/python -m bench.loaded_run [--points 1000] [--spinners 8] [--anchor-points 40] [--no-docs]``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from bench._common import bench_parser, format_table, machine_description, markdown_table, record

RIG = Path(__file__).resolve().parent.parent / "examples" / "rig_simulated.toml"
#: A run that is still going after this many wall seconds is stopped and reported as not finished.
RUN_TIMEOUT_S = 4 * 3600.0


def sweep_toml(points: int) -> str:
    """A grid sweep of about ``points`` reachable directions (anisotropic, so every azimuth counts)."""
    n = max(2, round((points / 4) ** 0.5))
    ti = [round(5.0 + 60.0 * k / (n - 1), 3) for k in range(n)]
    to = [round(5.0 + 65.0 * k / (n - 1), 3) for k in range(n)]
    return "\n".join([
        'name = "loaded run"', "", "[sweep]", 'kind = "grid"', f"theta_i_deg = {ti}", f"theta_o_deg = {to}",
        "phi_o_deg = [100.0, 140.0, 180.0, 220.0]", "isotropic = false", "", "[capture]", "target_snr = 100.0", "",
    ])  # fmt: skip


class LoadSampler:
    """Samples the 1-minute load average every ``period_s`` seconds in a thread until stopped."""

    def __init__(self, period_s: float = 5.0) -> None:
        self.samples: list[float] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(period_s,), daemon=True)

    def _run(self, period_s: float) -> None:
        while not self._stop.wait(period_s):
            self.samples.append(os.getloadavg()[0])

    def __enter__(self) -> LoadSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


@dataclass(frozen=True)
class RunResult:
    """One ``gonio run``: exit code (None if it timed out), points journalled, wall seconds, load, errors."""

    code: int | None
    measured: int
    wall_s: float
    load: list[float]
    errors: list[str]


def gonio_run(points: int, work: Path, name: str) -> RunResult:
    """Run ``gonio run`` on a sweep of ``points`` points; exit code, points measured, wall seconds, errors."""
    sweep = work / f"{name}.toml"
    sweep.write_text(sweep_toml(points))
    out = work / name
    cmd = [sys.executable, "-m", "gonio.cli", "run", str(sweep), "--rig", str(RIG), "--out", str(out), "--quiet"]
    t0 = time.perf_counter()
    with LoadSampler() as load:
        try:
            done = subprocess.run(cmd, capture_output=True, text=True, timeout=RUN_TIMEOUT_S, check=False)
            code, err = done.returncode, done.stderr
        except subprocess.TimeoutExpired:
            code, err = None, f"not finished after {RUN_TIMEOUT_S:g} s"
    wall = time.perf_counter() - t0
    journal = out / "journal.jsonl"
    lines = journal.read_text().splitlines() if journal.exists() else []
    measured = sum(1 for line in lines if json.loads(line).get("kind") == "point")
    failures = [line for line in str(err).splitlines() if "status packet" in line or "Error" in line]
    return RunResult(code, measured, wall, load.samples or [os.getloadavg()[0]], failures[-3:])


def spin(count: int) -> list[subprocess.Popen[bytes]]:
    """Start ``count`` processes that each keep one core busy."""
    return [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(count)]


def main() -> None:
    """Run the anchor, then the loaded run; print and record the figures."""
    parser = bench_parser(__doc__)
    parser.add_argument("--points", type=int, default=1000, help="points of the loaded run (default 1000)")
    parser.add_argument("--spinners", type=int, default=8, help="busy processes during the loaded run (default 8)")
    parser.add_argument("--anchor-points", type=int, default=40, help="points of the unloaded anchor run")
    args = parser.parse_args()
    machine = machine_description()
    print(machine, flush=True)
    rows = []
    with tempfile.TemporaryDirectory(prefix="gonio-loaded-") as tmp:
        work = Path(tmp)
        anchor = gonio_run(args.anchor_points, work, "anchor")
        print(f"anchor: exit {anchor.code}, {anchor.measured} points in {anchor.wall_s:.0f} s", flush=True)
        spinners = spin(args.spinners)
        try:
            loaded = gonio_run(args.points, work, "loaded")
        finally:
            for p in spinners:
                p.kill()
                p.wait()
        print(f"loaded: exit {loaded.code}, {loaded.measured} points in {loaded.wall_s:.0f} s", flush=True)
    per_anchor = anchor.wall_s / max(anchor.measured, 1)
    for label, r, extra in (("anchor", anchor, 0), ("loaded", loaded, args.spinners)):
        load, per = r.load, r.wall_s / max(r.measured, 1)
        rows.append([label, str(extra), f"{min(load):.1f} / {sum(load) / len(load):.1f} / {max(load):.1f}",
                     str(r.measured), "finished" if r.code == 0 else f"exit {r.code}: {'; '.join(r.errors)}",
                     f"{r.wall_s:.0f}", f"{per:.2f}", f"{per / per_anchor:.2f}"])  # fmt: skip
    head = ["run", "spinners", "load 1-min min / mean / max", "points measured", "outcome", "wall (s)",
            "wall / point (s)", "ratio to anchor"]  # fmt: skip
    print(format_table(head, rows))
    if args.no_docs:
        return
    record(
        "loaded_run", "A long run under load",
        f" --points {args.points} --spinners {args.spinners} --anchor-points {args.anchor_points}",
        f"{machine}, shared with other work (the anchor's load is theirs).",
        "`gonio run` on the simulated rig (`examples/rig_simulated.toml`, planned exposures at SNR 100) while "
        "busy processes (`python -c 'while 1: pass'`) contend for the cores; the load is the 1-minute load "
        "average sampled every 5 s during the run. Anchor: a short run of the same kind without the spinners.",
        markdown_table(head, rows),
    )  # fmt: skip


if __name__ == "__main__":
    main()
