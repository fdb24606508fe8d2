"""The run's table as Parquet (``samples.parquet`` beside ``samples.csv``): typed columns with units and meanings.

The CSV is what a person opens; the Parquet copy is what pandas, polars, DuckDB or Spark read as it is, with
the types right (booleans, integers, nullable floats, the bracket's exposures as a list of seconds) and no
parsing. Every column's unit and description is stored twice in the file's metadata: on its Arrow field
(``field.metadata[b"unit"]``, ``[b"description"]``; pyarrow, pandas and polars keep them) and as one JSON
document under the file's key-value metadata key ``gonio.columns`` (which any Parquet reader sees, DuckDB
through ``parquet_kv_metadata``). ``gonio.table`` names the layout (``TABLE_FORMAT``).

Rows may hold typed values (``rig.run.tables.samples.build_rows``) or the CSV's strings (a table read back, the
adaptive sweep's merged rows): each column's type follows from its name, so both give the same file.

The run's ``[metadata]`` (sample, operator, notes, free keys; ``rig.run.config.schema.Metadata``) travels as
the file-level key ``gonio.metadata`` (a JSON object). The CSV gets the same facts in a sidecar,
``samples.schema.json`` (:func:`schema_doc`): every column's type, unit and meaning, and the metadata.

The bracket's exposures (``exposures_s``) are a list column here and a JSON array in the CSV (``[0.01, 0.04]``);
tables written before that hold ``0.01;0.04``, which :func:`exposure_list` reads too.
"""

from __future__ import annotations

import json
import re
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from acquisition.files.atomic import atomic_path
from model.version import gonio_version

TABLE_FORMAT = "gonio-samples/1"
PARQUET_NAME = "samples.parquet"
#: Suffix of the CSV's sidecar: samples.csv -> samples.schema.json.
SCHEMA_SUFFIX = ".schema.json"
#: File-level key of the run's metadata in the Parquet file.
METADATA_KEY = "gonio.metadata"
_ANGLES = {"theta_i_deg": "incidence zenith", "phi_i_deg": "incidence azimuth", "theta_o_deg": "outgoing zenith",
           "phi_o_deg": "outgoing azimuth"}  # fmt: skip
_PER_CHANNEL = {
    "brdf": ("1/sr", "BRDF in channel {c}, calibrated against the reference tile (times cos theta_o if "
             "includes_cosine); empty without a reference"),
    "brdf_se": ("1/sr", "standard error of brdf_{c}: readings, reference readings and the tile's albedo"),
    "brdf_se_readings": ("1/sr", "standard error of brdf_{c} without the tile albedo's share, which is common to "
                         "every point of the run"),
    "reading": ("counts/s", "ROI mean of the HDR merge in channel {c} at gain 1, before calibration"),
    "reading_se": ("counts/s", "standard error of reading_{c}"),
}  # fmt: skip
_FIXED = {
    "index": ("int", "", "the point's index in the sweep file's list of directions"),
    "includes_cosine": ("bool", "", "true when brdf_* holds f_r cos(theta_o) instead of f_r"),
    "lower_bound": ("bool", "", "true when pixels saturated in every frame: the value is a lower bound"),
    "dark": ("bool", "", "true when the ROI showed no light even after metering: the value is noise about zero"),
    "n_frames": ("int", "", "frames in the exposure bracket (top-up included)"),
    "total_exposure_s": ("float", "s", "sum of the bracket's exposure times"),
    "exposures_s": ("list", "s", "exposure time of each frame of the bracket, in capture order (CSV: a JSON array)"),
    "utc": ("str", "", "UTC time (ISO 8601) the point's journal record was made, right after its reading; "
            "empty in older journals"),
    "tile": ("int", "", "image mode only: the k x k pixel tile of the sensor the sample is (row * columns + "
             "column of the sensor's tile grid); several rows share a point's index, one per tile on the sample"),
    "round": ("int", "", "round of the adaptive sweep that measured the point (0 is the space-filling start)"),
    "direction_cov": ("str", "", "JSON: the 4 x 4 covariance of the local unit directions' tangent components wi_x, "
                      "wi_y, wo_x, wo_y (dimensionless, rad^2 for small errors); empty in older journals"),
}
for _a, _text in _ANGLES.items():
    _FIXED[_a.replace("_deg", "_std_deg")] = (
        "float", "deg", f"standard uncertainty of the measured {_text} (joints and geometry); empty in older journals"
    )
_CHANNEL_COLUMN = re.compile(r"^(?P<what>brdf|brdf_se|brdf_se_readings|reading|reading_se)_(?P<c>[a-z0-9]+)$")


@dataclass(frozen=True)
class Column:
    """A column's type (int, float, bool, str, list of floats, map of str to float), unit ("" if none), meaning."""

    kind: str
    unit: str
    description: str


def column(name: str) -> Column:
    """What a column of the run's table holds, from its name (unknown names: text, undescribed)."""
    if name in _FIXED:
        return Column(*_FIXED[name])
    if name in _ANGLES:
        return Column("float", "deg", f"measured {_ANGLES[name]} (from the joint angles read back), local frame")
    if name.startswith("target_") and name[7:] in _ANGLES:
        return Column("float", "deg", f"{_ANGLES[name[7:]]} the sweep asked for")
    m = _CHANNEL_COLUMN.match(name)
    if m:
        unit, text = _PER_CHANNEL[m["what"]]
        return Column("float", unit, text.format(c=m["c"]))
    if name.endswith("_deg"):
        return Column("float", "deg", f"angle of the {name[:-4]} joint, read back from the axis after the move")
    return Column("str", "", "not described by gonio (a column added to the table after this writer)")


def _value(kind: str, value: Any, where: str) -> Any:
    if value is None or value == "":
        return [] if kind == "list" else None
    try:
        if kind == "float":
            return float(value)
        if kind == "int":
            return int(value)
        if kind == "bool":
            if isinstance(value, str):
                if value.lower() not in ("true", "false"):
                    raise ValueError(f"{value!r} is not true or false")
                return value.lower() == "true"
            return bool(value)
        if kind == "list":
            return exposure_list(value)
        if kind == "map":
            return [(str(k), None if v is None else float(v)) for k, v in dict(value).items()]
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{where}: {value!r} is not a {kind} ({exc})") from None
    return str(value)


def exposure_list(value: Any) -> list[float]:
    """A list cell as floats: a list, a JSON array (``[0.01, 0.04]``) or an older table's ``0.01;0.04``."""
    if value is None or value == "":
        return []
    if isinstance(value, str):
        text = value.strip()
        parts = json.loads(text) if text.startswith("[") else text.split(";")
        if not isinstance(parts, list):
            raise ValueError(f"{value!r} is not a list")
        return [float(v) for v in parts]
    return [float(v) for v in value]


def parquet_table(
    rows: Sequence[Mapping[str, Any]],
    columns: Sequence[str] | None = None,
    *,
    describe: Callable[[str], Column] = column,
    table_format: str = TABLE_FORMAT,
    metadata: Mapping[str, str] | None = None,
) -> Any:
    """The rows as a ``pyarrow.Table`` with units and descriptions on every field and in the file metadata.

    ``describe`` gives each column's type, unit and meaning (default: the run table's :func:`column`);
    ``metadata`` adds file-level keys beside ``gonio.table`` (= ``table_format``), ``gonio.version`` and
    ``gonio.columns``.
    """
    import pyarrow as pa

    cols = list(dict.fromkeys(k for row in rows for k in row) if columns is None else columns)
    types = {"float": pa.float64(), "int": pa.int64(), "bool": pa.bool_(), "str": pa.string(),
             "list": pa.list_(pa.float64()), "map": pa.map_(pa.string(), pa.float64())}  # fmt: skip
    fields, arrays, docs = [], [], {}
    for name in cols:
        info = describe(name)
        values = [_value(info.kind, row.get(name), f"row {i}, column {name!r}") for i, row in enumerate(rows)]
        fields.append(pa.field(name, types[info.kind], metadata={"unit": info.unit, "description": info.description}))
        arrays.append(pa.array(values, type=types[info.kind]))
        docs[name] = {"unit": info.unit, "description": info.description}
    meta = {"gonio.table": table_format, "gonio.version": gonio_version(), "gonio.columns": json.dumps(docs),
            **(metadata or {})}  # fmt: skip
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields, metadata=meta))


def write_parquet(path: str | Path, rows: Sequence[Mapping[str, Any]], columns: Sequence[str] | None = None,
                  **how: Any) -> Path:  # fmt: skip
    """Write the rows to ``path`` as Parquet atomically (temporary file, fsync, rename); ValueError on a bad value.

    ``how`` goes to :func:`parquet_table` (``describe``, ``table_format``, ``metadata``).
    """
    import pyarrow.parquet as pq

    table = parquet_table(rows, columns, **how)
    target = Path(path)
    with atomic_path(target) as tmp:
        pq.write_table(table, tmp)
        tmp.chmod(0o644)
    return target


class ParquetWarning(UserWarning):
    """The Parquet copy of a table could not be written; the CSV, which is the record, stands."""


def schema_doc(
    rows: Sequence[Mapping[str, Any]], metadata: Mapping[str, Any] | None = None, *, table: str = "samples.csv"
) -> dict[str, Any]:
    """The CSV's sidecar: the table's format, every column's type, unit and meaning, and the run's metadata."""
    cols = list(dict.fromkeys(k for row in rows for k in row))
    columns = {}
    for name in cols:
        info = column(name)
        columns[name] = {"type": info.kind, "unit": info.unit, "description": info.description}
        if info.kind == "list":
            columns[name]["csv"] = "a JSON array of numbers in one cell"
    return {"table": table, "format": TABLE_FORMAT, "gonio_version": gonio_version(), "columns": columns,
            "metadata": dict(metadata or {})}  # fmt: skip


def write_schema(csv_path: str | Path, rows: Sequence[Mapping[str, Any]], metadata: Mapping[str, Any] | None = None
                 ) -> Path:  # fmt: skip
    """Write ``<stem>.schema.json`` beside the CSV at ``csv_path`` atomically; returns its path."""
    target = Path(csv_path).with_name(Path(csv_path).stem + SCHEMA_SUFFIX)
    text = json.dumps(schema_doc(rows, metadata, table=Path(csv_path).name), indent=2, allow_nan=False) + "\n"
    with atomic_path(target) as tmp:
        tmp.write_text(text, encoding="utf-8")
        tmp.chmod(0o644)
    return target


def write_beside(
    csv_path: str | Path, rows: Sequence[Mapping[str, Any]], metadata: Mapping[str, Any] | None = None
) -> Path | None:
    """Write the CSV's sidecar schema and its Parquet copy (same stem); None and a warning if Parquet fails.

    The CSV is the run's record and is written first: a Parquet copy that cannot be written (a full disk, a
    value no Parquet type holds) must not keep a measured run from being marked finished. ``metadata`` is the
    run's ``[metadata]``: the sidecar and the Parquet file's ``gonio.metadata`` key carry it.
    """
    target = Path(csv_path).with_suffix(".parquet")
    try:
        write_schema(csv_path, rows, metadata)
    except (OSError, ValueError, TypeError) as exc:
        warnings.warn(f"{csv_path}: its schema sidecar was not written: {exc}", ParquetWarning, stacklevel=2)
    try:
        meta = {METADATA_KEY: json.dumps(dict(metadata or {}), allow_nan=False)}
        return write_parquet(target, rows, metadata=meta)
    except (OSError, ValueError, TypeError, ImportError) as exc:
        warnings.warn(f"{target}: the Parquet copy of {Path(csv_path).name} was not written: {exc}", ParquetWarning,
                      stacklevel=2)  # fmt: skip
        return None
