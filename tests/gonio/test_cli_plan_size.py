"""Issue 31: a sweep's size is bounded before its points exist, and a large plan shows its progress."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from gonio import cli
from rig.run.config.schema import MAX_SWEEP_POINTS


def _grid(tmp_path: Path, n_i: int, n_o: int, **extra: object) -> Path:
    ti = [round(60.0 * k / n_i, 6) for k in range(n_i)]
    to = [round(80.0 * k / n_o, 6) for k in range(n_o)]
    lines = ["[sweep]", 'kind = "grid"', f"theta_i_deg = {json.dumps(ti)}", f"theta_o_deg = {json.dumps(to)}"]
    lines += [f"{k} = {json.dumps(v)}" for k, v in extra.items()]
    path = tmp_path / "sweep.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.parametrize(("n_i", "n_o", "phi"), [(2000, 2000, None), (100, 100, list(range(101)))])
def test_a_sweep_of_more_points_than_the_limit_is_refused_naming_its_lists(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], n_i: int, n_o: int, phi: list[int] | None
) -> None:
    extra = {"phi_o_deg": phi} if phi else {}
    sweep = _grid(tmp_path, n_i, n_o, **extra)
    assert cli.main(["plan", str(sweep)]) == 2
    err = capsys.readouterr().err
    total = n_i * n_o * (len(phi) if phi else 1)
    lengths = f"theta_i_deg ({n_i}) x theta_o_deg ({n_o})" + (f" x phi_o_deg ({len(phi)})" if phi else "")
    assert f"{sweep}: [sweep] {lengths} = {total} points: expected at most {MAX_SWEEP_POINTS} points" in err


def test_a_large_plan_shows_its_stages_on_stderr_unless_quiet(tmp_path: Path, capsys: pytest.CaptureFixture[str]):
    sweep = _grid(tmp_path, 120, 100, order=False)  # 12000 points, in the file's order: a quick plan
    assert cli.main(["plan", str(sweep)]) == 0
    out, err = capsys.readouterr()
    assert "planning 12000 points" in err and "time estimate" in err
    assert "planning" not in out
    assert cli.main(["plan", str(sweep), "--quiet"]) == 0
    assert "planning" not in capsys.readouterr().err


def test_a_small_plan_shows_no_bar(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["plan", str(_grid(tmp_path, 3, 5))]) == 0
    assert "planning" not in capsys.readouterr().err
