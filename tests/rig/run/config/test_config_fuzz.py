"""Fuzzed rig and sweep files: every one either loads and plans, or fails with a ConfigError naming the file.

Each case takes an example file and changes one to three keys (another type, a bad number, a missing or an
unknown key, a nested table), seeded, so a failure names the seed that reproduces it. The suite runs 300
cases (4 blocks of 75); ``GONIO_FUZZ_BLOCKS=32 pytest tests/rig/run/config/test_config_fuzz.py`` runs 2,400.
"""

from __future__ import annotations

import math
import os
import random
import tomllib
from pathlib import Path
from typing import Any

import pytest

from rig.run.config.files import ConfigError, parse, rig_config, sweep_config
from rig.run.config.schema import RigFile, SweepFile

EXAMPLES = Path(__file__).resolve().parents[4] / "examples"
RIGS = ["rig_simulated.toml", "rig_dynamixel.toml"]
SWEEPS = ["sweep_grid.toml", "sweep_in_plane.toml", "sweep_rusinkiewicz.toml"]

VALUES: list[Any] = [
    "x", "", -1, 0, 1, 2.5, -0.0, 1e308, -1e308, math.inf, -math.inf, math.nan, True, False, [], [0], [1.0, "a"],
    [[1.0, 2.0]], {}, {"a": 1}, [90.0, 95.0], [-10.0], 10**30, "simulated", "grbl", "dynamixel", [0.0] * 5,
    1e-9, 89.99, 179.0, 4096, 65535.0, 0.5, [0.0, 0.0, 0.0], [1.0, 2.0, 3.0, 4.0], "Lambert", "CookTorrance",
]  # fmt: skip


def key_paths(doc: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every key path of a TOML document (list items: the first three), depth first."""
    out = [prefix] if prefix else []
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += key_paths(v, (*prefix, k))
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:3]):
            out += key_paths(v, (*prefix, i))
    return out


def mutate(doc: dict[str, Any], rng: random.Random) -> dict[str, Any]:
    """The document with 1-3 random changes."""
    import copy

    doc = copy.deepcopy(doc)
    for _ in range(rng.randint(1, 3)):
        paths = key_paths(doc)
        if not paths:
            break
        path = rng.choice(paths)
        parent: Any = doc
        for part in path[:-1]:
            parent = parent[part]
        action = rng.random()
        if action < 0.15 and isinstance(parent, dict):
            del parent[path[-1]]
        elif action < 0.25 and isinstance(parent, dict):
            parent[f"extra_{rng.randint(0, 9)}"] = rng.choice(VALUES)
        else:
            parent[path[-1]] = copy.deepcopy(rng.choice(VALUES))
    return doc


def check_case(seed: int) -> str:
    """Build, validate and plan one fuzzed pair; '' if it behaved, else what went wrong."""
    from rig.run.config.files import material_from
    from rig.run.session import capture_settings, make_plan, reference_settings

    rng = random.Random(seed)
    rig_doc = tomllib.loads((EXAMPLES / rng.choice(RIGS)).read_text())
    sweep_doc = tomllib.loads((EXAMPLES / rng.choice(SWEEPS)).read_text())
    if rng.random() < 0.5:
        rig_doc = mutate(rig_doc, rng)
    else:
        sweep_doc = mutate(sweep_doc, rng)
    try:
        rig = rig_config(parse(rig_doc, RigFile, "fuzz-rig.toml"), "fuzz-rig.toml")
        sweep = sweep_config(parse(sweep_doc, SweepFile, "fuzz-sweep.toml"), "fuzz-sweep.toml")
        reference_settings(rig)
        capture_settings(rig, sweep)
        if rig.file.link.kind == "simulated":
            material_from(rig)
        if len(sweep.directions_deg) <= 5000:
            make_plan(rig, sweep)
    except ConfigError as exc:
        text = str(exc)
        if "fuzz-rig.toml" not in text and "fuzz-sweep.toml" not in text:
            return f"seed {seed}: a ConfigError without the file: {text}"
        return ""
    except Exception as exc:  # anything else is a traceback a user would see
        return f"seed {seed}: {type(exc).__name__}: {exc}"
    return ""


@pytest.mark.parametrize("block", range(int(os.environ.get("GONIO_FUZZ_BLOCKS", "4"))))
def test_fuzzed_files_load_or_fail_with_a_clear_error(block: int) -> None:
    failures = [f for f in (check_case(seed) for seed in range(block * 75, (block + 1) * 75)) if f]
    assert not failures, "\n".join(failures[:10])


def test_a_toml_nested_a_thousand_levels_deep_is_a_config_error(tmp_path: Path) -> None:
    from rig.run.config.files import load_rig, load_sweep

    deep = tmp_path / "deep.toml"
    deep.write_text("a = " + "[" * 1000 + "]" * 1000 + "\n")
    for load in (load_rig, load_sweep):
        with pytest.raises(ConfigError, match=r"deep.toml: .*nested too deeply"):
            load(deep)


def test_an_unreachable_reference_pose_names_the_file_and_the_table() -> None:
    from rig.run.session import reference_settings

    doc = {"reference": {"theta_i_deg": 0.0, "theta_o_deg": 5.0}}  # 5 deg apart: closer than the arms can be
    rig = rig_config(parse(doc, RigFile, "lab-rig.toml"), "lab-rig.toml")
    with pytest.raises(ConfigError, match=r"lab-rig.toml: \[reference\] theta_i_deg = 0.0, theta_o_deg = 5.0: "):
        reference_settings(rig)


@pytest.mark.parametrize("seed", [750, 1870])
def test_a_reference_pose_outside_an_axis_limit_names_the_file(seed: int) -> None:
    # Found by the 2,400-case fuzz: a tilt axis whose limits leave out 0 deg ended in an AxisLimitError.
    assert check_case(seed) == ""
