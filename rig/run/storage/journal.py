"""What the runner's journal records must hold, checked before a resume or a table trusts them.

The run store keeps any record with a "kind"; the runner and the table read "point" and "reference" records
by key. A journal edited by hand or damaged (a record without its index, a point appended twice) must end in
an error that names the line, not in a KeyError or in a table with a row too many. Line numbers are 1-based
lines of journal.jsonl (every line is one record: the store refuses anything else).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from rig.run.storage.store import RunStoreError


class JournalError(RunStoreError):
    """A journal record lacks a key the runner needs, has the wrong type, or repeats a point or reference."""


def _number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _numbers(value: Any, length: int | None = None) -> bool:
    return isinstance(value, list) and bool(value) and all(_number(v) for v in value) and (
        length is None or len(value) == length
    )


def _count(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


_LEVEL = {"peak": _number, "mean": _number, "dark": _number, "n_pixels": _count}

_READING = {
    "reading": lambda v: _numbers(v),
    "reading_std_error": lambda v: _numbers(v),
    "exposures_s": lambda v: _numbers(v),
    "lower_bound": lambda v: isinstance(v, bool),
    "level": lambda v: isinstance(v, dict) and all(k in v and ok(v[k]) for k, ok in _LEVEL.items()),
}

_POINT = {
    "index": _count,
    "position": _count,
    "target_deg": lambda v: _numbers(v, 4),
    "theta_i_deg": _number,
    "phi_i_deg": _number,
    "theta_o_deg": _number,
    "phi_o_deg": _number,
    "joints_deg": lambda v: isinstance(v, dict) and all(_number(x) for x in v.values()),
    **_READING,
}

_REFERENCE = {"slot": _count, "theta_i_deg": _number, "theta_o_deg": _number, **_READING}

_EXPECTED = {
    "index": "a whole number >= 0 (the sweep row)",
    "position": "a whole number >= 0 (the place in the plan)",
    "slot": "a whole number >= 0 (the plan position of the reading)",
    "target_deg": "a list of 4 numbers (degrees)",
    "joints_deg": "an object of joint angles in degrees",
    "lower_bound": "true or false",
    "level": "an object with peak, mean, dark and n_pixels",
}


def check_records(records: Sequence[Mapping[str, Any]], journal: str | Path) -> None:
    """Raise JournalError naming the journal line of the first point or reference record the runner cannot use."""
    seen: dict[tuple[str, int], int] = {}
    for line, rec in enumerate(records, 1):
        kind = rec.get("kind")
        keys = _POINT if kind == "point" else _REFERENCE if kind == "reference" else None
        if keys is None:
            continue
        for key, ok in keys.items():
            if key not in rec:
                raise JournalError(f"{journal}: line {line}: a {kind!r} record without {key!r}; "
                                   "the journal was edited or damaged (restore it, or remove the line)")  # fmt: skip
            if not ok(rec[key]):
                expected = _EXPECTED.get(key, "a number" if keys[key] is _number else "a list of numbers")
                raise JournalError(f"{journal}: line {line}: {kind} {key} = {rec[key]!r}: expected {expected}")
        ident = (str(kind), int(rec["index" if kind == "point" else "slot"]))
        if ident in seen:
            what = f"point {ident[1]}" if kind == "point" else f"reference slot {ident[1]}"
            raise JournalError(f"{journal}: line {line}: {what} is already recorded on line {seen[ident]}; "
                               "a journal holds each once (remove the duplicate line)")  # fmt: skip
        seen[ident] = line
