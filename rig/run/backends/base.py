"""Backends: what a rig file's ``[link] kind`` names, found by registration rather than by import.

A rig backend opens a rig file's instruments (the link, the camera, the clock they share and the
reference target) for the length of a run. Backends are registered as Python entry points in the group
``gonio.backends``; gonio's own are ``dynamixel`` and ``grbl`` (:mod:`rig.run.backends.hardware`) and ``simulated``
(:mod:`simulator.backend`), declared in gonio's ``pyproject.toml``. This is how the session reaches the
simulator without ``rig`` importing it, and how a lab adds a stage of its own as a separate package,
without editing gonio: it declares

    [project.entry-points."gonio.backends"]
    lab_stage = "lab_gonio.stage:BACKEND"

where ``BACKEND`` is a :class:`RigBackend`, and rig files may then say ``[link] kind = "lab_stage"``.
Camera backends follow the same rule in the group ``gonio.cameras`` (:mod:`acquisition.cameras.registry`).
Finding backends and reading their traits (all that loading a rig file needs) is :mod:`rig.run.registry`.

Loading a backend imports only its registering module; that module should import its hardware
libraries inside ``open``, so that reading a rig file stays quick.
"""

from __future__ import annotations

from collections.abc import Mapping
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from typing import Protocol

from acquisition.frame import Camera
from rig.instrument.clock import Clock
from rig.instrument.links.base import MotionLink
from rig.run import registry
from rig.run.backends.flat_source import FlatSource
from rig.run.backends.reference import BoardTarget, ReferenceTarget
from rig.run.config.files import RigConfig

#: Joint angles in degrees a simulated rig starts at (a resumed run's last pose), by joint name.
StartPose = Mapping[str, float]


@dataclass
class Instruments:
    """What a run drives: the link, the camera, the clock they share, the reference target (if any), the flat source."""

    link: MotionLink
    camera: Camera
    clock: Clock
    target: ReferenceTarget | None
    #: What ``gonio calibrate camera`` shows the camera (None: the backend cannot calibrate its camera).
    flat_source: FlatSource | None = None
    #: Mounts the calibration board for ``gonio calibrate geometry`` (None: the backend cannot).
    board: BoardTarget | None = None


class OpenInstruments(Protocol):
    """How a backend opens a rig file's instruments: ``open(rig, start=None)``."""

    def __call__(self, rig: RigConfig, start: StartPose | None = None) -> AbstractContextManager[Instruments]:
        """A context manager yielding the run's instruments and closing what it opened."""
        ...


@dataclass(frozen=True)
class RigBackend(registry.BackendTraits):
    """A registered rig backend: its traits (:class:`rig.run.registry.BackendTraits`) and how it opens.

    ``open(rig, start=None)`` returns a context manager that yields the run's :class:`Instruments` and
    closes what it opened (the runner shuts the link down itself). ``start`` (joint angles in degrees) is
    where a resumed run's journal says the axes stood when it stopped: real hardware stands wherever it
    stands and ignores it; a simulation starts its axes there, as a rig that stayed put would.
    """

    open: OpenInstruments = field(kw_only=True)


def backend(name: str) -> RigBackend:
    """The rig backend registered under ``name``; :class:`rig.run.registry.BackendError` if there is none."""
    found = registry.load(name)
    if not isinstance(found, RigBackend):
        raise registry.BackendError(f"rig backend {name!r} is a {type(found).__name__}, not a RigBackend")
    return found
