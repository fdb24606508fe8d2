"""The simulated rig as the ``simulated`` backend of ``gonio.backends``: what the session opens for it.

Registered in gonio's ``pyproject.toml``, so ``rig`` finds the simulator by name and never imports it.
The rig file's ``[simulation]`` table describes the sample and the light (:mod:`simulator.from_config`)
and what moves the joints (``link``: virtual Dynamixel servos, or a virtual GRBL controller whose axes are
lettered, move coordinated and are homed before a run moves, :mod:`simulator.grbl_rig`);
the rendered camera and the flip-in reference tile come with the rig, so ``[camera] backend`` and
``[reference] kind`` are "simulated" there too. Mitsuba loads when a run opens the rig, not when a rig
file is read.
"""

from __future__ import annotations

import contextlib
import dataclasses
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

from rig.run.backends.base import Instruments, RigBackend, StartPose
from rig.run.backends.hardware import dynamixel_options
from rig.run.config.files import RigConfig
from rig.run.registry import BackendTraits


@contextlib.contextmanager
def open_simulated(rig: RigConfig, start: StartPose | None = None) -> Iterator[Instruments]:
    """Start the simulated rig of a rig file (its axes at ``start``, degrees) and yield its instruments."""
    from simulator.from_config import spec_from
    from simulator.rig import SimulatedRig

    with SimulatedRig(spec_from(rig), start=start) as sim:
        link = sim.open_link(options=dynamixel_options(rig))
        assert sim.camera is not None
        target = sim.reference if rig.file.reference.kind == "simulated" else None
        yield Instruments(link, sim.camera, sim.clock, target, sim.flat_source, board=sim.board)


@contextlib.contextmanager
def open_simulated_grbl(rig: RigConfig, start: StartPose | None = None) -> Iterator[Instruments]:
    """Start the simulated GRBL rig of a rig file (its axes physically at ``start``, degrees): its instruments."""
    from simulator.from_config import spec_from
    from simulator.grbl_rig import SimulatedGrblRig

    with SimulatedGrblRig(spec_from(rig), start=start) as sim:
        assert sim.camera is not None
        target = sim.reference if rig.file.reference.kind == "simulated" else None
        yield Instruments(sim.open_link(), sim.camera, sim.clock, target, sim.flat_source, board=sim.board)


def _open(rig: RigConfig, start: StartPose | None = None) -> contextlib.AbstractContextManager[Instruments]:
    """The simulated rig whose joints ``[simulation] link`` names: Dynamixel servos or a GRBL controller."""
    return (open_simulated_grbl if rig.file.simulation.link == "grbl" else open_simulated)(rig, start)


@dataclass(frozen=True)
class SimulatedBackend(RigBackend):
    """The simulated rig's backend, whose traits follow the rig file's ``[simulation] link``."""

    def for_file(self, file: Any) -> BackendTraits:
        """GRBL's traits (axis letters, coordinated moves) for ``link = "grbl"``, the servos' otherwise."""
        if file.simulation.link == "grbl":
            return dataclasses.replace(self, addressing="letter", coordinated=True)
        return self


SIMULATED = SimulatedBackend(
    open=_open, addressing="id", needs_port=False, default_axes=True, cameras=("simulated",),
    camera_keys=("resolution", "spp", "variant"), references=("simulated",),
)  # fmt: skip
