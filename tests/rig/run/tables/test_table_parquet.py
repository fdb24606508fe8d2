"""samples.parquet beside samples.csv: the same rows typed, with units and meanings, read by pyarrow and DuckDB; the
CSV's sidecar samples.schema.json; the run's [metadata] in the manifest, both tables and the sidecar; UTC per point."""

from __future__ import annotations

import csv
import datetime
import json
import math
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from rig.run.config.files import parse, sweep_config
from rig.run.config.schema import SweepFile
from rig.run.session import start_run
from rig.run.tables.parquet import (
    METADATA_KEY,
    TABLE_FORMAT,
    ParquetWarning,
    column,
    exposure_list,
    parquet_table,
    write_beside,
    write_parquet,
)
from tests.run_helpers import GOLD, sim_rig

RIG_METADATA = {"operator": "rig owner", "lab": "optics 2", "notes": "lamp replaced in May"}
SWEEP_METADATA = {"sample": "gold foil #7", "operator": "A. Tester", "batch": 12, "tags": ["metal", "reference"]}


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("parquet") / "run"
    doc = {"metadata": SWEEP_METADATA, "sweep": {"kind": "in_plane", "theta_i_deg": [30.0],
                                                  "theta_o_deg": [-40.0, 0.0, 20.0, 50.0]}}  # fmt: skip
    sweep = sweep_config(parse(doc, SweepFile, "meta-sweep.toml"), "meta-sweep.toml")
    start_run(sim_rig(GOLD, metadata=RIG_METADATA), sweep, out, progress=False)
    return out


def csv_rows(run: Path) -> list[dict[str, str]]:
    with open(run / "samples.csv", newline="") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.mitsuba
def test_a_finished_run_has_its_table_as_parquet_with_units(run: Path) -> None:
    rows = csv_rows(run)
    table = pq.read_table(run / "samples.parquet")
    assert table.column_names == list(rows[0]) and table.num_rows == len(rows) == 4
    # Typed: numbers as numbers, flags as booleans, the bracket as a list of seconds; values exactly the CSV's.
    assert table.schema.field("index").type == "int64" and table.schema.field("lower_bound").type == "bool"
    assert table.column("brdf_g").to_pylist() == [float(r["brdf_g"]) for r in rows]
    assert table.column("light_deg").to_pylist() == [float(r["light_deg"]) for r in rows]
    exposures = table.column("exposures_s").to_pylist()
    assert exposures == [json.loads(r["exposures_s"]) for r in rows] and all(len(e) >= 1 for e in exposures)
    assert all(math.isclose(sum(e), float(r["total_exposure_s"])) for e, r in zip(exposures, rows, strict=True))
    # Every column is described, on its field and in the file's key-value metadata.
    docs = json.loads(table.schema.metadata[b"gonio.columns"])
    assert table.schema.metadata[b"gonio.table"].decode() == TABLE_FORMAT and set(docs) == set(table.column_names)
    for name in table.column_names:
        field = table.schema.field(name)
        assert field.metadata[b"description"].decode() == docs[name]["description"]
        assert "not described" not in docs[name]["description"], name
    assert docs["brdf_r"]["unit"] == "1/sr" and docs["reading_se_b"]["unit"] == "counts/s"
    assert docs["camera_deg"]["unit"] == "deg" and "camera joint" in docs["camera_deg"]["description"]


@pytest.mark.mitsuba
def test_duckdb_reads_it_without_pandas(run: Path) -> None:
    duckdb = pytest.importorskip("duckdb")
    path = str(run / "samples.parquet")
    con = duckdb.connect()
    n, mean_r, frames = con.execute(
        "SELECT count(*), avg(brdf_r), sum(len(exposures_s)) FROM read_parquet(?)", [path]).fetchone()
    rows = csv_rows(run)
    assert n == len(rows) and frames == sum(int(r["n_frames"]) for r in rows)
    assert mean_r == pytest.approx(sum(float(r["brdf_r"]) for r in rows) / len(rows), rel=1e-12)
    kv = dict(con.execute("SELECT key, value FROM parquet_kv_metadata(?)", [path]).fetchall())
    assert json.loads(kv[b"gonio.columns"])["theta_i_deg"]["unit"] == "deg"


def test_typed_rows_and_csv_strings_give_the_same_file(tmp_path: Path) -> None:
    typed = [{"index": 0, "theta_i_deg": 10.0, "brdf_r": 0.25, "brdf_se_r": None, "lower_bound": False,
              "exposures_s": [0.001, 0.004], "round": 2}]  # fmt: skip
    text = [{"index": "0", "theta_i_deg": "10.0", "brdf_r": "0.25", "brdf_se_r": "", "lower_bound": "false",
             "exposures_s": "[0.001, 0.004]", "round": "2"}]  # fmt: skip
    old = [{**text[0], "exposures_s": "0.001;0.004"}]  # a table written before exposures were a JSON array
    a, b = write_parquet(tmp_path / "a.parquet", typed), write_parquet(tmp_path / "b.parquet", text)
    assert a.read_bytes() == b.read_bytes() == write_parquet(tmp_path / "c.parquet", old).read_bytes()
    got = pq.read_table(a).to_pylist()[0]
    assert got == {**typed[0], "exposures_s": [0.001, 0.004]}


def test_a_bad_value_names_its_row_and_column_and_the_csv_stands(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"row 1, column 'lower_bound': 'maybe' is not a bool"):
        parquet_table([{"lower_bound": "true"}, {"lower_bound": "maybe"}])
    table = tmp_path / "samples.csv"
    table.write_text("lower_bound\nmaybe\n")
    with pytest.warns(ParquetWarning, match="samples.parquet: the Parquet copy of samples.csv was not written"):
        assert write_beside(table, [{"lower_bound": "maybe"}]) is None
    assert not (tmp_path / "samples.parquet").exists() and table.read_text() == "lower_bound\nmaybe\n"


def test_columns_gonio_does_not_know_are_kept_as_text() -> None:
    assert column("operator_note").kind == "str" and column("brdf_se_readings_g").unit == "1/sr"
    assert column("target_phi_o_deg").description == "outgoing azimuth the sweep asked for"


def test_exposure_lists_old_and_new_and_a_bad_one() -> None:
    assert exposure_list("[0.01, 0.04]") == exposure_list("0.01;0.04") == exposure_list([0.01, 0.04]) == [0.01, 0.04]
    assert exposure_list("") == [] and exposure_list("0.5") == [0.5]
    with pytest.raises(ValueError):
        exposure_list('{"a": 1}')


@pytest.mark.mitsuba
def test_metadata_and_units_travel_with_the_tables(run: Path) -> None:
    merged = {**RIG_METADATA, **SWEEP_METADATA}  # the sweep's keys win: it is about this measurement
    assert merged["operator"] == "A. Tester"
    manifest = json.loads((run / "manifest.json").read_text())
    assert manifest["metadata"] == merged and manifest["rig"]["metadata"] == RIG_METADATA
    table = pq.read_table(run / "samples.parquet")
    assert json.loads(table.schema.metadata[METADATA_KEY.encode()]) == merged
    schema = json.loads((run / "samples.schema.json").read_text())
    rows = csv_rows(run)
    assert schema["metadata"] == merged and schema["table"] == "samples.csv" and schema["format"] == TABLE_FORMAT
    assert list(schema["columns"]) == list(rows[0])  # every CSV column, in order, with its unit and meaning
    assert schema["columns"]["brdf_r"]["unit"] == "1/sr" and schema["columns"]["theta_i_deg"]["unit"] == "deg"
    assert schema["columns"]["exposures_s"] == {**schema["columns"]["exposures_s"], "type": "list", "unit": "s"}
    assert all(c["description"] and "not described" not in c["description"] for c in schema["columns"].values())


@pytest.mark.mitsuba
def test_every_point_has_its_utc_time(run: Path) -> None:
    rows = csv_rows(run)
    journal = [json.loads(line) for line in (run / "journal.jsonl").read_text().splitlines()]
    points = {r["index"]: r for r in journal if r.get("kind") == "point"}
    times = [datetime.datetime.fromisoformat(r["utc"]) for r in rows]
    assert all(t.tzinfo is not None and t.utcoffset() == datetime.timedelta(0) for t in times)
    assert [r["utc"] for r in rows] == [points[int(r["index"])]["utc"] for r in rows]
    assert pq.read_table(run / "samples.parquet").column("utc").to_pylist() == [r["utc"] for r in rows]
