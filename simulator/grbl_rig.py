"""The simulated rig driven by a virtual GRBL 1.1 controller instead of Dynamixel servos.

``SimulatedGrblRig(spec)`` is a :class:`simulator.rig.SimulatedRig` whose joints are stepper axes of one
``simulator.grbl.VirtualGrbl`` on a pseudo-terminal (``Axis.address`` = axis letter, GRBL's unit = one motor
degree, as ``rig.instrument.links.grbl`` defines). The rendered camera watches where the steppers
physically stand, which is not always what GRBL reports: opening the port resets an Arduino-based GRBL,
which then counts from 0 wherever the axes are, exactly as on a real rig. Only homing makes the report
true again, which is why a run's ``GrblLink`` homes before it moves (``require_home``).

The controller comes up as a lab would have commissioned it for the axes (:func:`grbl_settings`): steps per
motor degree, rates and accelerations from the axes, homing on (``$22=1``, each switch at machine 0 and
the axes' ``zero_offset_deg`` there), travel covering every joint's range, soft limits where the ranges
fit GRBL's machine space, hard limits armed (they trip only when a test injects it).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

from rig.instrument.axis import Axis
from rig.instrument.links.grbl import AXIS_LETTERS, GrblLink
from rig.run.config.files import GRBL_PULLOFF_DEG, default_grbl_axes
from simulator.grbl.controller import VirtualGrbl
from simulator.grbl.server import GrblPtyServer
from simulator.rig import SimRigSpec, SimulatedRig, SimulatedRigError

#: Homing seek and locate rates ($25, $24) in motor degrees per minute.
HOMING_SEEK_DEG_MIN = 1800.0
HOMING_FEED_DEG_MIN = 120.0


def _coordinate(axis: Axis, joint_deg: float) -> float:
    """GRBL machine coordinate (motor degrees) of a joint angle, unchecked (a start pose may sit on a limit)."""
    return axis.direction * (joint_deg - axis.zero_offset_deg) * axis.gear_ratio


def grbl_settings(axes: tuple[Axis, ...]) -> dict[int, float]:
    """GRBL ``$`` settings of a controller commissioned for ``axes`` (see the module docstring)."""
    settings: dict[int, float] = {22: 1.0, 21: 1.0, 23: 0.0, 24: HOMING_FEED_DEG_MIN, 25: HOMING_SEEK_DEG_MIN,
                                  27: GRBL_PULLOFF_DEG}  # fmt: skip
    fits = True
    for axis in axes:
        i = AXIS_LETTERS.index(str(axis.address))
        ends = (_coordinate(axis, axis.min_deg), _coordinate(axis, axis.max_deg))
        fits = fits and max(ends) <= 0.0
        settings[100 + i] = axis.units_per_degree
        settings[110 + i] = axis.max_speed_deg_s * axis.gear_ratio * 60.0
        settings[120 + i] = axis.max_accel_deg_s2 * axis.gear_ratio
        settings[130 + i] = max(abs(e) for e in ends) + 2.0 * GRBL_PULLOFF_DEG
    # Soft limits keep targets in [-$130, 0]: only where every joint's range maps there.
    settings[20] = 1.0 if fits else 0.0
    return settings


class SimulatedGrblRig(SimulatedRig):
    """A simulated rig whose joints a virtual GRBL controller moves; see the module docstring."""

    def __init__(self, spec: SimRigSpec | None = None, *, start: Mapping[str, float] | None = None) -> None:
        spec = spec or SimRigSpec()
        if spec.axes is None:  # one stepper per joint, as a GRBL rig file without [axes] gets
            spec = dataclasses.replace(spec, axes=default_grbl_axes(spec.geometry))
        super().__init__(spec, start=start)
        for axis in self.axes:
            if not (isinstance(axis.address, str) and axis.address in AXIS_LETTERS):
                raise SimulatedRigError(f"axis {axis.name!r}: address {axis.address!r} is not a GRBL axis letter")
        self.grbl: GrblPtyServer | None = None

    @property
    def controller(self) -> VirtualGrbl:
        """The virtual GRBL (for inspection and fault injection)."""
        if self.grbl is None:
            raise SimulatedRigError("the simulated GRBL rig is not running")
        return self.grbl.controller

    def _start_axes(self) -> None:
        indices = [AXIS_LETTERS.index(str(a.address)) for a in self.axes]
        letters = AXIS_LETTERS[: max(indices) + 1]
        at = self.start_pose()
        # Where the steppers physically stand at power-up, whole steps, in homed machine coordinates.
        start = {str(a.address): round(_coordinate(a, at[a.name]) * a.units_per_degree) / a.units_per_degree
                 for a in self.axes}  # fmt: skip
        controller = VirtualGrbl(self.clock, axes=letters, settings=grbl_settings(self.axes), start_position=start)
        self.grbl = GrblPtyServer(controller)
        self.grbl.start()

    def physical_units(self, axis: Axis) -> float:
        """Where ``axis``'s joint physically stands now, in steps (what a camera sees, whatever GRBL reports).

        Gear play (``backlash_deg``) leaves the load half of it behind the motor's last direction of motion.
        """
        letter = str(axis.address)
        coordinate = self.controller.physical_position[letter]
        if self.spec.backlash_deg:
            lag = 0.5 * self.spec.backlash_deg * axis.gear_ratio  # motor degrees: GRBL's unit
            coordinate -= self.controller.driven_direction[letter] * lag
        return coordinate * axis.units_per_degree

    def moving(self) -> bool:
        """Whether the steppers run now (a move, homing, or a feed hold still slowing down): a frame taken then is
        blurred along the motion."""
        return self.grbl is not None and self.controller.stepping

    @property
    def port(self) -> str:
        """Device path of the virtual controller's serial port."""
        if self.grbl is None:
            raise SimulatedRigError("the simulated rig is not running: use it as a context manager or call start()")
        return self.grbl.port

    def open_link(self, **options: Any) -> GrblLink:  # type: ignore[override]  # GRBL's options, not Dynamixel's
        """A GRBL link to this rig's controller on its clock, homing before it moves, as a run opens one."""
        options.setdefault("require_home", True)
        return GrblLink(self.port, self.axes, clock=self.clock, **options)

    def close(self) -> None:
        """Stop the camera and the controller; safe to call twice."""
        super().close()
        if self.grbl is not None:
            self.grbl.stop()
