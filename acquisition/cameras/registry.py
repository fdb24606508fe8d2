"""Camera backends by name: what a rig file's ``[camera] backend`` names, found by registration.

A camera backend is registered as a Python entry point in the group ``gonio.cameras`` whose object is a
:class:`CameraBackend`; gonio's own (``folder``, ``opencv``, ``gphoto2``, ``genicam``) are in
:mod:`acquisition.cameras.builtin`, declared in gonio's ``pyproject.toml``. A lab adds a camera of its own as a
separate package the same way, without editing gonio (docs/architecture.md). The simulated rig's rendered camera
is not among them: it comes with the simulated rig backend (``rig.run.backends.base``), since it watches the
virtual servos. Finding, loading and refusing a name is :class:`acquisition.registry.Registry`'s.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from acquisition.cameras import CameraError, ClockLike
from acquisition.frame import Camera
from acquisition.registry import Registry, ordered

GROUP = "gonio.cameras"
#: gonio's own camera backends, in the order a message names those that read a key (others follow alphabetically).
BUILTIN = ("folder", "opencv", "gphoto2", "genicam")


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
            This is the one list of which backend reads which key: config validation derives its checks from it
            (the keys' types, bounds and meaning are ``rig.run.config.camera.Camera``'s).
        required: those of ``keys`` a rig file must give.
    """

    open: Callable[[Mapping[str, Any], ClockLike], Camera]
    description: str = ""
    keys: tuple[str, ...] = ()
    required: tuple[str, ...] = ()


CAMERAS = Registry(GROUP, CameraBackend, "camera backend", CameraError)


def names() -> tuple[str, ...]:
    """Every registered camera backend's name, alphabetically."""
    return CAMERAS.names()


def camera_backend(name: str) -> CameraBackend:
    """The camera backend registered under ``name``; CameraError names the registered ones."""
    return CAMERAS.load(name)


def readers(key: str) -> tuple[str, ...]:
    """The registered camera backends that read ``[camera]`` ``key``, gonio's own first (BUILTIN order)."""
    found = []
    for name in names():
        try:
            if key in camera_backend(name).keys:
                found.append(name)
        except CameraError:
            continue  # a broken plugin is named when a rig file chooses it, not in another backend's message
    return ordered(found, BUILTIN)


def reload() -> None:
    """Forget what was looked up (after installing a plugin in a running process, or in tests)."""
    CAMERAS.reload()
