"""Camera backends by name: what a rig file's ``[camera] backend`` names, found by registration.

A camera backend is registered as a Python entry point in the group ``gonio.cameras`` whose object is a
:class:`CameraBackend`; gonio's own (``folder``, ``opencv``) are in :mod:`acquisition.cameras.builtin`,
declared in gonio's ``pyproject.toml``. A lab adds a camera of its own as a separate package the same
way, without editing gonio (docs/architecture.md). The simulated rig's rendered camera is not among
them: it comes with the simulated rig backend (``rig.run.backends.base``), since it watches the virtual servos.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from typing import Any

from acquisition.cameras import CameraError, ClockLike
from acquisition.frame import Camera

GROUP = "gonio.cameras"


@dataclass(frozen=True)
class CameraBackend:
    """A registered camera backend.

    Parameters:
        open: ``open(settings, clock)`` returns an open :class:`acquisition.frame.Camera`; ``settings`` is
            the rig file's validated ``[camera]`` table as a mapping, ``clock`` the run's clock.
        description: one line for listings and error messages.
        keys: the ``[camera]`` keys this backend reads beyond the common ones (exposure range, ROI, noise,
            calibration, flat field); a rig file that sets another backend's key is an error naming it.
            ``"options"`` admits a free ``[camera.options]`` table, for a lab's backend with settings of its own.
        required: those of ``keys`` a rig file must give.
    """

    open: Callable[[Mapping[str, Any], ClockLike], Camera]
    description: str = ""
    keys: tuple[str, ...] = ()
    required: tuple[str, ...] = ()


def _entry_points() -> dict[str, EntryPoint]:
    return {ep.name: ep for ep in entry_points(group=GROUP)}


@functools.cache
def _registered() -> dict[str, EntryPoint]:
    return _entry_points()


def names() -> tuple[str, ...]:
    """Every registered camera backend's name, alphabetically."""
    return tuple(sorted(_registered()))


@functools.cache
def camera_backend(name: str) -> CameraBackend:
    """The camera backend registered under ``name``; CameraError names the registered ones."""
    ep = _registered().get(name)
    if ep is None:
        raise CameraError(
            f"no camera backend {name!r} in the entry-point group {GROUP!r}; registered: {', '.join(names()) or 'none'}"
        )
    try:
        found = ep.load()
    except Exception as exc:  # a broken plugin names itself, whatever it raised
        raise CameraError(f"camera backend {name!r} ({ep.value}) cannot be loaded: {exc}") from exc
    if not isinstance(found, CameraBackend):
        raise CameraError(f"camera backend {name!r} ({ep.value}) is a {type(found).__name__}, not a CameraBackend")
    return found


def reload() -> None:
    """Forget what was looked up (after installing a plugin in a running process, or in tests)."""
    _registered.cache_clear()
    camera_backend.cache_clear()
