"""Targets the rig puts where the sample is: the Lambertian reference tile, and the calibration board.

A real rig either has a flip-in (or stage-mounted) reference that software can move, or an operator who
swaps the tile by hand; the simulated rig swaps the rendered material. The runner only needs the two
calls of ``ReferenceTarget``. ``ManualReference`` asks the operator on the terminal and waits for Enter.
Geometry calibration (``rig.alignment``) mounts a ChArUco board the same way (``BoardTarget``,
``ManualBoard``).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Protocol, runtime_checkable

from acquisition.board import ChArUcoBoard
from model.errors import InputError


class OperatorAbsent(InputError, RuntimeError):
    """A prompt for the operator found standard input closed: nobody is there to answer it."""


def operator_prompt(ask: Callable[[str], str]) -> Callable[[str], str]:
    """``ask`` (``input`` by default), raising OperatorAbsent where input has ended (a script, no terminal)."""

    def prompt(text: str) -> str:
        try:
            return ask(text)
        except EOFError:
            raise OperatorAbsent(
                f"gonio asked the operator {text.strip().rstrip(':')!r}, but standard input is closed: run it "
                "where someone can answer (a terminal), or give it what it asks for on its input"
            ) from None

    return prompt


@runtime_checkable
class ReferenceTarget(Protocol):
    """Something that can put the reference tile in view (``present``) and take it away (``withdraw``)."""

    @property
    def description(self) -> str:
        """What the reference is (for the journal and the manifest)."""
        ...

    def present(self, slot: int) -> None:
        """Put the reference where the sample is for reading ``slot`` (its place in the plan); returns once in place."""
        ...

    def withdraw(self) -> None:
        """Put the sample back; returns once it is in place."""
        ...


class ManualReference:
    """An operator swaps the tile by hand, prompted on the terminal (``ask`` is ``input`` by default)."""

    def __init__(self, ask: Callable[[str], str] | None = None, description: str = "reference tile placed by hand"):
        self._ask = operator_prompt(ask or input)
        self._description = description

    @property
    def description(self) -> str:
        """What the reference is."""
        return self._description

    def present(self, slot: int) -> None:
        """Ask the operator to place the reference tile (for the reading before point ``slot``) and wait for Enter."""
        print("\a", end="", file=sys.stderr)
        self._ask(f"Reference reading before point {slot}: place the reference tile on the stage, then press Enter: ")

    def withdraw(self) -> None:
        """Ask the operator to put the sample back and wait for Enter."""
        self._ask("Put the sample back on the stage, then press Enter: ")


@runtime_checkable
class BoardTarget(Protocol):
    """Something that can mount the calibration board where the sample is, and take it off again."""

    @property
    def description(self) -> str:
        """What the board is mounted on (for the calibration file)."""
        ...

    def present_board(self, board: ChArUcoBoard, alpha: float) -> None:
        """Mount ``board`` (its coat's roughness ``alpha``, GGX) where the sample is; returns once in place."""
        ...

    def withdraw_board(self) -> None:
        """Put the sample back; returns once it is in place."""
        ...


class ManualBoard:
    """An operator mounts the board by hand, prompted on the terminal (``ask`` is ``input`` by default)."""

    def __init__(self, ask: Callable[[str], str] | None = None) -> None:
        self._ask = operator_prompt(ask or input)

    @property
    def description(self) -> str:
        """What the board is."""
        return "ChArUco board mounted by hand"

    def present_board(self, board: ChArUcoBoard, alpha: float) -> None:
        """Ask the operator to mount the printed board and wait for Enter."""
        print("\a", end="", file=sys.stderr)
        self._ask(f"Mount the ChArUco board ({board.squares} x {board.squares} squares of {board.square_mm:g} mm, "
                  f"{board.dictionary}) centred on the stage, pattern upright, then press Enter: ")  # fmt: skip

    def withdraw_board(self) -> None:
        """Ask the operator to put the sample back and wait for Enter."""
        self._ask("Put the sample back on the stage, then press Enter: ")
