"""How bench.example_outputs normalises a file or a stream before it digests it.

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
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import re
import zipfile
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import PurePosixPath
from typing import TypeVar

T = TypeVar("T")
PLACEHOLDER = "<normalised>"

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

#: An ISO 8601 time stamp in UTC, as gonio prints them.
UTC_STAMP = re.compile(rb"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d(?:\.\d+)?\+00:00")
#: A tqdm progress bar's segment of stderr.
PROGRESS_BAR = re.compile(rb"\d+%\|")
#: The fit time that ends a ``fitting ...`` line of gonio analyze.
FIT_TIME = re.compile(rb"^(fitting .*) \(\d+(?:\.\d+)? s\)$")
DASHBOARD = re.compile(rb"http://127\.0\.0\.1:\d+")


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
