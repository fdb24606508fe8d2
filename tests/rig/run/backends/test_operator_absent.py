"""A prompt for the operator with nobody to answer (standard input closed) is bad input, never a bug."""

from __future__ import annotations

import pytest

from acquisition.board import ChArUcoBoard
from gonio.cli_errors import EXIT_BAD_INPUT, report
from rig.run.backends.flat_source import ManualFlatSource
from rig.run.backends.reference import ManualBoard, ManualReference, OperatorAbsent


def _closed(prompt: str) -> str:
    raise EOFError  # what input() raises once standard input has ended


@pytest.mark.parametrize("ask", [
    lambda: ManualReference(ask=_closed).present(3),
    lambda: ManualReference(ask=_closed).withdraw(),
    lambda: ManualBoard(ask=_closed).present_board(ChArUcoBoard(), 0.01),
    lambda: ManualFlatSource(ask=_closed).illuminate(),
    lambda: ManualFlatSource(ask=_closed).darken(),
])  # fmt: skip
def test_a_prompt_on_closed_input_names_what_it_asked(ask: object) -> None:
    with pytest.raises(OperatorAbsent, match=r"standard input is closed") as caught:
        ask()  # type: ignore[operator]
    assert "press Enter" in str(caught.value)


def test_the_command_line_calls_it_bad_input(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(OperatorAbsent) as caught:
        ManualReference(ask=_closed).present(0)
    assert report(caught.value, False) == EXIT_BAD_INPUT
    assert "standard input is closed" in capsys.readouterr().err
