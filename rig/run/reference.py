"""The reference target: how the runner puts a Lambertian tile of known albedo where the sample is.

A real rig either has a flip-in (or stage-mounted) reference that software can move, or an operator who
swaps the tile by hand; the simulated rig swaps the rendered material. The runner only needs the two
calls of ``ReferenceTarget``. ``ManualReference`` asks the operator on the terminal and waits for Enter.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Protocol, runtime_checkable


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
        self._ask = ask or input
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
