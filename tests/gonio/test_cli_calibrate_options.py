"""``gonio calibrate``'s options are checked before anything loads, moves or is written, and blamed by name."""

from __future__ import annotations

from pathlib import Path

import pytest

from gonio.cli import main


@pytest.mark.parametrize(
    ("command", "option", "value", "expected"),
    [
        ("geometry", "--square-mm", "0", "--square-mm 0: expected the board's square size in mm, a number > 0"),
        ("geometry", "--square-mm", "nan", "--square-mm nan: expected the board's square size in mm"),
        ("geometry", "--square-mm", "-6", "--square-mm -6: expected the board's square size in mm"),
        ("geometry", "--marker-mm", "7",
         "--marker-mm 7: expected the ArUco marker's size in mm, > 0 and below --square-mm (6)"),
        ("geometry", "--marker-mm", "0", "--marker-mm 0: expected the ArUco marker's size in mm"),
        ("geometry", "--squares", "2", "--squares 2: expected 3 to 20 squares per side of the board"),
        ("geometry", "--captures", "3", "--captures 3: expected 8 to 1000 captures"),
        ("geometry", "--alpha", "inf", "--alpha inf: expected the coat's GGX roughness in [1e-4, 0.3]"),
        ("geometry", "--alpha", "0.5", "--alpha 0.5: expected the coat's GGX roughness in [1e-4, 0.3]"),
        ("camera", "--steps", "3", "--steps 3: expected at least 6 exposures"),
        ("camera", "--flat-frames", "1", "--flat-frames 1: expected 0 (no flat field) or at least 2"),
    ],
)  # fmt: skip
def test_calibrate_blames_the_option_that_is_wrong(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], command: str, option: str, value: str, expected: str
) -> None:
    out = tmp_path / "calib"
    # A rig file that does not exist: the option is checked first, and nothing is opened or created.
    code = main(["calibrate", command, "--rig", str(tmp_path / "absent.toml"), "--out", str(out), option, value])
    assert code == 2
    err = capsys.readouterr().err
    assert expected in err
    if option == "--square-mm":
        assert "marker" not in err
    assert not out.exists()
