"""gonio's hardware backends as registered in ``gonio.backends``: a Dynamixel bus or a GRBL controller.

Each opens its link on ``[link] port`` with the rig's axes, the camera that ``[camera] backend`` names
(through ``gonio.cameras``), and for ``[reference] kind = "manual"`` a prompt that asks a person to place
the tile. Time is real (``SystemClock``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from acquisition.cameras.registry import camera_backend
from acquisition.frame import Camera
from rig.instrument.clock import Clock, SystemClock
from rig.instrument.links.base import MotionLink
from rig.instrument.links.dynamixel import DynamixelOptions
from rig.run import registry
from rig.run.backends.base import Instruments, RigBackend, StartPose
from rig.run.backends.bounded_camera import BoundedCamera
from rig.run.backends.flat_source import ManualFlatSource
from rig.run.backends.reference import ManualBoard, ManualReference, ReferenceTarget
from rig.run.config.files import ConfigError, RigConfig


def dynamixel_options(rig: RigConfig) -> DynamixelOptions:
    """The Dynamixel link's options from the rig's [link] table."""
    f = rig.file.link
    return DynamixelOptions(poll_interval_s=f.poll_interval_s, allow_reboot=f.allow_reboot)


def open_camera(rig: RigConfig, clock: Clock) -> Camera:
    """The camera ``[camera] backend`` names, opened with the validated ``[camera]`` table."""
    cam = rig.file.camera
    providers = [n for n in registry.names() if cam.backend in registry.load(n).cameras]
    if providers:
        raise ConfigError(f"{rig.path}: camera.backend = {cam.backend!r} needs the {providers[0]} link")
    return camera_backend(cam.backend).open(cam.model_dump(), clock)


def _dynamixel_link(rig: RigConfig, clock: Clock) -> MotionLink:
    from rig.instrument.links.dynamixel import DynamixelLink

    f = rig.file.link
    assert f.port is not None
    return DynamixelLink.open(f.port, rig.axes, baudrate=f.baudrate, retries=f.retries, clock=clock,
                              latency_timer_ms=f.latency_timer_ms, options=dynamixel_options(rig))  # fmt: skip


def _grbl_link(rig: RigConfig, clock: Clock) -> MotionLink:
    from rig.instrument.links.grbl import GrblLink

    f = rig.file.link
    assert f.port is not None
    # A run never assumes where the axes are: it homes (or refuses to move without homing, $22=0).
    return GrblLink(f.port, rig.axes, baudrate=f.baudrate, clock=clock, require_home=True)


@contextlib.contextmanager
def _instruments(rig: RigConfig, link: MotionLink, clock: Clock) -> Iterator[Instruments]:
    # Bounded here, not only in the runner, so that closing a camera that hung cannot hang the exit.
    camera = BoundedCamera(open_camera(rig, clock), slack_s=rig.file.camera.capture_timeout_s)
    manual: ReferenceTarget | None = ManualReference() if rig.file.reference.kind == "manual" else None
    try:
        yield Instruments(link, camera, clock, manual, ManualFlatSource(), board=ManualBoard())
    finally:
        camera.close()


def _open_dynamixel(rig: RigConfig, start: StartPose | None = None) -> contextlib.AbstractContextManager[Instruments]:
    # Real axes stand wherever they stand: ``start`` is for simulations.
    clock = SystemClock()
    return _instruments(rig, _dynamixel_link(rig, clock), clock)


def _open_grbl(rig: RigConfig, start: StartPose | None = None) -> contextlib.AbstractContextManager[Instruments]:
    clock = SystemClock()
    return _instruments(rig, _grbl_link(rig, clock), clock)


DYNAMIXEL = RigBackend(open=_open_dynamixel, addressing="id")
GRBL = RigBackend(open=_open_grbl, addressing="letter", coordinated=True)
