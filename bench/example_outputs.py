"""Digest of every output of the shipped examples, to show that a refactor leaves them byte-identical (issue 29).

Run: ``python -m bench.example_outputs --out DIGEST.json`` records the digest; ``python -m bench.example_outputs
--compare BASE.json`` recomputes it and lists every entry that differs, is new or is gone (exit 1 if any).
``--keep DIR`` keeps the temporary tree (the outputs, and each command's stdout and stderr in ``logs/``) for a
``diff``; ``--list`` prints the commands. The baseline of issue 29 is this module run at fe5004d.

What runs (:func:`steps`, in order; later steps read earlier ones' outputs), in a fresh temporary directory holding
a copy of ``examples/``, as the README, the example files' comments and ``examples/*.py`` give them, at their
smallest settings: ``gonio --help`` of every subcommand; ``gonio plan`` and ``gonio run`` of each shipped sweep file
on rig_simulated.toml (the README's in-plane run as ``runs/gold``, then ``gonio resume`` of it); the GRBL rig's plan
and run; ``gonio calibrate camera`` of the RAW rig, then a run with that calibration (the file's commented
``calibration``/``flat_field`` lines on and ``[camera.noise]`` deleted, as its comment says); ``gonio calibrate
geometry`` of rig_misaligned.toml, then a plan and a run with its commented ``calibration`` line on (at fe5004d the
run stopped with exit 4, "the reference reading is dark even after metering": its large ROI's frames were planned
too short to detect its pixels); ``gonio analyze`` of the README run, with the default ladder and with ``--models
lambert,ggx_conductor --merl``; ``gonio sim merl`` and ``gonio analyze`` of it; ``gonio adaptive --budget 100`` and
its analysis; ``gonio batch analyze`` and ``gonio batch study`` as in the README; ``gonio demo``; ``gonio models``;
``python examples/raw_sweep.py``; ``python examples/compare_renderer.py``; and every README Python block that
tests/test_readme.py runs. Left out: the rehearsal of a real rig (``gonio sim rig``/``servos``/``grbl`` serve a pty
until Ctrl-C; ``gonio servo`` needs one). The commands take 3 CPU minutes (half of it calibrate geometry and the two
Dask batches): 4-5 minutes of wall time on 2 cores at load average 5, 12 at load average 14.

The code under test is this tree's: the commands run with ``PYTHONPATH`` = this tree, led by a
``gonio-<version>.dist-info`` made from this tree's pyproject.toml, so that the entry points (the backends and
cameras a rig file names) are this tree's too, not those an editable install of another checkout registered
(a refactor that moves ``rig.run.hardware`` changes them); :func:`check_environment` makes sure before running.

The digest maps ``"<step>/<path>"`` (relative to the temporary directory) to the SHA-256 of the normalised
content of every file the step created or changed, ``"<step>/<stdout>"`` and ``"<step>/<stderr>"`` to its
normalised output streams and ``"<step>/<exit>"`` to its exit status (the decimal text); a file a step deleted
maps to ``"deleted"``.

Normalisation takes out what depends on the wall clock or on the process, and only that: ``bench._normalise``
says what, file by file, and why.

Not digested: Dask's scratch space (``tmp/dask-scratch-space``: its empty lock files are Dask's) and
``__pycache__``. Everything else was the same bytes in two runs at fe5004d: PNG figures (matplotlib writes no
date), the MERL tables, the renders (seeded), what the figure processes and the Dask workers write. The commands
inherit the environment but for ``PYTHONPATH``, ``TMPDIR`` (in the temporary directory), ``COLUMNS``/``LINES``
(fixed: argparse wraps the help at the terminal's width), ``PYTHONIOENCODING``, ``MPLBACKEND`` and
``PYTHONHASHSEED`` (unset, so random, as for a user).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

from bench._normalise import Paths, normalise_file, normalise_stderr, normalise_stdout, sha256

ROOT = Path(__file__).resolve().parent.parent
DELETED = "deleted"

#: Directories (relative to the temporary directory) never digested, and directory names never digested anywhere.
EXCLUDED_DIRS = ("tmp/dask-scratch-space/",)
EXCLUDED_NAMES = ("__pycache__",)
#: A directory name made by tempfile.mkdtemp: its prefix, then eight random characters.
MKDTEMP_NAME = re.compile(r"^(tmp|.*[-_])[a-z0-9_]{8}$")


@dataclass(frozen=True)
class Step:
    """One command of the examples: its name (the digest's key prefix), argv and the exit status it should give."""

    name: str
    argv: tuple[str, ...]
    expect: int = 0
    stdin: str | None = None
    note: str = ""


def gonio(*args: str) -> tuple[str, ...]:
    """argv of the gonio console script (``-P``: the script's directory, not the working one, leads sys.path)."""
    return (sys.executable, "-P", "-m", "gonio.cli", *args)


def python(*args: str) -> tuple[str, ...]:
    """argv of ``python ARGS`` as a user runs an example script."""
    return (sys.executable, *args)


_SIM = "examples/rig_simulated.toml"
#: Copies of example rig files edited as their comments say after a calibration: lines uncommented, a table deleted.
CALIBRATED_RIGS = {
    "examples/rig_simulated_raw_calibrated.toml": ("examples/rig_simulated_raw.toml",
                                                   ("calibration", "flat_field"), "camera.noise"),
    "examples/rig_misaligned_calibrated.toml": ("examples/rig_misaligned.toml", ("calibration",), None),
}  # fmt: skip


def readme_python_blocks(readme: Path) -> list[str]:
    """The README's Python blocks that are run (tests/test_readme.py's rule: not after ``<!-- not run: ... -->``)."""
    fenced = re.findall(r"(<!-- not run: [^>]+ -->\n)?```python\n(.*?)```", readme.read_text(), re.S)
    return [code for marker, code in fenced if not marker]


_HELP = """
import argparse
from gonio.cli import build_parser

def show(parser: argparse.ArgumentParser) -> None:
    print(parser.format_help())
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                show(sub)

show(build_parser())
"""


def steps(readme: Path) -> list[Step]:
    """The commands, in the order they run (later ones read earlier ones' outputs)."""
    out = [
        Step("help", python("-P", "-c", _HELP), note="gonio --help and every subcommand's --help"),
        Step("plan-grid", gonio("plan", "examples/sweep_grid.toml", "--rig", _SIM)),
        Step("plan-in-plane", gonio("plan", "examples/sweep_in_plane.toml", "--rig", _SIM)),
        Step("plan-rusinkiewicz", gonio("plan", "examples/sweep_rusinkiewicz.toml", "--rig", _SIM)),
        Step("run-grid", gonio("run", "examples/sweep_grid.toml", "--rig", _SIM, "--out", "runs/grid")),
        Step("run-gold", gonio("run", "examples/sweep_in_plane.toml", "--rig", _SIM, "--out", "runs/gold")),
        Step("resume-gold", gonio("resume", "runs/gold")),
        Step("run-rusinkiewicz", gonio("run", "examples/sweep_rusinkiewicz.toml", "--rig", _SIM,
                                       "--out", "runs/rusinkiewicz")),
        Step("plan-grbl", gonio("plan", "examples/sweep_in_plane.toml", "--rig", "examples/rig_simulated_grbl.toml")),
        Step("run-grbl", gonio("run", "examples/sweep_in_plane.toml", "--rig", "examples/rig_simulated_grbl.toml",
                               "--out", "runs/gold-grbl")),
        Step("calibrate-camera", gonio("calibrate", "camera", "--rig", "examples/rig_simulated_raw.toml",
                                       "--out", "calib/")),
        Step("run-raw", gonio("run", "examples/sweep_in_plane.toml", "--rig",
                              "examples/rig_simulated_raw_calibrated.toml", "--out", "runs/gold-raw")),
        Step("calibrate-geometry", gonio("calibrate", "geometry", "--rig", "examples/rig_misaligned.toml",
                                         "--out", "calib")),
        Step("plan-misaligned", gonio("plan", "examples/sweep_grid.toml", "--rig",
                                      "examples/rig_misaligned_calibrated.toml")),
        Step("run-misaligned", gonio("run", "examples/sweep_grid.toml", "--rig",
                                     "examples/rig_misaligned_calibrated.toml", "--out", "runs/grid-misaligned")),
        Step("analyze-gold", gonio("analyze", "runs/gold")),
        Step("analyze-gold-ggx", gonio("analyze", "runs/gold", "--models", "lambert,ggx_conductor", "--merl",
                                       "--out", "runs/gold/analysis-ggx")),
        Step("sim-merl", gonio("sim", "merl", "--out", "paint.binary")),
        Step("analyze-merl", gonio("analyze", "paint.binary", "--samples", "20000")),
        Step("adaptive", gonio("adaptive", "--rig", _SIM, "--out", "runs/gold-adaptive", "--budget", "100")),
        Step("analyze-adaptive", gonio("analyze", "runs/gold-adaptive")),
        Step("batch-analyze", gonio("batch", "analyze", "runs/gold", "paint.binary", "--out", "batch/june",
                                    "--models", "lambert,lambert_ggx,ggx_conductor")),
        Step("batch-study", gonio("batch", "study", "--rig", _SIM, "--sweep", "examples/sweep_grid.toml",
                                  "examples/sweep_rusinkiewicz.toml", "--out", "studies/gold")),
        Step("demo", gonio("demo")),
        Step("models", gonio("models")),
        Step("raw-sweep", python("examples/raw_sweep.py")),
        Step("compare-renderer", python("examples/compare_renderer.py")),
    ]  # fmt: skip
    for i, code in enumerate(readme_python_blocks(readme), 1):
        out.append(Step(f"readme-python-{i}", python("-"), stdin=code, note=code.strip().splitlines()[0]))
    return out


def write_dist_info(pyproject: Path, site: Path) -> Path:
    """A ``gonio-<version>.dist-info`` (METADATA, entry points) of ``pyproject`` in ``site``; its path."""
    project = tomllib.loads(pyproject.read_text())["project"]
    info = site / f"{project['name']}-{project['version']}.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {project['name']}\nVersion: {project['version']}\n")
    groups = {"console_scripts": project.get("scripts", {}), **project.get("entry-points", {})}
    text = "".join(f"[{g}]\n" + "".join(f"{k} = {v}\n" for k, v in eps.items()) + "\n" for g, eps in groups.items())
    (info / "entry_points.txt").write_text(text)
    return info


def prepare_workspace(work: Path) -> None:
    """Copy examples/ (modification times kept) and write the calibrated rig files the comments describe."""
    shutil.copytree(ROOT / "examples", work / "examples", ignore=shutil.ignore_patterns("__pycache__"))
    (work / "tmp").mkdir()
    for target, (source, uncomment, drop_table) in CALIBRATED_RIGS.items():
        lines, skipping = [], False
        for line in (work / source).read_text().splitlines(keepends=True):
            if drop_table is not None and line.startswith("["):
                skipping = line.split("]")[0].strip("[ ") == drop_table
            if skipping:
                continue
            for key in uncomment:
                if line.startswith(f"# {key} = "):
                    line = line[2:]
            lines.append(line)
        (work / target).write_text("".join(lines))


def subprocess_env(site: Path) -> dict[str, str]:
    """The commands' environment: this tree's code and entry points, a fixed terminal width, random hashes."""
    env = dict(os.environ)
    env.pop("PYTHONHASHSEED", None)
    env.update(PYTHONPATH=f"{site}{os.pathsep}{ROOT}", COLUMNS="100", LINES="50", PYTHONIOENCODING="utf-8",
               MPLBACKEND="Agg")  # fmt: skip
    return env


def check_environment(env: Mapping[str, str], work: Path) -> None:
    """Fail unless the commands will import this tree's packages and read its entry points."""
    code = ("import json, importlib.metadata as md, gonio, rig, analysis, simulator; "
            "print(json.dumps({'files': [m.__file__ for m in (gonio, rig, analysis, simulator)], "
            "'eps': sorted(e.value for e in md.entry_points(group='gonio.backends'))}))")  # fmt: skip
    res = subprocess.run([sys.executable, "-P", "-c", code], env=dict(env), cwd=work, capture_output=True, text=True)
    if res.returncode != 0:
        raise SystemExit(f"cannot import gonio in the commands' environment:\n{res.stderr}")
    got = json.loads(res.stdout)
    outside = [f for f in got["files"] if not Path(f).resolve().is_relative_to(ROOT)]
    if outside:
        raise SystemExit(f"the commands would import {outside}, not this tree's code ({ROOT})")
    want = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]["gonio.backends"]
    if got["eps"] != sorted(want.values()):
        raise SystemExit(f"the commands would load backends {got['eps']}, not this tree's {sorted(want.values())}")


def snapshot(work: Path) -> dict[str, tuple[int, int]]:
    """Every file under work (relative POSIX path) with its modification time and size."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(work):
        dirnames[:] = sorted(d for d in dirnames if d not in EXCLUDED_NAMES)
        for name in filenames:
            p = Path(dirpath, name)
            rel = p.relative_to(work).as_posix()
            if rel.startswith(EXCLUDED_DIRS):
                continue
            st = p.stat()
            out[rel] = (st.st_mtime_ns, st.st_size)
    return out


def name_mkdtemps(work: Path, paths: Paths, before: set[str]) -> None:
    """Give each directory ``tempfile.mkdtemp`` made in work/tmp during a step a placeholder name."""
    made = {p: m.group(1) for p in (work / "tmp").iterdir()
            if p.is_dir() and p.name not in before and (m := MKDTEMP_NAME.match(p.name))}  # fmt: skip

    def signature(p: Path) -> tuple[str, list[tuple[str, int]]]:
        return made[p], sorted((f.relative_to(p).as_posix(), f.stat().st_size) for f in p.rglob("*") if f.is_file())

    taken = set(paths.names.values())
    for p in sorted(made, key=signature):
        n, placeholder = 1, f"{made[p]}XXXXXXXX"
        while placeholder in taken:
            n += 1
            placeholder = f"{made[p]}XXXXXXXX-{n}"
        paths.names[p.name] = placeholder
        taken.add(placeholder)


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_step(step: Step, work: Path, logs: Path, env: Mapping[str, str], paths: Paths) -> tuple[dict[str, str], int]:
    """Run one step in work; the digest entries of what it printed and of the files it created or changed."""
    before = snapshot(work)
    tmp_before = {p.name for p in (work / "tmp").iterdir()}
    res = subprocess.run(step.argv, cwd=work, env=dict(env), input=step.stdin.encode() if step.stdin else None,
                         capture_output=True, timeout=1800)  # fmt: skip
    (logs / f"{step.name}.stdout").write_bytes(res.stdout)
    (logs / f"{step.name}.stderr").write_bytes(res.stderr)
    name_mkdtemps(work, paths, tmp_before)
    after = snapshot(work)
    digest = {
        f"{step.name}/<exit>": sha256(str(res.returncode).encode()),
        f"{step.name}/<stdout>": sha256(normalise_stdout(res.stdout, paths)),
        f"{step.name}/<stderr>": sha256(normalise_stderr(res.stderr, paths)),
    }
    for rel in sorted(after):
        if before.get(rel) != after[rel]:
            digest[f"{step.name}/{paths.key(rel)}"] = sha256(normalise_file(rel, (work / rel).read_bytes(), paths))
    for rel in sorted(set(before) - set(after)):
        digest[f"{step.name}/{paths.key(rel)}"] = DELETED
    return digest, res.returncode


def compute(keep: Path | None = None, only: set[str] | None = None,
            report: Callable[[str], None] = print) -> tuple[dict[str, str], list[str]]:  # fmt: skip
    """Run every step in a fresh temporary directory; the digest and the steps that exited unexpectedly."""
    root = Path(tempfile.mkdtemp(prefix="gonio-example-outputs-"))
    try:
        work, logs, site = root / "work", root / "logs", root / "site"
        work.mkdir()
        logs.mkdir()
        write_dist_info(ROOT / "pyproject.toml", site)
        prepare_workspace(work)
        env = subprocess_env(site)
        env["TMPDIR"] = str(work / "tmp")
        check_environment(env, work)
        paths = Paths(str(work))
        todo = [s for s in steps(ROOT / "README.md") if only is None or s.name in only]
        digest: dict[str, str] = {}
        failed: list[str] = []
        t_all, cpu_all = time.perf_counter(), _children_cpu_s()
        for i, step in enumerate(todo, 1):
            t0, cpu0 = time.perf_counter(), _children_cpu_s()
            entries, code = run_step(step, work, logs, env, paths)
            digest.update(entries)
            files = sum(1 for k in entries if not k.endswith(">"))
            flag = "" if code == step.expect else f"  UNEXPECTED (expected exit {step.expect})"
            if flag:
                failed.append(step.name)
            report(f"[{i:2d}/{len(todo)}] {step.name:<20} exit {code}, {files:3d} files, "
                   f"{time.perf_counter() - t0:6.1f} s (CPU {_children_cpu_s() - cpu0:5.1f} s){flag}")  # fmt: skip
        report(f"{len(todo)} commands, {sum(1 for k in digest if not k.endswith('>'))} files digested "
               f"({len(digest)} entries) in {time.perf_counter() - t_all:.0f} s "
               f"(CPU {_children_cpu_s() - cpu_all:.0f} s, load average {os.getloadavg()[0]:.1f})")  # fmt: skip
        return digest, failed
    finally:
        if keep is not None:
            shutil.copytree(root, keep, symlinks=True, dirs_exist_ok=True)
            report(f"kept the outputs and logs in {keep}")
        shutil.rmtree(root, ignore_errors=True)


def differences(base: Mapping[str, str], new: Mapping[str, str]) -> list[str]:
    """One line per entry that differs, is only in the base or only in the new digest."""
    out = []
    for key in sorted(set(base) | set(new)):
        if key not in new:
            out.append(f"only in base: {key}")
        elif key not in base:
            out.append(f"only in new:  {key}")
        elif base[key] != new[key]:
            out.append(f"differs:      {key}")
    return out


def main(argv: list[str] | None = None) -> int:
    """Entry point: record a digest (--out) and/or compare it with a recorded one (--compare); exit status."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--out", type=Path, help="write the digest here (JSON)")
    parser.add_argument("--compare", type=Path, metavar="BASE", help="compare with this digest; exit 1 if any differs")
    parser.add_argument("--keep", type=Path, metavar="DIR", help="keep the outputs and each command's output here")
    parser.add_argument("--steps", help="comma-separated step names to run (for debugging; later steps read "
                        "earlier steps' outputs)")  # fmt: skip
    parser.add_argument("--list", action="store_true", help="print the steps and their commands, run nothing")
    args = parser.parse_args(argv)
    if args.list:
        for s in steps(ROOT / "README.md"):
            shown = " ".join("python" if a == sys.executable else "CODE" if "\n" in a else a for a in s.argv)
            print(f"{s.name:<20} {shown}" + (f"   # {s.note}" if s.note else ""))
        return 0
    if args.out is None and args.compare is None:
        parser.error("give --out DIGEST.json, --compare BASE.json or both")
    base = json.loads(args.compare.read_text()) if args.compare else None
    only = set(args.steps.split(",")) if args.steps else None
    digest, failed = compute(args.keep, only)
    if args.out:
        args.out.write_text(json.dumps(digest, indent=1, sort_keys=True) + "\n")
        print(f"wrote {args.out}")
    if failed:
        print(f"exited other than expected: {', '.join(failed)} (logs: --keep DIR)")
    if base is not None:
        if only is not None:
            base = {k: v for k, v in base.items() if k.split("/", 1)[0] in only}
        diff = differences(base, digest)
        print("\n".join(diff) if diff else f"identical: all {len(digest)} entries agree with {args.compare}")
        if diff:
            print(f"{len(diff)} of {len(set(base) | set(digest))} entries differ")
            return 1
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
