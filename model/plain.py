"""One walk over JSON-like values (dicts, lists, tuples and scalars); what happens at a leaf is its caller's rule.

Every copy of a nest of values into plain JSON is this walk with a rule at the leaves: the run store's journal keeps
only exact JSON types (its rule refuses the rest), the run's files take numpy values and refuse NaN naming the key
(:func:`jsonable`, also the exports'), the analysis writes NaN as null. The walk keeps exact plain values (str, int,
bool, None and finite floats) and copies dicts and lists (tuples become lists) itself, so that the common case calls
no rule; anything else, and any key that is not an exact str, goes to the rule.

A rule refuses with :class:`Refused`; the walk adds the key or index of every level to it on the way out (nothing is
built on the way in: a journal record has hundreds of values), so that the message names the value refused.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from model.errors import GonioError

#: A rule: a leaf (or a key) in, what the copy holds in its place out; raises to refuse it.
Rule = Callable[[Any], Any]


class Refused(GonioError, ValueError):
    """A rule refused a value; ``path`` gathers where it sits (innermost first) as the walk unwinds."""

    def __init__(self, what: str) -> None:
        super().__init__(what)
        self.what = what
        self.path: list[str] = []

    def named(self, where: str) -> str:
        """The refusal as a message: ``where`` (the top value's name), the keys and indices down to it, and why."""
        return where + "".join(reversed(self.path)) + self.what


def json_walk(leaf: Rule, key: Rule) -> Callable[[Any], Any]:
    """The walk with these rules: a copy of a value, plain values kept, dicts and lists copied, the rest to the rules.

    Plain values are exact str, int, bool, None and finite floats; a tuple becomes a list. Any other value x
    becomes ``leaf(x)``, a dict's key k that is not an exact str ``key(k)``. A :class:`Refused` raised below
    leaves with the key or index it came from. (Made once a rule: the rules sit in the walk's closure, not in
    every call's arguments, which is what keeps the journal's walk as quick as a walk of its own.)
    """

    def walk(value: Any) -> Any:
        kind = type(value)
        if kind is float:
            return value if math.isfinite(value) else leaf(value)
        if kind is str or kind is int or kind is bool or value is None:
            return value
        if kind is list or kind is tuple:
            try:
                return [walk(v) for v in value]
            except Refused as exc:
                exc.path.append(f"[{_first_refused(walk, value)}]")
                raise
        if kind is dict:
            out = {}
            try:
                for k, v in value.items():
                    out[k if type(k) is str else key(k)] = walk(v)
            except Refused as exc:
                for bad in value:  # a refused key of this dict is named before anything inside it
                    if type(bad) is not str:
                        key(bad)
                exc.path.append(f"[{k!r}]")
                raise
            return out
        return leaf(value)

    return walk


def _first_refused(walk: Callable[[Any], Any], items: list[Any] | tuple[Any, ...]) -> int:
    """The index of the first of ``items`` that ``walk`` refuses (called once one was)."""
    for i, v in enumerate(items):
        try:
            walk(v)
        except Refused:
            return i
    raise AssertionError("a rule refused a value once and accepted it again")


def keep(value: Any) -> Any:
    """The rule that keeps whatever the walk hands it as it is."""
    return value


#: A copy of a nest: dicts and lists copied, tuples as lists, anything else kept (a deep copy of plain JSON values).
json_copy = json_walk(keep, keep)


def _str_key(k: Any) -> Any:
    if isinstance(k, str):
        return k
    raise Refused(f" has key {k!r}: expected str keys")


def _json_leaf(value: Any) -> Any:
    if isinstance(value, np.ndarray | np.generic):
        return _walk_jsonable(value.tolist())
    if value is None or isinstance(value, bool | int | str):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise Refused(f" = {value!r}: non-finite numbers are refused (use None for a missing value)")
        return value
    if isinstance(value, Mapping):
        return _walk_jsonable(dict(value))
    if isinstance(value, list | tuple):
        return _walk_jsonable(list(value))
    raise Refused(f" = {value!r} ({type(value).__name__}): not representable in JSON")


_walk_jsonable = json_walk(_json_leaf, _str_key)


def jsonable(value: Any, where: str) -> Any:
    """``value`` as plain JSON types (numpy scalars and arrays become numbers and lists); errors name the key.

    ValueError names the first value refused (a non-finite number, a key that is not a str, an object JSON cannot
    hold) by its path from ``where``, e.g. ``record['readings'][2] = nan: ...``.
    """
    try:
        return _walk_jsonable(value)
    except Refused as exc:
        raise ValueError(exc.named(where)) from None
