"""The README's Python examples run as shipped (a block after ``<!-- not run: REASON -->`` is shown, not run)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parent.parent / "README.md"
FENCED = re.findall(r"(<!-- not run: [^>]+ -->\n)?```python\n(.*?)```", README.read_text(), re.S)
BLOCKS = [code for marker, code in FENCED if not marker]


def test_readme_has_examples() -> None:
    assert len(BLOCKS) >= 3
    assert all("dask_jobqueue" not in code for code in BLOCKS)  # the SLURM sketch needs a cluster: not run


@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_readme_example_runs(index: int, capsys: pytest.CaptureFixture[str]) -> None:
    exec(compile(BLOCKS[index], f"README.md example {index + 1}", "exec"), {"__name__": "readme"})
    assert capsys.readouterr().out.strip(), "every example prints its result"
