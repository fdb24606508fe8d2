"""The simulated rig as the ``simulated`` backend of ``gonio.backends``: what the session opens for it.

Registered in gonio's ``pyproject.toml``, so ``rig`` finds the simulator by name and never imports it.
The rig file's ``[simulation]`` table describes the sample and the light (:mod:`simulator.from_config`);
the rendered camera and the flip-in reference tile come with the rig, so ``[camera] backend`` and
``[reference] kind`` are "simulated" there too. Mitsuba loads when a run opens the rig, not when a rig
file is read.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from rig.run.backends import Instruments, RigBackend, StartPose
from rig.run.config import RigConfig
from rig.run.hardware import dynamixel_options


@contextlib.contextmanager
def open_simulated(rig: RigConfig, start: StartPose | None = None) -> Iterator[Instruments]:
    """Start the simulated rig of a rig file (its axes at ``start``, degrees) and yield its instruments."""
    from simulator.from_config import spec_from
    from simulator.rig import SimulatedRig

    with SimulatedRig(spec_from(rig), start=start) as sim:
        link = sim.open_link(options=dynamixel_options(rig))
        assert sim.camera is not None
        target = sim.reference if rig.file.reference.kind == "simulated" else None
        yield Instruments(link, sim.camera, sim.clock, target, sim.flat_source)


SIMULATED = RigBackend(
    open=open_simulated, addressing="id", needs_port=False, default_axes=True, cameras=("simulated",),
    references=("simulated",),
)  # fmt: skip
