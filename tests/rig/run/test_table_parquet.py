"""samples.parquet beside samples.csv: the same rows typed, with units and meanings, read by pyarrow and DuckDB."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from rig.run.session import start_run
from rig.run.table_parquet import TABLE_FORMAT, ParquetWarning, column, parquet_table, write_beside, write_parquet
from tests.run_helpers import GOLD, in_plane_sweep, sim_rig


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("parquet") / "run"
    start_run(sim_rig(GOLD), in_plane_sweep([30.0], [-40.0, 0.0, 20.0, 50.0]), out, progress=False)
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
    assert exposures == [[float(t) for t in r["exposures_s"].split(";")] for r in rows]
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
              "exposures_s": "0.001;0.004", "round": 2}]  # fmt: skip
    text = [{"index": "0", "theta_i_deg": "10.0", "brdf_r": "0.25", "brdf_se_r": "", "lower_bound": "false",
             "exposures_s": "0.001;0.004", "round": "2"}]  # fmt: skip
    a, b = write_parquet(tmp_path / "a.parquet", typed), write_parquet(tmp_path / "b.parquet", text)
    assert a.read_bytes() == b.read_bytes()
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
