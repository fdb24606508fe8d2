"""``jsonable`` (model.plain's walk) returns and refuses what its naming walk did before, to the type and message."""

import enum
import json
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import pytest

from model.plain import jsonable
from rig.run.storage.formats import NotExactJson, exact_json


class Colour(enum.IntEnum):
    RED = 1


class Fancy(float):
    pass


class Name(str):
    pass


def typed(value: Any) -> Any:
    """The value with every leaf's type spelled out, so that 1 == 1.0 == True cannot hide a difference."""
    if isinstance(value, dict):
        return {k: typed(v) for k, v in value.items()}
    if isinstance(value, list):
        return [typed(v) for v in value]
    return (type(value).__name__, repr(value))


def reference_jsonable(value: Any, where: str) -> Any:
    """``jsonable`` before its walk was shared: a walk that built the key path of every value."""
    if isinstance(value, np.ndarray | np.generic):
        value = value.tolist()
    if value is None or isinstance(value, bool | int | str):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"{where} = {value!r}: non-finite numbers are refused (use None for a missing value)")
        return value
    if isinstance(value, Mapping):
        bad = [k for k in value if not isinstance(k, str)]
        if bad:
            raise ValueError(f"{where} has key {bad[0]!r}: expected str keys")
        return {k: reference_jsonable(v, f"{where}[{k!r}]") for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [reference_jsonable(v, f"{where}[{i}]") for i, v in enumerate(value)]
    raise ValueError(f"{where} = {value!r} ({type(value).__name__}): not representable in JSON")


def test_the_walk_equals_the_naming_walk() -> None:
    record = {
        "kind": "point", "index": 3, "flag": True, "none": None, "x": -0.0, "big": 1e300,
        "np": np.float64(0.1), "np32": np.float32(0.1), "i64": np.int64(7), "arr": np.arange(6.0).reshape(2, 3),
        "tuple": (1.0, (2, "a")), "nested": {"a": [np.bool_(True), Colour.RED, Fancy(2.5)], "b": {"c": []}},
        Name("sub"): {Name("k"): Name("v")},
    }  # fmt: skip
    fast, named = jsonable(record, "record"), reference_jsonable(record, "record")
    assert typed(fast) == typed(named)
    assert json.dumps(fast, allow_nan=False) == json.dumps(named, allow_nan=False)


@pytest.mark.parametrize("bad", [math.nan, math.inf, np.float64(-math.inf), {1: 2.0}, {"a": [1.0, math.nan]}, object()])
def test_refusals_still_name_the_value(bad: Any) -> None:
    with pytest.raises(ValueError, match=r"record\[.x.\]"):
        jsonable({"x": bad}, "record")


@pytest.mark.parametrize("bad", [
    math.nan, [1.0, [2.0, -math.inf]], (0, {"a": {"b": [object()]}}), np.array([[1.0, 2.0], [3.0, math.nan]]),
    {"a": 1.0, 2: 3.0}, {"a": math.nan, 2: 3.0}, {"a": {"b": math.nan, 5: 1}}, {"l": [math.nan], "d": {1: 2}},
    {"m": np.array([1j])}, [{"ok": 1}, {"k": (1, 2, {None: 1})}], {"deep": [[[], [np.float32(math.inf)]]]},
    [Fancy(math.nan)], {"x": [1, 2, {"y": frozenset()}]}, {"z": {"q": np.float64(math.nan)}, 3.5: 0},
])  # fmt: skip
def test_a_refusal_names_what_the_naming_walk_named(bad: Any) -> None:
    with pytest.raises(ValueError) as expected:
        reference_jsonable({"top": bad}, "record")
    with pytest.raises(ValueError) as got:
        jsonable({"top": bad}, "record")
    assert str(got.value) == str(expected.value)


def test_records_to_read_are_the_records(tmp_path: Any) -> None:
    from rig.run.storage.store import RunStore

    store = RunStore.create(tmp_path / "run", {"what": "test"})
    store.append({"kind": "point", "index": 1, "values": [1.0, np.float64(2.5)]})
    store.append({"kind": "event", "message": "x"})
    assert list(store.records_to_read()) == store.records()
    assert RunStore.read(tmp_path / "run").records_to_read() == tuple(store.records())
    store.close()


def reference_csv_text(rows: list[dict[str, Any]], columns: list[str] | None = None) -> str:
    """``csv_text`` before its fast paths (key order and cells as then)."""
    import csv
    import io

    from rig.run.storage.formats import _cell

    cols = list(dict.fromkeys(k for row in rows for k in row) if columns is None else columns)
    buf = io.StringIO()
    out = csv.writer(buf, lineterminator="\n")
    out.writerow(cols)
    for i, row in enumerate(rows):
        out.writerow([_cell(i, c, row.get(c)) for c in cols])
    return buf.getvalue()


def test_csv_text_equals_the_reference() -> None:
    from rig.run.storage.formats import csv_text

    rng = np.random.default_rng(6)
    pool: list[Any] = [0.1, -0.0, 1e300, 5e-324, 3, True, False, None, "a,b", np.float64(2.5), np.float32(0.1),
                       np.int64(-4), np.bool_(True), Fancy(1.5), Colour.RED, float(rng.normal())]  # fmt: skip
    for _ in range(200):
        keys = [f"k{j}" for j in rng.permutation(8)[: int(rng.integers(1, 8))]]
        rows = [{k: pool[int(rng.integers(len(pool)))] for k in keys if rng.random() < 0.8} for _ in range(5)]
        assert csv_text(rows) == reference_csv_text(rows)
        assert csv_text(rows, ["k3", "k1", "k0"] + [k for k in keys if k not in ("k3", "k1", "k0")]) == (
            reference_csv_text(rows, ["k3", "k1", "k0"] + [k for k in keys if k not in ("k3", "k1", "k0")])
        )
    with pytest.raises(ValueError, match="not among the columns"):
        csv_text([{"a": 1.0, "b": 2.0}], ["a"])
    with pytest.raises(ValueError, match="expected a finite number"):
        csv_text([{"a": math.nan}])


def random_record(rng: np.random.Generator, depth: int = 0) -> Any:
    """A random nest of exact plain values: floats of every magnitude and sign, ints, strs, bools, None."""
    roll = rng.integers(0, 9 if depth < 3 else 6)
    if roll == 0:
        return float(rng.choice([0.0, -0.0, 5e-324, -5e-324, -1.7976931348623157e308, 1.0 / 3.0, 2.0**53 + 2.0]))
    if roll == 1:
        return float(rng.normal() * 10.0 ** rng.integers(-300, 300))
    if roll == 2:
        return int(rng.integers(-(2**62), 2**62)) * int(rng.integers(1, 2**40))
    if roll == 3:
        return str(rng.choice(["", "a", "é\u2603", "\ud800", 'q"\\\n\t', "kind"]))
    if roll == 4:
        return bool(rng.integers(0, 2))
    if roll == 5:
        return None
    if roll == 6:
        return [random_record(rng, depth + 1) for _ in range(rng.integers(0, 4))]
    if roll == 7:
        return tuple(random_record(rng, depth + 1) for _ in range(rng.integers(0, 4)))
    return {f"k{i}": random_record(rng, depth + 1) for i in range(rng.integers(0, 4))}


def read_back(value: Any) -> Any:
    """What the journal kept before: the line written, parsed again."""
    return json.loads(json.dumps(jsonable(value, "record"), allow_nan=False, ensure_ascii=True, separators=(",", ":")))


def test_exact_json_is_what_the_line_reads_back() -> None:
    from rig.run.storage.store import _encode_line

    rng = np.random.default_rng(21)
    for _ in range(2000):
        record = {"kind": "point", "value": random_record(rng)}
        kept = exact_json(record)
        assert typed(kept) == typed(read_back(record))
        assert repr(kept) == repr(read_back(record))  # -0.0 and 0.0 spelled apart
        line = json.dumps(jsonable(record, "record"), allow_nan=False, ensure_ascii=True, separators=(",", ":"))
        assert _encode_line(kept) == _encode_line(record) == line


def test_exact_json_copies() -> None:
    inner = [1.0, {"a": 2}]
    record = {"kind": "point", "x": inner, "y": inner}
    kept = exact_json(record)
    assert kept == record and kept["x"] is not inner and kept["x"][1] is not inner[1] and kept["x"] is not kept["y"]


@pytest.mark.parametrize("value", [np.float64(0.1), np.int64(3), np.bool_(True), np.arange(2.0), Colour.RED,
                                   Fancy(2.5), math.nan, -math.inf, {1: 2.0}, {Name("a"): 1}, Name("b"), object(),
                                   frozenset()])  # fmt: skip
def test_exact_json_refuses_what_reads_back_as_another_type(value: Any) -> None:
    with pytest.raises(NotExactJson):
        exact_json({"kind": "point", "nested": [{"x": value}]})


def test_the_journal_keeps_what_it_reads_back(tmp_path: Any) -> None:
    from rig.run.storage.store import RunStore

    rng = np.random.default_rng(5)
    store = RunStore.create(tmp_path / "run", {"what": "test"})
    records = [{"kind": "point", "value": random_record(rng)} for _ in range(50)]
    records += [{"kind": "event", "np": np.float64(0.5), "enum": Colour.RED, "fancy": Fancy(1.5), Name("k"): 1}]
    for record in records:
        store.append(record)
    kept = store.records_to_read()
    again = RunStore.read(tmp_path / "run").records_to_read()
    assert [typed(r) for r in kept] == [typed(r) for r in again] == [typed(read_back(r)) for r in records]
    store.close()
