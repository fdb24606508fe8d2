"""The command line's failures: whose they are (the exit code), what they name, and nothing worse than needed."""

from __future__ import annotations

import os
import subprocess
import sys
from importlib.metadata import version
from pathlib import Path

import pytest

from gonio import cli

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"


def test_version_is_the_installed_distribution(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"gonio {version('gonio')}"


def test_help_lists_every_exit_code(capsys):
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    for code in ("0 done", "1 declined", "2 bad input", "3 hardware fault", "4 camera fault", "70 internal error",
                 "74 operating-system error", "130 interrupted", "141 output pipe closed"):  # fmt: skip
        assert code in text


@pytest.mark.parametrize(
    ("argv", "hint"),
    [(["rnu"], "did you mean 'run'?"), (["servo", "pnig"], "did you mean 'ping'?"),
     (["sim", "servo"], "did you mean 'servos'?"), (["plan", "x.toml", "--lsit"], "(--lsit: did you mean '--list'?)"),
     (["analyze", "x", "--y-scale", "lgo"], "did you mean 'log'?")],
)  # fmt: skip
def test_a_misspelt_command_choice_or_option_gets_a_suggestion(argv, hint, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    assert hint in capsys.readouterr().err


def test_a_misspelt_key_or_value_in_a_rig_or_sweep_file_gets_a_suggestion(tmp_path, capsys):
    rig = tmp_path / "rig.toml"
    rig.write_text('[link]\nkind = "simulatd"\n[axes.tilt]\nid = 3\ngear_ration = 3.0\n')
    assert cli.main(["plan", str(EXAMPLES / "sweep_grid.toml"), "--rig", str(rig)]) == 2
    err = capsys.readouterr().err
    assert "link.kind = 'simulatd'" in err and "did you mean 'simulated'?" in err
    assert "axes.tilt.gear_ration = 3.0: unknown key" in err and "did you mean 'gear_ratio'?" in err
    rig.write_text("[axes.tlit]\nid = 3\n")
    assert cli.main(["plan", str(EXAMPLES / "sweep_grid.toml"), "--rig", str(rig)]) == 2
    assert "axes.tlit: no such joint" in (err := capsys.readouterr().err) and "did you mean 'tilt'?" in err
    sweep = tmp_path / "sweep.toml"
    sweep.write_text("[sweep]\nkind = 'grid'\ntheta_i_deg = [0.0]\ntheta_o_deg = [30.0]\n[captur]\ntarget_snr = 50\n")
    assert cli.main(["plan", str(sweep)]) == 2
    assert "captur = {'target_snr': 50}: unknown key" in (err := capsys.readouterr().err) and "'capture'?" in err


def test_an_operating_system_error_is_its_own_exit_code_with_the_path_and_reason(tmp_path, capsys):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    assert cli.main(["models", "--out", str(blocker / "models")]) == 74
    err = capsys.readouterr().err
    assert f"operating-system error: {blocker / 'models'}: Not a directory [ENOTDIR]" in err


@pytest.mark.parametrize("under", ["a-file", "a-file/deeper"])
def test_a_run_directory_the_system_refuses_is_an_operating_system_error(tmp_path, capsys, under):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    out = tmp_path / under / "run"
    assert cli.main(["run", str(EXAMPLES / "sweep_grid.toml"), "--out", str(out), "--quiet"]) == 74
    err = capsys.readouterr().err
    assert "operating-system error: " in err and "cannot create the run directory" in err
    assert "Not a directory [ENOTDIR]" in err and str(out.parent) in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file"]


def test_an_unexpected_exception_is_a_bug_not_bad_input(monkeypatch, capsys):
    def broken(*_args, **_kw):
        raise ValueError("an internal value went wrong")  # a ValueError that is nobody's input

    monkeypatch.setattr("gonio.models_demo.write_slices", broken)
    assert cli.main(["models"]) == 70
    err = capsys.readouterr().err
    assert "internal error (a bug in gonio, not in your input): ValueError: an internal value went wrong" in err
    assert "raised at tests/gonio/test_cli_errors.py:" in err and "in broken" in err and "gonio --debug" in err
    assert "Traceback" not in err
    assert cli.main(["--debug", "models"]) == 70
    assert "Traceback (most recent call last)" in capsys.readouterr().err


def test_ctrl_c_is_interrupted(monkeypatch, capsys):
    def interrupted(*_args, **_kw):
        raise KeyboardInterrupt

    monkeypatch.setattr("gonio.models_demo.write_slices", interrupted)
    assert cli.main(["models"]) == 130
    assert "interrupted" in capsys.readouterr().err


def test_a_run_into_an_existing_run_says_how_to_resume_it(tmp_path, capsys):
    run = tmp_path / "gold"
    run.mkdir()
    (run / "manifest.json").write_text("{}")
    assert cli.main(["run", str(EXAMPLES / "sweep_grid.toml"), "--out", str(run), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"to continue it: gonio resume {run}" in err and "RunStore.open" not in err


def test_resume_of_a_missing_directory_says_it_does_not_exist(tmp_path, capsys):
    assert cli.main(["resume", str(tmp_path / "nowhere"), "--quiet"]) == 2
    assert f"{tmp_path / 'nowhere'}: does not exist" in capsys.readouterr().err
    (tmp_path / "file").write_text("")
    assert cli.main(["resume", str(tmp_path / "file"), "--quiet"]) == 2
    assert "is a file, not a run directory" in capsys.readouterr().err
    assert cli.main(["resume", str(tmp_path), "--quiet"]) == 2
    assert "not a run directory (no manifest.json)" in capsys.readouterr().err


def _gonio(*args: str, stdout: int, timeout: float = 300.0) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "gonio.cli", *args], stdout=stdout, stderr=subprocess.PIPE,
                          text=True, cwd=ROOT, env=env, timeout=timeout, check=False)  # fmt: skip


def test_output_into_a_closed_pipe_ends_quietly():
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before gonio writes a byte, as `| head` is after its lines
    try:
        done = _gonio("plan", "examples/sweep_grid.toml", "--rig", "examples/rig_simulated.toml", "--list",
                      stdout=write_end)  # fmt: skip
    finally:
        os.close(write_end)
    assert done.returncode == 141
    assert done.stderr == ""  # no "Broken pipe", no traceback, no "Exception ignored"


def test_a_torn_journal_line_on_resume_is_one_plain_line_not_a_python_warning(tmp_path, capsys):
    from rig.run.storage.store import RunStore

    run = tmp_path / "run"
    with RunStore.create(run, {"points": 1}) as store:
        store.append({"kind": "point", "index": 0})
    with open(run / "journal.jsonl", "ab") as fh:
        fh.write(b'{"kind":"point","ind')  # what a SIGKILL in the middle of a write leaves
    cli.main(["resume", str(run), "--quiet"])  # the made-up manifest fails later; the warning comes first
    err = capsys.readouterr().err
    line = next(x for x in err.splitlines() if "half-written" in x)
    assert line == (f"gonio: warning: {run / 'journal.jsonl'}: line 2 was half-written (20 bytes, not a whole record) "
                    "and was dropped: the process before died in the middle of writing it; that point is measured "
                    "again")  # fmt: skip
    assert "RunStoreWarning" not in err and "warnings.warn" not in err and ".py:" not in err
