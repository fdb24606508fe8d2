"""Objects found by name through registration: one entry-point group, looked up once, checked for their type.

gonio has two such registries, the camera backends (``acquisition.cameras.registry``, group ``gonio.cameras``)
and the rig backends (``rig.run.registry``, group ``gonio.backends``); both are a :class:`Registry`, so a name
is found, loaded, checked and refused in one way. It sits here, in the lowest layer that has plugins, so that
both can use it.
"""

from __future__ import annotations

from collections.abc import Iterable
from importlib.metadata import EntryPoint, entry_points
from typing import Generic, TypeVar

from model.spelling import did_you_mean

T = TypeVar("T")


def ordered(names: Iterable[str], first: tuple[str, ...] = ()) -> tuple[str, ...]:
    """Names with those of ``first`` at the front, in its order, then the others alphabetically."""
    return tuple(sorted(set(names), key=lambda n: (first.index(n) if n in first else len(first), n)))


class Registry(Generic[T]):
    """The objects registered in the entry-point group ``group``, each a ``kind``, by name.

    Parameters:
        group: the entry-point group, e.g. "gonio.cameras".
        kind: the type a registered object must be.
        noun: what messages call one, e.g. "camera backend".
        error: the exception raised for a name not registered, a plugin that cannot be loaded or is not a ``kind``.
        kind_name: what messages call the type (default ``kind``'s name).
        first: names listed first, in this order (gonio's own); the others follow alphabetically.
        advise: True where a name not registered is answered with the closest registered one, and with how to
            install gonio when none is.
    """

    def __init__(self, group: str, kind: type[T], noun: str, error: type[Exception], *, kind_name: str = "",
                 first: tuple[str, ...] = (), advise: bool = False) -> None:  # fmt: skip
        self.group, self.kind, self.noun, self.error = group, kind, noun, error
        self.kind_name, self.first, self.advise = kind_name or kind.__name__, first, advise
        self._registered: dict[str, EntryPoint] | None = None
        self._loaded: dict[str, T] = {}

    def entry_points(self) -> dict[str, EntryPoint]:
        """The group's entry points in the installed metadata, by name (a test replaces this to add its own)."""
        return {ep.name: ep for ep in entry_points(group=self.group)}

    def registered(self) -> dict[str, EntryPoint]:
        """The group's entry points by name, read once (until ``reload``)."""
        if self._registered is None:
            self._registered = self.entry_points()
        return self._registered

    def names(self) -> tuple[str, ...]:
        """Every registered name, those of ``first`` first, then alphabetically."""
        return ordered(self.registered(), self.first)

    def load(self, name: str) -> T:
        """The object registered under ``name``, loaded once; ``error`` names the registered ones if there is none."""
        if name in self._loaded:
            return self._loaded[name]
        ep = self.registered().get(name)
        if ep is None:
            known = self.names()
            hint = " (none is registered: is gonio installed? `pip install -e .`)" if self.advise and not known else ""
            close = did_you_mean(name, known, aside=True) if self.advise else ""
            raise self.error(f"no {self.noun} {name!r} in the entry-point group {self.group!r}{close}; "
                             f"registered: {', '.join(known) or 'none'}{hint}")  # fmt: skip
        try:
            found = ep.load()
        except Exception as exc:  # a broken plugin names itself, whatever it raised
            raise self.error(f"{self.noun} {name!r} ({ep.value}) cannot be loaded: {exc}") from exc
        if not isinstance(found, self.kind):
            raise self.error(f"{self.noun} {name!r} ({ep.value}) is a {type(found).__name__}, not a {self.kind_name}")
        self._loaded[name] = found
        return found

    def reload(self) -> None:
        """Forget what was looked up (after installing a plugin in a running process, or in tests)."""
        self._registered = None
        self._loaded.clear()
