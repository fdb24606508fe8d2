"""Camera backends that satisfy ``acquisition.frame.Camera``, and what they share.

- ``tethered.TetheredFolderCamera``: frames that vendor tethering software writes into a folder.
- ``opencv.OpenCVCamera``: UVC webcams and machine-vision cameras with a UVC mode (8-bit frames).
- ``gphoto2.GPhoto2Camera``: still cameras over USB/PTP through libgphoto2 (extra ``gonio[gphoto2]``).
- ``genicam.GenICamCamera``: GenICam/GigE Vision/USB3 Vision cameras through harvesters (extra
  ``gonio[genicam]``).

Backends are imported from their modules, so importing this package loads neither OpenCV nor any
optional library. Time comes from a ``ClockLike`` (acquisition must not import rig; ``rig.instrument.clock``'s
clocks satisfy this protocol structurally).
"""

from __future__ import annotations

import importlib
import time
from types import ModuleType
from typing import Protocol, runtime_checkable

from model.errors import CameraFault, InputError


@runtime_checkable
class ClockLike(Protocol):
    """A source of monotonic time in seconds that can be waited on (``rig.instrument.clock.Clock`` fits)."""

    def now(self) -> float:
        """Current time in seconds (monotonic, arbitrary origin)."""
        ...

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` of this clock's time pass."""
        ...


class RealTimeClock:
    """Wall-clock time in seconds: what a camera waits on unless a test or simulation injects a clock."""

    def now(self) -> float:
        """Seconds from ``time.monotonic``."""
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        """Block for ``seconds`` of real time."""
        if seconds > 0:
            time.sleep(seconds)


class CameraError(CameraFault, RuntimeError):
    """A camera could not be opened, configured or read."""


class ExposureUnconfirmedError(CameraError):
    """A strict camera was asked for an exposure its driver cannot set or report back."""


class BackendNotInstalledError(InputError, ImportError):
    """An optional camera backend's library is missing; the message names the pip extra that installs it."""


def import_backend(module: str, extra: str, backend: str) -> ModuleType:
    """Import ``module`` for camera ``backend``; raise BackendNotInstalledError naming ``gonio[extra]`` if missing."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise BackendNotInstalledError(
            f"the {backend} camera backend needs the Python module {module!r}, which is not installed "
            f"({exc}); install it with: pip install 'gonio[{extra}]'",
            name=module,
        ) from exc


__all__ = [
    "BackendNotInstalledError",
    "CameraError",
    "ClockLike",
    "ExposureUnconfirmedError",
    "RealTimeClock",
    "import_backend",
]
