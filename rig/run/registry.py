"""The registry of rig backends: which names ``[link] kind`` may take, and what each backend's files may say.

Backends are registered as Python entry points in the group ``gonio.backends`` (see :mod:`rig.run.backends.base`
for what a backend is and how a lab registers its own). This module only finds them (through
:class:`acquisition.registry.Registry`, as the camera backends are found) and reads their traits, which is all
that reading a rig file needs; opening one is :mod:`rig.run.backends.base`'s.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any, Literal

from acquisition.registry import Registry
from model.errors import InputError

GROUP = "gonio.backends"
#: gonio's own backends, in the order error messages list them (others follow alphabetically).
BUILTIN = ("simulated", "dynamixel", "grbl")


class BackendError(InputError, LookupError):
    """No backend is registered under a name, or a registered one cannot be loaded."""


@dataclass(frozen=True)
class BackendTraits:
    """What a backend's rig files may say, as config validation reads it.

    Parameters:
        addressing: "id" (``[axes.<joint>] id``, a servo id) or "letter" (``letter``, a GRBL axis).
        coordinated: True where one move drives all axes along a straight line in joint space (GRBL),
            False where each axis moves on its own profile (Dynamixel); the planner times moves by it.
        needs_port: True where ``[link] port`` is required (a device path).
        default_axes: True where ``[axes.*]`` may be left out (one XM430-W350 per joint).
        cameras: camera backends only this backend provides (the simulated rig's rendered camera); when
            given, ``[camera] backend`` must be one of them.
        camera_keys: the ``[camera]`` keys those cameras read beyond the common ones (as
            ``acquisition.cameras.registry.CameraBackend.keys`` for a registered camera).
        references: reference kinds only this backend provides, beside "manual" and "none".
    """

    addressing: Literal["id", "letter"] = "id"
    coordinated: bool = False
    needs_port: bool = True
    default_axes: bool = False
    cameras: tuple[str, ...] = ()
    camera_keys: tuple[str, ...] = ()
    references: tuple[str, ...] = ()

    def for_file(self, file: Any) -> BackendTraits:
        """The traits that hold for one rig file (a ``RigFile``): these, unless the backend's files choose.

        A backend whose rig files pick their link (the simulated rig's ``[simulation] link``) overrides this.
        """
        return self


def listing(names: Iterable[str]) -> str:
    """Names as an error message lists them: 'a', 'b' or 'c'."""
    quoted = [repr(n) for n in names]
    return quoted[0] if len(quoted) == 1 else ", ".join(quoted[:-1]) + " or " + quoted[-1]


BACKENDS = Registry(GROUP, BackendTraits, "rig backend", BackendError, kind_name="RigBackend", first=BUILTIN,
                    advise=True)  # fmt: skip


def names() -> tuple[str, ...]:
    """Every registered rig backend's name, gonio's own first."""
    return BACKENDS.names()


def load(name: str) -> BackendTraits:
    """The object registered under ``name`` (a :class:`rig.run.backends.base.RigBackend`); BackendError if none."""
    return BACKENDS.load(name)


def provided_cameras() -> tuple[str, ...]:
    """Camera backends that come with a rig backend (such as the simulated rig's camera)."""
    return tuple(dict.fromkeys(c for n in names() for c in load(n).cameras))


def reload() -> None:
    """Forget what was looked up (after installing a plugin in a running process, or in tests)."""
    BACKENDS.reload()
