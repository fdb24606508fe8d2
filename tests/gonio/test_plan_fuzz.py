"""Issue 31: the shipped rig and sweep files, mutated at random, through ``gonio plan`` in-process.

Keys are removed or their values replaced with odd values of every TOML type (huge and tiny floats, nan, inf,
negatives, big integers, strings, arrays, nested tables); the file is written as TOML and planned as a user
would. Whatever the input, the exit code is 0 (planned), 2 (bad input, named) or 74 (a path the system
refuses): never 70, an internal error.
"""

from __future__ import annotations

import math
import os
import tomllib
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gonio import cli
from tests.rig.run.config.test_config_fuzz import key_paths

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
RIGS = sorted(p.name for p in EXAMPLES.glob("rig_*.toml"))
SWEEPS = sorted(p.name for p in EXAMPLES.glob("sweep_*.toml"))

# -- a small TOML writer (the project has no TOML writer dependency, and tomllib only reads) --------------------


def _key(k: str) -> str:
    return k if k and all(c.isalnum() or c in "_-" for c in k) else _string(k)


def _string(s: str) -> str:
    out = s.replace("\\", "\\\\").replace('"', '\\"')
    out = "".join(c if c.isprintable() else f"\\u{ord(c):04x}" for c in out)
    return f'"{out}"'


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return _string(v)
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"no TOML for {v!r}")


def dumps(doc: dict[str, Any], prefix: str = "") -> str:
    """TOML text for a document of plain values and tables."""
    plain = [f"{_key(k)} = {_value(v)}" for k, v in doc.items() if not isinstance(v, dict)]
    text = (f"[{prefix}]\n" if prefix else "") + "".join(line + "\n" for line in plain)
    for k, v in doc.items():
        if isinstance(v, dict):
            text += "\n" + dumps(v, f"{prefix}.{_key(k)}" if prefix else _key(k))
    return text


# -- mutations --------------------------------------------------------------------------------------------------

ODD_FLOATS = [1e308, -1e308, 1e-308, 5e-324, -5e-324, 1e30, -1e30, 1e-300, 0.0, -0.0, math.nan, math.inf,
              -math.inf, -1.0, 0.5, 89.999, 90.0, 180.0, 360.0, 1e6]  # fmt: skip
ODD_INTS = [0, -1, 1, 2**31, 2**32, 2**63 - 1, -(2**63), 10**30, 2**64 + 1, 253, 4096]
ODD_STRINGS = ["", "x", "simulated", "dynamixel", "grbl", "Lambert", "CookTorrance", "/dev/null", "/proc/x",
               "calib/absent.json", "four_axis", "in_plane", "fixed_camera", "grid", "\u00e9"]  # fmt: skip
scalars = st.one_of(
    st.sampled_from(ODD_FLOATS),
    st.sampled_from(ODD_INTS),
    st.floats(allow_nan=True, allow_infinity=True),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.booleans(),
    st.sampled_from(ODD_STRINGS),
    st.text(max_size=8),
)
#: Long angle lists (issue 31: two of them made a grid of billions of points, a MemoryError at load).
long_lists = st.sampled_from([1100, 2000]).map(lambda n: [80.0 * k / n for k in range(n)])


def _containers(inner: st.SearchStrategy[Any]) -> st.SearchStrategy[Any]:
    return st.one_of(st.lists(inner, max_size=5), st.dictionaries(st.sampled_from(["a", "id", "x"]), inner, max_size=3))


values = st.one_of(st.recursive(scalars, _containers, max_leaves=12), long_lists)


def _mutate(doc: dict[str, Any], data: st.DataObject) -> dict[str, Any]:
    for _ in range(data.draw(st.integers(1, 3), label="changes")):
        paths = key_paths(doc)
        if not paths:
            break
        path = data.draw(st.sampled_from(paths), label="path")
        parent: Any = doc
        for part in path[:-1]:
            parent = parent[part]
        action = data.draw(st.sampled_from(["remove", "replace", "replace", "add"]), label="action")
        if action == "remove" and isinstance(parent, dict):
            del parent[path[-1]]
        elif action == "add" and isinstance(parent.get(path[-1]) if isinstance(parent, dict) else None, dict):
            parent[path[-1]][data.draw(st.sampled_from(["bogus", "seed", "alpha", "rho", "every"]))] = data.draw(values)
        else:
            parent[path[-1]] = data.draw(values, label="value")
    return doc


def _code(argv: list[str]) -> int:
    try:
        return cli.main(argv)
    except SystemExit as exc:  # argparse's own refusals
        return int(exc.code or 0)


# GONIO_FUZZ_EXAMPLES=3000 runs a longer search (about two minutes).
SLOW_OK = [HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.function_scoped_fixture]


@settings(max_examples=int(os.environ.get("GONIO_FUZZ_EXAMPLES", "120")), deadline=None, suppress_health_check=SLOW_OK)
@given(st.sampled_from(RIGS), st.sampled_from(SWEEPS), st.sampled_from(["rig", "sweep", "both"]), st.data())
def test_mutated_example_files_plan_or_are_refused_never_a_bug(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], rig_name: str, sweep_name: str, which: str, data: st.DataObject
) -> None:
    rig_doc = tomllib.loads((EXAMPLES / rig_name).read_text())
    sweep_doc = tomllib.loads((EXAMPLES / sweep_name).read_text())
    if which in ("rig", "both"):
        rig_doc = _mutate(rig_doc, data)
    if which in ("sweep", "both"):
        sweep_doc = _mutate(sweep_doc, data)
    rig, sweep = tmp_path / "rig.toml", tmp_path / "sweep.toml"
    rig.write_text(dumps(rig_doc), encoding="utf-8")
    sweep.write_text(dumps(sweep_doc), encoding="utf-8")
    code = _code(["plan", str(sweep), "--rig", str(rig), "--quiet"])
    err = capsys.readouterr().err
    assert code != 70, err
    assert code in (0, 2, 74), (code, err)
    if code == 2:
        assert "gonio: error: " in err or "error: argument" in err, err


def test_the_toml_writer_round_trips_the_examples() -> None:
    for name in (*RIGS, *SWEEPS):
        doc = tomllib.loads((EXAMPLES / name).read_text())
        assert tomllib.loads(dumps(doc)) == doc
