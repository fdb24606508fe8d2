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
