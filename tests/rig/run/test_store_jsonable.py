"""``jsonable``'s fast walk (exact plain types first) returns what its naming walk returns, types included."""

import enum
import json
import math
from typing import Any

import numpy as np
import pytest

from rig.run.store_formats import _named, jsonable


class Colour(enum.IntEnum):
    RED = 1


class Fancy(float):
    pass


def typed(value: Any) -> Any:
    """The value with every leaf's type spelled out, so that 1 == 1.0 == True cannot hide a difference."""
    if isinstance(value, dict):
        return {k: typed(v) for k, v in value.items()}
    if isinstance(value, list):
        return [typed(v) for v in value]
    return (type(value).__name__, repr(value))


def test_the_fast_walk_equals_the_naming_walk() -> None:
    record = {
        "kind": "point", "index": 3, "flag": True, "none": None, "x": -0.0, "big": 1e300,
        "np": np.float64(0.1), "np32": np.float32(0.1), "i64": np.int64(7), "arr": np.arange(6.0).reshape(2, 3),
        "tuple": (1.0, (2, "a")), "nested": {"a": [np.bool_(True), Colour.RED, Fancy(2.5)], "b": {"c": []}},
    }  # fmt: skip
    fast, named = jsonable(record, "record"), _named(record, "record")
    assert typed(fast) == typed(named)
    assert json.dumps(fast, allow_nan=False) == json.dumps(named, allow_nan=False)


@pytest.mark.parametrize("bad", [math.nan, math.inf, np.float64(-math.inf), {1: 2.0}, {"a": [1.0, math.nan]}, object()])
def test_refusals_still_name_the_value(bad: Any) -> None:
    with pytest.raises(ValueError, match=r"record\[.x.\]"):
        jsonable({"x": bad}, "record")


def test_records_to_read_are_the_records(tmp_path: Any) -> None:
    from rig.run.store import RunStore

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

    from rig.run.store_formats import _cell

    cols = list(dict.fromkeys(k for row in rows for k in row) if columns is None else columns)
    buf = io.StringIO()
    out = csv.writer(buf, lineterminator="\n")
    out.writerow(cols)
    for i, row in enumerate(rows):
        out.writerow([_cell(i, c, row.get(c)) for c in cols])
    return buf.getvalue()


def test_csv_text_equals_the_reference() -> None:
    from rig.run.store_formats import csv_text

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
