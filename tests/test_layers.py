"""The layering of docs/architecture.md holds, and the check behind it catches what it is meant to catch.

The contracts live in pyproject.toml ([tool.importlinter]); ``make lint`` runs them too. The synthetic
trees below carry the project's package names with one bad import each, checked against those same
contracts, so a contract that stops catching an upward arrow or a circle fails here.
"""

from __future__ import annotations

import subprocess
import sys
import textwrap
import tomllib
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
CHECK = ("import sys; sys.path.insert(0, '.'); from importlinter.cli import lint_imports; "
         "sys.exit(lint_imports(no_cache=True))")
# Generous: a loaded CI machine must not turn slowness into a failure.
TIMEOUT_S = 600


def _lint(cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", CHECK], cwd=cwd, capture_output=True, text=True, timeout=TIMEOUT_S)


def test_the_project_keeps_its_layers_and_has_no_circles() -> None:
    result = _lint(REPO)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


RUN_PARTS = ("adaptive", "session", "calibrate", "measuring", "backends", "planning", "storage", "tables", "config",
             "registry")  # fmt: skip
SKELETON = ("gonio", "analysis", "analysis/report", "analysis/exports", "simulator", "simulator/sub", "rig",
            "rig/alignment", "rig/run", *(f"rig/run/{part}" for part in RUN_PARTS), "rig/instrument", "acquisition",
            "model")  # fmt: skip


def _tree(tmp: Path, files: dict[str, str]) -> Path:
    config = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"]
    lines = ["[tool.importlinter]", f"root_packages = {config['root_packages']!r}".replace("'", '"')]
    for contract in config["contracts"]:
        lines.append("[[tool.importlinter.contracts]]")
        lines += [f"{k} = {v!r}".replace("'", '"') for k, v in contract.items()]
    (tmp / "pyproject.toml").write_text("\n".join(lines) + "\n")
    for pkg in SKELETON:
        (tmp / pkg).mkdir(parents=True, exist_ok=True)
        (tmp / pkg / "__init__.py").write_text("")
        (tmp / pkg / "m.py").write_text("X = 1\n")
    for name, text in files.items():
        (tmp / name).write_text(textwrap.dedent(text))
    return tmp


def test_a_clean_tree_passes(tmp_path: Path) -> None:
    tree = _tree(tmp_path, {"gonio/m.py": "import analysis.m\nimport simulator.m\nimport rig.run.m\n",
                            "rig/run/m.py": "import rig.instrument.m\nimport acquisition.m\n",
                            "acquisition/m.py": "import model.m\n"})  # fmt: skip
    result = _lint(tree)
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.parametrize(
    "files,what",
    [
        ({"rig/run/m.py": "import simulator.m\n"}, "rig is not allowed to import simulator"),
        ({"model/m.py": "def f():\n    import acquisition.m\n"}, "model is not allowed to import acquisition"),
        ({"analysis/m.py": "import simulator.m\n"}, "analysis is not allowed to import simulator"),
        ({"simulator/m.py": "import gonio.m\n"}, "simulator is not allowed to import gonio"),
        ({"rig/instrument/m.py": "import rig.run.m\n"}, "rig.instrument is not allowed to import rig.run"),
        ({"rig/run/m.py": "import rig.alignment.m\n"}, "rig.run is not allowed to import rig.alignment"),
        ({"rig/run/config/m.py": "import rig.run.session.m\n"},
         "rig.run.config is not allowed to import rig.run.session"),
        ({"rig/run/storage/m.py": "import rig.run.tables.m\n"},
         "rig.run.storage is not allowed to import rig.run.tables"),
        ({"analysis/report/m.py": "import analysis.exports.m\n"},
         "analysis.report is not allowed to import analysis.exports"),
        ({"model/a.py": "import model.b\n", "model/b.py": "import model.a\n"}, "No cycles are allowed in model"),
        ({"simulator/sub/a.py": "from simulator.sub import b\n", "simulator/sub/b.py": "import simulator.sub.a\n"},
         "No cycles are allowed in simulator.sub"),
    ],
)  # fmt: skip
def test_an_upward_import_or_a_circle_is_caught(tmp_path: Path, files: dict[str, str], what: str) -> None:
    result = _lint(_tree(tmp_path, files))
    assert result.returncode != 0
    assert what in result.stdout, result.stdout + result.stderr
