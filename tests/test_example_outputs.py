"""bench/example_outputs.py's normalisers (bench/_normalise.py) take out exactly the keys, columns and text they list,
nothing else.

The examples themselves are not run here (minutes); only the normalisation, on small made-up files.
"""

from __future__ import annotations

import io
import json
import zipfile

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from bench._normalise import (
    JSON_KEYS,
    PLACEHOLDER,
    Paths,
    normalise_csv_columns,
    normalise_file,
    normalise_json_keys,
    normalise_stderr,
    normalise_stdout,
    parquet_canonical,
    zip_canonical,
)

P = json.dumps(PLACEHOLDER)


def test_a_json_key_is_normalised_wherever_it_is_and_the_rest_stays_byte_for_byte():
    text = '{\n  "a": 1,\n  "utc": "2026-01-01T00:00:00+00:00",\n  "b": {"utc": [1, {"x": 2}], "c": "utc"}\n}\n'
    want = f'{{\n  "a": 1,\n  "utc": {P},\n  "b": {{"utc": {P}, "c": "utc"}}\n}}\n'
    assert normalise_json_keys(text, ["utc"]) == want


def test_a_dotted_key_is_a_path_from_the_root_and_json_lines_are_read_one_value_after_the_other():
    text = '{"facts": {"t": {"error": {"rms": 0.1}}, "p": {"error": 2}}, "error": 3}\n{"error": 4}\n'
    assert normalise_json_keys(text, ["facts.t.error"]) == text.replace('{"rms": 0.1}', P)
    assert normalise_json_keys(text, ["facts.*.error"]) == text.replace('{"rms": 0.1}', P).replace(": 2}", f": {P}}}")
    lines = '{"utc":"x","u":1}\n{"k":[{"utc":"y"}],"utc":"z"}\n'
    assert normalise_json_keys(lines, ["utc"]) == f'{{"utc":{P},"u":1}}\n{{"k":[{{"utc":{P}}}],"utc":{P}}}\n'


def test_each_file_loses_exactly_its_listed_keys():
    for pattern, keys in JSON_KEYS.items():
        names = [k for k in keys if "." not in k]
        doc = {k: f"value of {k}" for k in names} | {"kept": "2026-01-01T00:00:00+00:00", "n": 1.5}
        rel = "runs/x/" + pattern.replace("*", "task")
        got = json.loads(normalise_file(rel, json.dumps(doc, indent=2).encode(), Paths("/nowhere")))
        assert got == {k: PLACEHOLDER if k in names else v for k, v in doc.items()}, rel
    # An export's material.json is digested as it is (gonio writes Mitsuba's measured errors rounded).
    material = json.dumps({"facts": {"mitsuba_tabulated": {"error": {"rms_rel": 0.01561}}}}).encode()
    assert normalise_file("a/export/material.json", material, Paths("/nowhere")) == material
    lock = b"batch of vm:4242 since 2026-12-03T22:29:56.092826+00:00"
    assert normalise_file("studies/gold/.lock", lock, Paths("/nowhere")) == b"batch of <normalised> since <normalised>"


def test_a_csv_column_is_normalised_in_every_row_and_quoted_fields_stay():
    text = 'index,cov,utc\r\n0,"[[1,2],[3,4]]",2026-01-01T00:00:00+00:00\r\n1,"[[5]]",2026-01-01T00:00:01+00:00\r\n'
    assert normalise_csv_columns(text, ["utc"]) == text.replace("2026-01-01T00:00:00+00:00", PLACEHOLDER).replace(
        "2026-01-01T00:00:01+00:00", PLACEHOLDER
    )


def _parquet(utc: list[str], value: list[float]) -> bytes:
    sink = io.BytesIO()
    table = pa.table({"value": value, "utc": utc}).replace_schema_metadata({"gonio.table": "t/1"})
    pq.write_table(table, sink)
    return sink.getvalue()


def test_a_parquet_file_is_digested_without_its_normalised_column_but_with_every_other_value():
    a = _parquet(["2026-01-01T00:00:00+00:00", "2026-01-01T00:00:01+00:00"], [1.0, 2.0])
    b = _parquet(["2027-12-31T23:59:59+00:00", "2027-12-31T23:59:58+00:00"], [1.0, 2.0])
    c = _parquet(["2026-01-01T00:00:00+00:00", "2026-01-01T00:00:01+00:00"], [1.0, float(np.nextafter(2.0, 3.0))])
    assert a != b and parquet_canonical(a, ["utc"]) == parquet_canonical(b, ["utc"])
    assert parquet_canonical(a, ["utc"]) != parquet_canonical(c, ["utc"])
    assert parquet_canonical(a, []) != parquet_canonical(b, [])


def _npz(when: tuple[int, int, int, int, int, int], payload: bytes) -> bytes:
    sink = io.BytesIO()
    with zipfile.ZipFile(sink, "w") as z:
        z.writestr(zipfile.ZipInfo("gain.npy", date_time=when), payload)
    return sink.getvalue()


def test_a_zip_archive_loses_only_its_members_time_stamps():
    a, b = _npz((2026, 1, 1, 0, 0, 0), b"abc"), _npz((2027, 6, 1, 12, 0, 0), b"abc")
    assert a != b and zip_canonical(a) == zip_canonical(b) != zip_canonical(_npz((2026, 1, 1, 0, 0, 0), b"abd"))


def test_the_streams_lose_paths_time_stamps_progress_bars_and_fit_times_only():
    paths = Paths("/tmp/gonio-example-outputs-abc/work", {"tmpq1w2e3r4": "tmpXXXXXXXX"})
    out = b"run in /tmp/gonio-example-outputs-abc/work/tmp/tmpq1w2e3r4/run of 2026-12-03T22:28:04+00:00: 1.5 s\n"
    assert normalise_stdout(out, paths) == b"run in <work>/tmp/tmpXXXXXXXX/run of <utc>: 1.5 s\n"
    err = (b"fitting:  25%|##  | 1/4 [00:00<00:00]\rfitting lambert (3 parameters): chi2/dof = 90.4 (0.34 s)\n"
           b"photon transfer: exposure 1 of 32 (0.002524 s)\ndashboard: http://127.0.0.1:8787/status\n")  # fmt: skip
    assert normalise_stderr(err, paths) == (b"fitting lambert (3 parameters): chi2/dof = 90.4\n"
                                            b"photon transfer: exposure 1 of 32 (0.002524 s)\n"
                                            b"dashboard: http://127.0.0.1:<port>/status")  # fmt: skip
