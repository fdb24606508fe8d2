"""Bad input is refused before any run, sweep or report directory exists: a retry must not meet a dead one."""

from __future__ import annotations

from pathlib import Path

import pytest

from gonio import cli

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def _rig(tmp_path: Path, extra: str) -> Path:
    rig = tmp_path / "rig.toml"
    rig.write_text((EXAMPLES / "rig_simulated.toml").read_text().replace("[camera.noise]", extra + "\n[camera.noise]"))
    return rig


@pytest.mark.parametrize(
    ("extra", "message"),
    [('calibration = "calib/camera_calibration.json"', "both given"),
     ('calibration = "calib/absent.json"\nflat_field = "calib/absent.npz"', "camera.calibration")],
)  # fmt: skip
def test_a_run_with_a_bad_camera_input_creates_nothing_and_a_retry_says_the_same(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: str, message: str
) -> None:
    rig = _rig(tmp_path, extra)
    if "absent" in extra:  # without [camera.noise], so the missing file is what is wrong
        rig.write_text(rig.read_text().replace("[camera.noise]", "[metadata_unused]").replace(
            "[metadata_unused]\ne_per_dn = 4.0\nread_noise_e = 3.0\nfull_well_e = 60000.0\n", ""))  # fmt: skip
    out = tmp_path / "run"
    argv = ["run", str(EXAMPLES / "sweep_grid.toml"), "--rig", str(rig), "--out", str(out), "--quiet"]
    for _attempt in range(2):
        assert cli.main(argv) == 2
        err = capsys.readouterr().err
        assert message in err and "already holds a run" not in err
        assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rig.toml"]


def test_adaptive_with_a_zenith_beyond_90_names_the_option_and_creates_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "sweep"
    assert cli.main(["adaptive", "--max-theta", "120", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "--max-theta 120: expected a zenith in degrees, > 0 and at most 90" in err
    assert "error_pairs" not in err
    assert not out.exists()


@pytest.mark.parametrize(
    ("option", "value"),
    [("--budget", "0"), ("--initial", "500"), ("--batch", "0"), ("--snr", "-1"), ("--snr", "nan"),
     ("--reference-snr", "0"), ("--seed", "-1"), ("--max-theta", "0"), ("--tile-px", "0"), ("--tile-px", "600"),
     ("--scan-speed", "0"), ("--scan-speed", "nan"), ("--scan-speed", "45")],
)  # fmt: skip
def test_adaptive_blames_each_bad_option_by_name(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], option: str, value: str
) -> None:
    out = tmp_path / "sweep"
    assert cli.main(["adaptive", option, value, "--out", str(out), "--quiet"]) == 2
    assert f"gonio: error: {option} {value}: expected" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize(
    ("options", "message"),
    [(["--mode", "frame"], "argument --mode: invalid choice: 'frame'"),
     (["--motion", "scan"], "argument --motion: invalid choice: 'scan'"),
     (["--tile-px", "four", "--mode", "image"], "argument --tile-px: invalid int value: 'four'"),
     (["--tile-px", "4"], "--tile-px 4: has no meaning with --mode point"),
     (["--scan-speed", "3"], "--scan-speed 3: has no meaning with --motion stop")],
)  # fmt: skip
def test_adaptive_mode_options_that_do_not_go_together_are_refused_by_name(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], options: list[str], message: str
) -> None:
    out = tmp_path / "sweep"
    try:
        code: int | str | None = cli.main(["adaptive", *options, "--out", str(out), "--quiet"])
    except SystemExit as exc:  # argparse's own checks (a choice, a number) exit from parsing
        code = exc.code
    assert code == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_adaptive_mode_options_reach_the_sweep_s_settings(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    import rig.run.adaptive.sweep as adaptive

    seen: list[tuple[object, ...]] = []

    def stop(rig: object, out: object, spec: object, s: adaptive.AdaptiveSettings, **_: object) -> None:
        seen.append((s.mode, s.tile_px, s.motion, s.scan_speed_deg_s))
        raise KeyboardInterrupt  # the settings are all this test wants: nothing is measured (exit 130)

    monkeypatch.setattr(adaptive, "run_adaptive", stop)
    argv = ["adaptive", "--out", str(tmp_path / "a"), "--mode", "auto", "--tile-px", "4", "--motion", "continuous",
            "--scan-speed", "3.5", "--quiet"]  # fmt: skip
    assert cli.main(argv) == 130
    assert cli.main(["adaptive", "--out", str(tmp_path / "b"), "--quiet"]) == 130
    assert seen == [("auto", 4, "continuous", 3.5), ("point", None, "stop", None)]


def test_adaptive_with_a_bad_camera_input_creates_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rig = _rig(tmp_path, 'calibration = "calib/camera_calibration.json"')
    out = tmp_path / "sweep"
    assert cli.main(["adaptive", "--rig", str(rig), "--out", str(out), "--quiet"]) == 2
    assert "both given" in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("source", ["absent", "rig.toml"])
def test_analyze_of_a_bad_source_creates_no_report_directory(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], source: str
) -> None:
    (tmp_path / "rig.toml").write_text((EXAMPLES / "rig_simulated.toml").read_text())
    out = tmp_path / "report"
    assert cli.main(["analyze", str(tmp_path / source), "--out", str(out)]) == 2
    assert str(tmp_path / source) in capsys.readouterr().err
    assert not out.exists()
