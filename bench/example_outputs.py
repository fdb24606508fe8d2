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

Normalisation takes out what depends on the wall clock or on the process, and only that. A value is replaced by
``<normalised>`` (so a key or column that disappears is still a difference), everything around it kept byte for
byte:

- JSON keys (``JSON_KEYS``; a name at any depth, a dotted name a path from the root): ``manifest.json``
  ``created_utc`` (when the run began); ``journal.jsonl`` ``utc`` (when each point or reference was read: the
  simulated rig's ``rig_time_s``/``run_time_s`` are simulated and kept); ``status.json`` ``time_utc`` (when the
  state was written); a run's ``lock`` ``pid``, ``host``, ``since`` (the process that held it and since when: it
  stays behind a finished run, and ``gonio resume`` retakes it); ``camera_calibration.json`` and
  ``geometry_calibration.json`` ``created_utc`` (when it was made); a batch's or study's ``.tasks/*.json``
  ``worker`` (host:pid of the Dask worker), ``started_utc``, ``finished_utc``, ``created_utc`` (the run's),
  ``fingerprint`` (a digest of the inputs' modification times, which earlier steps set) and the task's timings
  ``fit_s``, ``candidates_s``, ``report_s``, ``wall_s``, ``cpu_s``. (An export's ``material.json`` is digested as
  it is: the errors Mitsuba's ``measured`` plugin shows, whose last bits vary from one ``gonio analyze`` process to
  the next, are written to 4 significant digits, ``model.mitsuba.projection.rounded_error``.)
- CSV columns (``CSV_COLUMNS``): ``samples.csv`` ``utc`` (each point's time), in every row.
- Parquet columns (``PARQUET_COLUMNS``): ``samples.parquet`` ``utc``; ``catalogue.parquet`` ``created_utc``,
  ``wall_s``, ``cpu_s``, ``fit_s``, ``worker``, ``finished_utc``, ``fingerprint`` (as in the task records). A
  Parquet file is digested by its parts, not its bytes (a column's values change its compressed pages): the
  writer, format version, key-value metadata and Arrow schema (units, descriptions), per row group and column the
  type, codec, encodings and count, for every other column also its statistics and sizes and every value; of a
  normalised column only which rows are null.
- Text (``LINE_PATTERNS``): a batch's or study's ``.lock``, ``of HOST:PID since UTC``.
- ``.npz`` archives (zip): the members' names, compression and contents, not their time stamps, which zip takes
  from the wall clock when the file is written.
- Every file, stdout and stderr: the temporary directory's absolute path, which appears in what records or prints
  absolute paths (raw_sweep.py's run manifest and output, a study's records, a README block's fit.json, the
  batch's printed paths), becomes ``<work>``, and the random part of a directory ``tempfile.mkdtemp`` made in it
  (raw_sweep.py's, the README blocks') ``XXXXXXXX``, in the digest's keys as well.
- stdout and stderr: ISO 8601 UTC time stamps (``gonio plan`` prints the geometry calibration's) become ``<utc>``.
  stderr also loses tqdm's progress bars (``\\r``-updated, with rates and ETAs), the fit times that end
  ``gonio analyze``'s ``fitting ... (0.25 s)`` lines and the port of the local Dask dashboard (any free one).

Not digested: Dask's scratch space (``tmp/dask-scratch-space``: its empty lock files are Dask's) and
``__pycache__``. Everything else was the same bytes in two runs at fe5004d: PNG figures (matplotlib writes no
date), the MERL tables, the renders (seeded), what the figure processes and the Dask workers write. The commands
inherit the environment but for ``PYTHONPATH``, ``TMPDIR`` (in the temporary directory), ``COLUMNS``/``LINES``
(fixed: argparse wraps the help at the terminal's width), ``PYTHONIOENCODING``, ``MPLBACKEND`` and
``PYTHONHASHSEED`` (unset, so random, as for a user).
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import io
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
import zipfile
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath
from typing import TypeVar

ROOT = Path(__file__).resolve().parent.parent
T = TypeVar("T")
PLACEHOLDER = "<normalised>"
DELETED = "deleted"

#: JSON keys whose values are wall-clock or process dependent, by file (a pattern matched from the path's right).
JSON_KEYS: dict[str, tuple[str, ...]] = {
    "manifest.json": ("created_utc",),
    "journal.jsonl": ("utc",),
    "status.json": ("time_utc",),
    "lock": ("pid", "host", "since"),
    "camera_calibration.json": ("created_utc",),
    "geometry_calibration.json": ("created_utc",),
    ".tasks/*.json": ("worker", "started_utc", "finished_utc", "created_utc", "fingerprint",
                      "fit_s", "candidates_s", "report_s", "wall_s", "cpu_s"),
}  # fmt: skip
#: CSV columns whose every value is wall-clock dependent, by file.
CSV_COLUMNS: dict[str, tuple[str, ...]] = {"samples.csv": ("utc",)}
#: Parquet columns whose every value is wall-clock or process dependent, by file.
PARQUET_COLUMNS: dict[str, tuple[str, ...]] = {
    "samples.parquet": ("utc",),
    "catalogue.parquet": ("created_utc", "wall_s", "cpu_s", "fit_s", "worker", "finished_utc", "fingerprint"),
}
#: Regular expressions (and their replacements) of wall-clock or process dependent text, by file.
LINE_PATTERNS: dict[str, tuple[tuple[str, str], ...]] = {
    ".lock": ((r"\bof \S+:\d+ since \S+", f"of {PLACEHOLDER} since {PLACEHOLDER}"),),
}
#: Directories (relative to the temporary directory) never digested, and directory names never digested anywhere.
EXCLUDED_DIRS = ("tmp/dask-scratch-space/",)
EXCLUDED_NAMES = ("__pycache__",)

#: An ISO 8601 time stamp in UTC, as gonio prints them.
UTC_STAMP = re.compile(rb"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(?:\.\d+)?\+00:00")
#: A directory name made by tempfile.mkdtemp: its prefix, then eight random characters.
MKDTEMP_NAME = re.compile(r"^(tmp|.*[-_])[a-z0-9_]{8}$")
#: A tqdm progress bar's segment of stderr.
PROGRESS_BAR = re.compile(rb"\d+%\|")
#: The fit time that ends a ``fitting ...`` line of gonio analyze.
FIT_TIME = re.compile(rb"^(fitting .*) \(\d+(?:\.\d+)? s\)$")
DASHBOARD = re.compile(rb"http://127\.0\.0\.1:\d+")


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


# --- normalisation -----------------------------------------------------------------------------------------


def _rule(table: Mapping[str, T], rel: str) -> T | None:
    path = PurePosixPath(rel)
    return next((v for pattern, v in table.items() if path.match(pattern)), None)


_WS = re.compile(r"[ \t\n\r]*")
_DECODER = json.JSONDecoder()


def _skip_ws(text: str, pos: int) -> int:
    m = _WS.match(text, pos)
    return m.end() if m else pos


def _json_value_spans(text: str, pos: int, path: tuple[str, ...], wanted: Callable[[tuple[str, ...]], bool],
                      spans: list[tuple[int, int]]) -> int:  # fmt: skip
    """Scan the JSON value at ``pos``; record the spans of the values (inside it) whose path is wanted; its end."""
    if text[pos] not in "{[":
        return int(_DECODER.raw_decode(text, pos)[1])
    is_object, close = text[pos] == "{", "}" if text[pos] == "{" else "]"
    pos, index = _skip_ws(text, pos + 1), 0
    if text.startswith(close, pos):
        return pos + 1
    while True:
        if is_object:
            key, pos = _DECODER.raw_decode(text, pos)
            pos = _skip_ws(text, _skip_ws(text, pos) + 1)  # past the colon
        else:
            key, index = index, index + 1
        end = _json_value_spans(text, pos, (*path, str(key)), wanted, spans)
        if wanted((*path, str(key))):
            spans.append((pos, end))
        pos = _skip_ws(text, end)
        if text.startswith(close, pos):
            return pos + 1
        pos = _skip_ws(text, pos + 1)  # past the comma


def json_key_matcher(keys: Iterable[str]) -> Callable[[tuple[str, ...]], bool]:
    """Whether a value's path is one of ``keys``: a name (at any depth) or a dotted path from the root (``*``: any)."""
    names = {k for k in keys if "." not in k}
    paths = [k.split(".") for k in keys if "." in k]

    def wanted(path: tuple[str, ...]) -> bool:
        return path[-1] in names or any(
            len(p) == len(path) and all(a in ("*", b) for a, b in zip(p, path, strict=True)) for p in paths
        )

    return wanted


def normalise_json_keys(text: str, keys: Iterable[str]) -> str:
    """``text`` (JSON or JSON Lines) with the value of each key replaced by the placeholder, formatting kept.

    A key is a name, replaced at any depth, or a dotted path from the root (``facts.mitsuba_tabulated.error``;
    ``*`` matches any key or list index). Object keys inside a replaced value are not looked at.
    """
    wanted, pos = json_key_matcher(keys), 0
    spans: list[tuple[int, int]] = []
    while (pos := _skip_ws(text, pos)) < len(text):  # JSON Lines: one value after the other
        pos = _json_value_spans(text, pos, (), wanted, spans)
    out, last = [], 0
    for start, end in sorted(spans):
        if start >= last:  # not inside a value already replaced
            out += [text[last:start], json.dumps(PLACEHOLDER)]
            last = end
    return "".join([*out, text[last:]])


def normalise_csv_columns(text: str, columns: Iterable[str]) -> str:
    """``text`` (CSV with a header) with every row's field in each column replaced by the placeholder."""
    lines = text.splitlines(keepends=True)
    reader = csv.reader(lines)
    header = next(reader, None)
    if header is None:
        return text
    index = [header.index(c) for c in columns if c in header]
    out, start = lines[: reader.line_num], reader.line_num
    for row in reader:
        span = "".join(lines[start : reader.line_num])
        start = reader.line_num
        for i in index:
            value = row[i] if i < len(row) else ""
            if value:
                if span.count(value) != 1:
                    raise ValueError(f"cannot normalise column {header[i]!r}: {value!r} is not unique in {span!r}")
                span = span.replace(value, PLACEHOLDER)
        out.append(span)
    return "".join(out)


def parquet_canonical(data: bytes, columns: Iterable[str]) -> bytes:
    """A Parquet file's metadata and values in a canonical form, the given columns' values left out but nulls."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    volatile = set(columns)
    f = pq.ParquetFile(pa.BufferReader(data))
    md = f.metadata
    parts: list[object] = [md.created_by, md.format_version, md.num_rows, md.num_row_groups, md.num_columns,
                           sorted((md.metadata or {}).items())]  # fmt: skip
    for g in range(md.num_row_groups):
        rg = md.row_group(g)
        parts.append(("row group", g, rg.num_rows))
        for c in range(rg.num_columns):
            col = rg.column(c)
            parts.append((col.path_in_schema, col.physical_type, col.compression, col.encodings,
                          col.has_dictionary_page, col.num_values))  # fmt: skip
            if col.path_in_schema.split(".")[0] not in volatile:
                s = col.statistics
                stats = (s.has_min_max and (s.min, s.max), s.null_count, s.num_values) if s is not None else None
                parts.append((stats, col.total_compressed_size, col.total_uncompressed_size))
    table = f.read()
    for name in table.column_names:
        if name in volatile:
            parts.append((name, table.column(name).is_null().to_pylist()))
    kept = table.drop_columns([n for n in table.column_names if n in volatile])
    sink = io.BytesIO()
    with pa.ipc.new_stream(sink, kept.schema) as writer:
        writer.write_table(kept)
    return repr(parts).encode() + f.schema_arrow.serialize().to_pybytes() + sink.getvalue()


def zip_canonical(data: bytes) -> bytes:
    """A zip archive (``.npz``) as its members' names, compression and contents, without their time stamps."""
    out = io.BytesIO()
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        for info in z.infolist():
            body = z.read(info)
            out.write(f"{info.filename}\0{info.compress_type}\0{len(body)}\0".encode() + body)
    return out.getvalue()


@dataclass
class Paths:
    """Replacements of process-dependent path text: the temporary directory and mkdtemp names inside it."""

    work: str
    names: dict[str, str] = field(default_factory=dict)

    def text(self, data: bytes) -> bytes:
        """``data`` with the work directory's path and every mkdtemp name replaced."""
        data = data.replace(self.work.encode(), b"<work>")
        for real, placeholder in self.names.items():
            data = data.replace(real.encode(), placeholder.encode())
        return data

    def key(self, rel: str) -> str:
        """A relative path with mkdtemp names replaced."""
        parts = rel.split("/")
        return "/".join(self.names.get(p, p) for p in parts)


def normalise_file(rel: str, data: bytes, paths: Paths) -> bytes:
    """The bytes of a file digested: its content with the wall-clock and process-dependent parts normalised."""
    if rel.endswith(".npz"):
        return paths.text(zip_canonical(data))
    if (cols := _rule(PARQUET_COLUMNS, rel)) is not None:
        return paths.text(parquet_canonical(data, cols))
    data = paths.text(data)
    if (keys := _rule(JSON_KEYS, rel)) is not None:
        data = normalise_json_keys(data.decode(), keys).encode()
    if (cols := _rule(CSV_COLUMNS, rel)) is not None:
        data = normalise_csv_columns(data.decode(), cols).encode()
    for pattern, repl in _rule(LINE_PATTERNS, rel) or ():
        data = re.sub(pattern.encode(), repl.encode(), data)
    return data


def normalise_stdout(data: bytes, paths: Paths) -> bytes:
    """A command's stdout without its temporary paths and UTC time stamps."""
    return UTC_STAMP.sub(b"<utc>", paths.text(data))


def normalise_stderr(data: bytes, paths: Paths) -> bytes:
    """A command's stderr as stdout, and without progress bars, fit times and the dashboard's port."""
    lines = []
    for segment in re.split(rb"[\r\n]", normalise_stdout(data, paths)):
        if not segment.strip() or PROGRESS_BAR.search(segment):
            continue
        segment = FIT_TIME.sub(rb"\1", segment)
        lines.append(DASHBOARD.sub(b"http://127.0.0.1:<port>", segment))
    return b"\n".join(lines)


def sha256(data: bytes) -> str:
    """Hex SHA-256 of data."""
    return hashlib.sha256(data).hexdigest()


# --- the run -----------------------------------------------------------------------------------------------


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
