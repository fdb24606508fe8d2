"""The light a camera calibration needs: uniform over the sensor, or none at all (the lens capped).

A photon-transfer and flat-field series wants a uniform, stable light filling the camera's view (an
integrating sphere, or a diffuser over a lamp) and dark frames with no light at all. The simulated rig
switches its rendered scene for one (``simulator.camera.view.SimulatedFlatSource``); on a real rig
``ManualFlatSource`` asks the operator to set it up and waits for Enter.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Protocol, runtime_checkable

from rig.run.backends.reference import operator_prompt


@runtime_checkable
class FlatSource(Protocol):
    """Puts a uniform light before the camera (``illuminate``), caps it (``darken``), or restores the rig."""

    @property
    def description(self) -> str:
        """What the source is (for the calibration file)."""
        ...

    def illuminate(self) -> None:
        """Uniform light over the whole view; returns once it is there and stable."""
        ...

    def darken(self) -> None:
        """No light on the sensor (lens capped, source off); returns once dark."""
        ...

    def restore(self) -> None:
        """The rig as it was for measuring."""
        ...


class ManualFlatSource:
    """An operator sets up the light and the cap by hand, prompted on the terminal (``ask``: ``input``)."""

    def __init__(self, ask: Callable[[str], str] | None = None,
                 description: str = "flat-field source placed by hand") -> None:  # fmt: skip
        self._ask = operator_prompt(ask or input)
        self._description = description

    @property
    def description(self) -> str:
        """What the source is."""
        return self._description

    def illuminate(self) -> None:
        """Ask for the uniform light (integrating sphere or diffuser filling the view) and wait for Enter."""
        print("\a", end="", file=sys.stderr)
        self._ask("Camera calibration: put a uniform, stable light filling the camera's view (integrating sphere "
                  "or diffuser), then press Enter: ")  # fmt: skip

    def darken(self) -> None:
        """Ask for the lens cap and wait for Enter."""
        print("\a", end="", file=sys.stderr)
        self._ask("Now cap the lens (no light on the sensor) for the dark frames, then press Enter: ")

    def restore(self) -> None:
        """Ask for the measuring set-up again and wait for Enter."""
        self._ask("Calibration done: restore the rig for measuring (lens uncapped, source away), then press Enter: ")
