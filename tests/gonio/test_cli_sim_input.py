"""What ``gonio sim`` says about bad input: an --axes it cannot serve, a ``capture`` line it cannot read."""

from __future__ import annotations

import pytest

from gonio import cli
from gonio.cli_sim import capture_seconds


@pytest.mark.parametrize("axes", ["XQ", "YZ", "", "XYZABCX", "xyz"])
def test_sim_grbl_refuses_axes_it_cannot_serve_as_bad_input(axes: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        cli.main(["sim", "grbl", "--axes", axes])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert f"--axes {axes!r}: expected the first 1 to 6 of GRBL's axis letters XYZABC in that order" in err


@pytest.mark.parametrize("text", ["abc", "0", "-1", "-0.5", "nan", "inf", "-inf", "1e999", ""])
def test_capture_line_with_a_bad_exposure_says_what_is_expected(text: str) -> None:
    with pytest.raises(ValueError) as err:
        capture_seconds(text)
    assert str(err.value) == f"'capture {text}': expected 'capture SECONDS' with SECONDS a positive number"


@pytest.mark.parametrize(("text", "seconds"), [("0.01", 0.01), ("2", 2.0), ("1e-4", 1e-4)])
def test_capture_line_with_a_positive_exposure_is_read(text: str, seconds: float) -> None:
    assert capture_seconds(text) == seconds


def test_input_lines_are_read_whole_and_the_last_one_without_its_newline() -> None:
    import os

    from gonio.cli_sim import _lines

    read_end, write_end = os.pipe()
    os.write(write_end, b"scene board\ncapture 0.")
    os.write(write_end, b"5\nscene sample")
    os.close(write_end)
    try:
        assert list(_lines(read_end)) == ["scene board\n", "capture 0.5\n", "scene sample"]
    finally:
        os.close(read_end)


def test_ctrl_c_stops_the_wait_for_a_line_though_sigint_restarts_reads() -> None:
    # Mitsuba's render leaves SIGINT's handler with SA_RESTART; a blocked read then never raised KeyboardInterrupt.
    import os
    import signal
    import threading
    import time

    from gonio.cli_sim import _lines

    read_end, write_end = os.pipe()
    signal.siginterrupt(signal.SIGINT, False)  # SA_RESTART, as a render leaves it
    timer = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT))
    start = time.monotonic()
    try:
        timer.start()
        with pytest.raises(KeyboardInterrupt):
            list(_lines(read_end, wake_s=0.05))
        assert time.monotonic() - start < 5.0
    finally:
        timer.cancel()
        signal.signal(signal.SIGINT, signal.default_int_handler)  # Python's own handler again, without SA_RESTART
        os.close(read_end)
        os.close(write_end)
