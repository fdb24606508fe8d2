import csv

import numpy as np

import model as m
from rig import cli
from rig.demo import in_plane_slice


def test_demo_writes_figure_and_table(tmp_path, capsys):
    assert cli.main(["demo", "--out", str(tmp_path)]) == 0
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
    theta_o = np.linspace(-89.0, 89.0, 357)
    f = in_plane_slice(m.CookTorrance(alpha=0.05, eta=1.5, fresnel="dielectric"), 40.0, theta_o)
    assert theta_o[np.argmax(f[:, 0])] == -40.0


def test_help_has_examples(capsys):
    try:
        cli.main(["demo", "--help"])
    except SystemExit as exc:
        assert exc.code == 0
    assert "Example: gonio demo" in capsys.readouterr().out


def test_unknown_command_is_bad_input(capsys):
    try:
        cli.main(["frobnicate"])
    except SystemExit as exc:
        assert exc.code == 2
    assert "invalid choice" in capsys.readouterr().err
