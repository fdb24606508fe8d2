import csv
import re

import numpy as np
import pytest

import model as m
from gonio import cli
from gonio.models_demo import in_plane_slice


def test_models_writes_figure_and_table(tmp_path, capsys):
    assert cli.main(["models", "--out", str(tmp_path)]) == 0
    png = tmp_path / "brdf_slices.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with open(tmp_path / "brdf_slices.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 4 * 3 * 357
    values = np.array([[float(r[k]) for k in ("f_r_red_per_sr", "f_r_green_per_sr", "f_r_blue_per_sr")] for r in rows])
    assert np.all(np.isfinite(values)) and np.all(values >= 0)
    out = capsys.readouterr().out
    assert "max albedo" in out and "NO" not in out.split("finite>=0")[1]


def test_slice_peaks_at_the_mirror_direction():
    # One sign convention everywhere: signed theta_o > 0 is forward of the light, where the mirror direction lies.
    theta_o = np.linspace(-89.0, 89.0, 357)
    f = in_plane_slice(m.CookTorrance(alpha=0.05, eta=1.5, fresnel="dielectric"), 40.0, theta_o)
    assert theta_o[np.argmax(f[:, 0])] == 40.0


def test_gonio_models_the_report_and_the_sweep_files_share_the_theta_o_sign():
    from analysis.report.plots import angles_of, in_plane_directions
    from model.geometry import degrees_to_vector
    from rig.run.config.sweeps import in_plane

    signed = np.array([-60.0, -20.0, 20.0, 60.0])
    wi, wo = in_plane_directions(35.0, signed)
    rows = in_plane([35.0], signed.tolist())  # a sweep file's in-plane slice: theta_i, phi_i, theta_o, phi_o
    np.testing.assert_allclose(wo, degrees_to_vector(rows[:, 2], rows[:, 3]), atol=1e-12)
    np.testing.assert_allclose(angles_of(np.broadcast_to(wi, wo.shape), wo).signed_theta_o, signed, atol=1e-9)
    brdf = m.CookTorrance(alpha=0.05, eta=1.5, fresnel="dielectric")
    np.testing.assert_allclose(in_plane_slice(brdf, 35.0, signed)[:, 0], brdf.eval(wi, wo), rtol=1e-12)


COMMANDS = [["demo"], ["models"], ["run"], ["plan"], ["resume"], ["servo", "scan"], ["servo", "ping"],
            ["servo", "status"], ["servo", "move"], ["sim", "servos"], ["sim", "grbl"], ["sim", "rig"], ["analyze"],
            ["adaptive"]]  # fmt: skip


@pytest.mark.parametrize("command", COMMANDS, ids=" ".join)
def test_every_command_explains_itself_with_an_example(command, capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main([*command, "--help"])
    assert exc.value.code == 0
    assert f"Example: gonio {' '.join(command)}" in capsys.readouterr().out


def test_unknown_command_is_bad_input(capsys):
    try:
        cli.main(["frobnicate"])
    except SystemExit as exc:
        assert exc.code == 2
    assert "invalid choice" in capsys.readouterr().err


EXAMPLES = __import__("pathlib").Path(__file__).resolve().parents[2] / "examples"


def test_plan_lists_unreachable_points_and_an_estimate_without_moving(capsys):
    sweep, rig = EXAMPLES / "sweep_in_plane.toml", EXAMPLES / "rig_simulated.toml"
    assert cli.main(["plan", str(sweep), "--rig", str(rig), "--list"]) == 0
    out = capsys.readouterr().out
    assert "32 to measure, 1 unreachable" in out and "min_separation" in out
    assert "Estimated run time" in out
    assert len([line for line in out.splitlines() if "->" in line]) == 32


def test_a_bad_sweep_file_is_bad_input(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[sweep]\nkind = 'grid'\n")
    assert cli.main(["plan", str(bad)]) == 2
    assert f"{bad}: [sweep] a 'grid' sweep needs theta_i_deg" in capsys.readouterr().err


@pytest.mark.mitsuba
def test_demo_measures_gold_on_the_simulated_rig(tmp_path, capsys):
    assert cli.main(["demo", "--out", str(tmp_path), "--points", "5", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert (tmp_path / "demo.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with open(tmp_path / "run" / "samples.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) >= 8
    median = float(out.split("median |measured/model - 1| = ")[1].split("%")[0]) / 100
    assert median < 0.03


def test_adaptive_measures_its_budget_with_the_reference_snr_asked_for(tmp_path, capsys):
    from tests.run_helpers import reference_relative_errors

    out = tmp_path / "ad"
    args = ["adaptive", "--rig", str(EXAMPLES / "rig_simulated.toml"), "--out", str(out), "--model", "lambert",
            "--budget", "12", "--initial", "8", "--batch", "4", "--snr", "50", "--reference-snr", "1200"]  # fmt: skip
    assert cli.main(args) == 0
    assert "12 captures in 2 rounds" in capsys.readouterr().out
    rel = reference_relative_errors(out)
    # The photon noise is planned to 1/1200; the journal's error also counts a 16-pixel scatter.
    assert len(rel) >= 4 and np.median(rel) <= 1.1 / 1200
    assert cli.main([*args[:4], str(tmp_path / "bad"), "--reference-snr", "0"]) == 2
    assert "--reference-snr 0: expected a positive signal-to-noise ratio" in capsys.readouterr().err


def test_adaptive_metadata_options_and_their_mistakes(capsys: pytest.CaptureFixture[str]) -> None:
    from gonio.cli_adaptive import _metadata

    assert _metadata(["sample=gold foil #7", "notes=a=b", "operator="]) == {
        "sample": "gold foil #7", "notes": "a=b", "operator": ""}
    assert cli.main(["adaptive", "--out", "/nonexistent/x", "--metadata", "sample"]) == 2
    assert "--metadata 'sample': expected KEY=VALUE" in capsys.readouterr().err
    assert cli.main(["adaptive", "--metadata", "sample=x"]) == 2  # neither --out nor --resume
    assert "--out DIR is required (or --resume DIR" in capsys.readouterr().err


def test_gonio_adaptive_shows_its_rounds_on_a_bar_with_an_eta(monkeypatch, tmp_path, capsys):
    # The rounds themselves are run_adaptive's (tests/rig/run/adaptive/test_adaptive.py); here: the command's bar.
    from pathlib import Path

    import rig.run.adaptive.sweep as adaptive
    from model.fit.solve import fit
    from model.fit.spec import LAMBERT
    from tests.analysis.test_report_honesty import GOLD, in_plane

    r = fit(LAMBERT, in_plane(GOLD), starts=1, warn=False)

    def rounds(rig, out, spec, settings, *, on_round=None, log=None, **_):
        result = adaptive.AdaptiveResult()
        for i, captures in enumerate((8, 12)):
            log(f"round {i}: {captures} captures")
            rnd = adaptive.Round(i, captures, 60.0, r, 0.1, Path(out) / f"round-{i:02d}")
            result.rounds.append(rnd)
            on_round(rnd)
        return result

    monkeypatch.setattr(adaptive, "run_adaptive", rounds)
    assert cli.main(["adaptive", "--out", str(tmp_path / "a"), "--budget", "12", "--initial", "8", "--batch", "4"]) == 0
    err = capsys.readouterr().err
    assert "round 1: 12 captures" in err and re.search(r"adaptive: +\d+%.*12/12 \[[0-9:]+<[0-9:?]+", err), err
