"""The registry of rig backends: which names ``[link] kind`` may take, and what each backend's files may say.

Backends are registered as Python entry points in the group ``gonio.backends`` (see :mod:`rig.run.backends.base`
for what a backend is and how a lab registers its own). This module only finds them and reads their
traits, which is all that reading a rig file needs; opening one is :mod:`rig.run.backends.base`'s.
"""

from __future__ import annotations

import difflib
import functools
from collections.abc import Iterable
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from typing import Any, Literal

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
        references: reference kinds only this backend provides, beside "manual" and "none".
    """

    addressing: Literal["id", "letter"] = "id"
    coordinated: bool = False
    needs_port: bool = True
    default_axes: bool = False
    cameras: tuple[str, ...] = ()
    references: tuple[str, ...] = ()

    def for_file(self, file: Any) -> BackendTraits:
        """The traits that hold for one rig file (a ``RigFile``): these, unless the backend's files choose.

        A backend whose rig files pick their link (the simulated rig's ``[simulation] link``) overrides this.
        """
        return self


def ordered(names: Iterable[str]) -> tuple[str, ...]:
    """Backend names with gonio's own first, in BUILTIN order, then the others alphabetically."""
    return tuple(sorted(set(names), key=lambda n: (BUILTIN.index(n) if n in BUILTIN else len(BUILTIN), n)))


def listing(names: Iterable[str]) -> str:
    """Names as an error message lists them: 'a', 'b' or 'c'."""
    quoted = [repr(n) for n in names]
    return quoted[0] if len(quoted) == 1 else ", ".join(quoted[:-1]) + " or " + quoted[-1]


def suggestion(name: str, known: Iterable[str]) -> str:
    """' (did you mean 'x'?)' for a close match among ``known``, else ''."""
    close = difflib.get_close_matches(name, list(known), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


def _entry_points() -> dict[str, EntryPoint]:
    return {ep.name: ep for ep in entry_points(group=GROUP)}


@functools.cache
def _registered() -> dict[str, EntryPoint]:
    return _entry_points()


def names() -> tuple[str, ...]:
    """Every registered rig backend's name, gonio's own first."""
    return ordered(_registered())


@functools.cache
def load(name: str) -> BackendTraits:
    """The object registered under ``name`` (a :class:`rig.run.backends.base.RigBackend`); BackendError if none."""
    ep = _registered().get(name)
    if ep is None:
        known = names()
        hint = " (none is registered: is gonio installed? `pip install -e .`)" if not known else ""
        raise BackendError(
            f"no rig backend {name!r} in the entry-point group {GROUP!r}{suggestion(name, known)}; "
            f"registered: {', '.join(known) or 'none'}{hint}"
        )
    try:
        found = ep.load()
    except Exception as exc:  # a broken plugin names itself, whatever it raised
        raise BackendError(f"rig backend {name!r} ({ep.value}) cannot be loaded: {exc}") from exc
    if not isinstance(found, BackendTraits):
        raise BackendError(f"rig backend {name!r} ({ep.value}) is a {type(found).__name__}, not a RigBackend")
    return found


def provided_cameras() -> tuple[str, ...]:
    """Camera backends that come with a rig backend (such as the simulated rig's camera)."""
    return tuple(dict.fromkeys(c for n in names() for c in load(n).cameras))


def reload() -> None:
    """Forget what was looked up (after installing a plugin in a running process, or in tests)."""
    _registered.cache_clear()
    load.cache_clear()
