"""The interface every motion link satisfies; the runner knows only this."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol, runtime_checkable

from model.errors import HardwareFault

Pose = Mapping[str, float]
"""Joint angles in degrees keyed by axis name."""


class LinkError(HardwareFault, RuntimeError):
    """A link failed in a way the caller should see: names the device, axis and what went wrong."""


class MoveTimeout(LinkError, TimeoutError):
    """Axes did not reach their targets within the timeout; carries the last positions read."""

    def __init__(self, message: str, positions_deg: Mapping[str, float]) -> None:
        super().__init__(message)
        self.positions_deg = dict(positions_deg)


@runtime_checkable
class MotionLink(Protocol):
    """Moves a set of axes to a pose and reports where they actually are (degrees)."""

    def move_to(self, pose: Pose) -> None:
        """Start a move of every named axis to its target in degrees (limits checked first)."""
        ...

    def wait_in_position(self, timeout_s: float) -> dict[str, float]:
        """Poll until every moving axis is within tolerance; return actual positions in degrees."""
        ...

    def read_positions(self) -> dict[str, float]:
        """Actual joint angles in degrees of every axis."""
        ...

    def stop(self) -> None:
        """Halt all motion now, keeping the device powered and holding."""
        ...

    def shutdown(self, keep_torque: bool = False) -> None:
        """Stop, leave the hardware safe (torque off / controller idle; ``keep_torque`` holds) and release the port."""
        ...


@runtime_checkable
class HomingLink(Protocol):
    """A link whose controller can lose track of where its axes are (GRBL after a reset), and finds out by homing."""

    def ensure_position_known(self) -> None:
        """Home unless the position is known (or refuse, saying why, where the controller cannot home)."""
        ...


@runtime_checkable
class ScanLink(Protocol):
    """A link that can run its axes at a chosen constant speed (continuous scans: ``rig.run.measuring.scan``)."""

    def set_speed(self, speeds_deg_s: Mapping[str, float] | None) -> dict[str, float]:
        """Cap the named axes' speed (deg/s of joint) for the moves that follow (None: back to each axis's top
        speed); the speeds the device actually runs at, after its own quantisation."""
        ...

    def stops_at(self, pose: Pose) -> dict[str, float]:
        """The joint angles (deg) the named axes come to rest at when sent ``pose`` (deg): each target rounded to
        the device's whole counts or steps, which may fall short of it."""
        ...
