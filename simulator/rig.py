"""The simulated rig: a virtual Dynamixel bus on a pty and a rendered camera that watches what the servos do.

``SimulatedRig(spec)`` (a context manager) starts the virtual servos, one per joint of the rig geometry,
and a ``SimulatedCamera`` whose radiance comes from Mitsuba, rendered from the pose the servos *physically*
hold (present position plus backlash) through the kinematics' world placement. A controller drives it
exactly like hardware: open ``rig.port`` with a ``DynamixelLink`` (``rig.open_link()`` does so) and take
frames from ``rig.camera``. Servo errors therefore reach the images the way they would on a real rig.

Time: with ``time_scale=None`` (the default) the bus, the link and the camera share one ``ManualClock``,
so polls and exposures advance simulated time instantly; a number runs a ``ScaledClock`` that factor
faster than real time, for external clients. Only one simulated rig runs per process at a time.
"""

from __future__ import annotations

import tempfile
import threading
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import numpy.typing as npt

from acquisition.noise import SensorNoise
from model.base import Model
from model.lambert import Lambert
from model.mitsuba.materials import MitsubaMaterial, to_mitsuba
from rig.instrument.axis import Axis
from rig.instrument.clock import Clock, ManualClock, ScaledClock
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Joints, RigPose, world_pose
from rig.instrument.links.dynamixel import DynamixelLink, DynamixelOptions
from rig.run.config import default_axes
from simulator.camera.pixels import PixelResponse
from simulator.camera.simulated import CameraOptics, SensorPatch, SimulatedCamera
from simulator.camera.view import SimulatedFlatSource, roi_patch
from simulator.dynamixel.bus import VirtualDynamixelBus
from simulator.render.renderer import RadianceRenderer
from simulator.render.spec import CameraSpec, LightSpec

_ACTIVE_LOCK = threading.Lock()
_active: list[SimulatedRig] = []


class SimulatedRigError(RuntimeError):
    """The simulated rig cannot start (one is already running in this process, or the spec is unusable)."""


@dataclass(frozen=True)
class SimRigSpec:
    """Everything the simulated rig is made of.

    Parameters
    ----------
    geometry:
        The rig (layout, arm radii, sample size, limits); the scene is placed from its kinematics.
    material:
        The sample's BRDF (any model of the model module).
    light, camera:
        The emitter on the light arm (intensity in W/sr) and the camera on the camera arm.
    noise, optics:
        The sensor's noise and range, and what turns radiance into counts per second.
    axes:
        The joints' servos; ``None`` gives ``default_axes(geometry)``.
    baudrate:
        The virtual bus's baud rate.
    fixed_pattern_dn:
        RMS of the camera's per-pixel offset in counts.
    time_scale:
        ``None`` for simulated time (``ManualClock``), or a factor of real time (``ScaledClock``).
    seed:
        Seeds the camera's noise and the servos' random faults. The noise of each frame is drawn from the
        seed, the servos' physical positions and the material in view, so it does not depend on what the
        rig did before (a resumed run sees what an uninterrupted one saw).
    reference_albedo:
        Albedo of the Lambertian reference tile that ``rig.run.reference`` swaps in for the sample.
    light_drift_per_s:
        Relative change of the light's intensity per second of rig time (0: a stable lamp), for drift tests.
    camera_output:
        "linear" (demosaiced counts), "raw" (a CFA mosaic) or "dng" (a mosaic written as a DNG file and read
        back through rawpy, the path a real camera's RAW files take); see ``simulator.camera.simulated``.
    response:
        The sensor's hidden vignetting, pixel response non-uniformity and non-linearity.
    dng_dir:
        Where "dng" frames are written and kept; None: a temporary folder, each file removed once read.
    """

    geometry: RigGeometry = field(default_factory=RigGeometry)
    material: Model = field(default_factory=lambda: Lambert(0.5))
    light: LightSpec = field(default_factory=lambda: LightSpec(intensity=1.0))
    camera: CameraSpec = field(default_factory=CameraSpec)
    noise: SensorNoise = field(default_factory=SensorNoise)
    optics: CameraOptics = field(default_factory=CameraOptics)
    axes: tuple[Axis, ...] | None = None
    baudrate: int = 1_000_000
    fixed_pattern_dn: float = 0.0
    time_scale: float | None = None
    seed: int = 0
    reference_albedo: float | tuple[float, float, float] = 0.99
    light_drift_per_s: float = 0.0
    camera_output: Literal["linear", "raw", "dng"] = "linear"
    response: PixelResponse = field(default_factory=PixelResponse)
    dng_dir: Path | None = None

    def resolved_axes(self) -> tuple[Axis, ...]:
        """The axes, defaulted from the geometry, checked to cover every joint of the layout."""
        axes = self.axes if self.axes is not None else default_axes(self.geometry)
        names = {a.name for a in axes}
        missing = [j for j in self.geometry.joint_names if j not in names]
        if missing:
            raise SimulatedRigError(f"SimRigSpec.axes lacks joints {missing} of layout {self.geometry.layout!r}")
        return tuple(axes)


class SimulatedRig:
    """A running simulated rig; see the module docstring."""

    def __init__(self, spec: SimRigSpec | None = None, *, start: Mapping[str, float] | None = None) -> None:
        self.spec = spec or SimRigSpec()
        self._start = dict(start or {})
        unknown = sorted(set(self._start) - set(self.spec.geometry.joint_names))
        if unknown:
            raise SimulatedRigError(f"start pose names joints {unknown} the {self.spec.geometry.layout} rig lacks")
        self.axes = self.spec.resolved_axes()
        self.clock: Clock = ManualClock() if self.spec.time_scale is None else ScaledClock(self.spec.time_scale)
        self.material: MitsubaMaterial = to_mitsuba(self.spec.material)
        self.renderer = RadianceRenderer(self.spec.geometry, self.spec.light, self.spec.camera)
        self.bus: VirtualDynamixelBus | None = None
        self.camera: SimulatedCamera | None = None
        self.renders = 0
        self.reference = SimulatedReference(self)
        self._showing: Model = self.spec.material
        self._reading: int | None = None
        self._shown: MitsubaMaterial = self.material
        self._reference_material = to_mitsuba(Lambert(self.spec.reference_albedo))
        self.flat_source = SimulatedFlatSource(self.spec.camera.resolution, self.spec.noise, self.spec.optics)
        self._dng_tmp: tempfile.TemporaryDirectory[str] | None = None

    def start(self) -> SimulatedRig:
        """Bring up the virtual bus and the camera; refuses if another simulated rig runs in this process."""
        with _ACTIVE_LOCK:
            if _active:
                raise SimulatedRigError(
                    f"a simulated rig is already running in this process (bus on {_active[0].port}); "
                    "close it first"
                )
            self._start_axes()
            dng_dir = self.spec.dng_dir
            if self.spec.camera_output == "dng" and dng_dir is None:
                self._dng_tmp = tempfile.TemporaryDirectory(prefix="gonio-sim-dng-")
                dng_dir = Path(self._dng_tmp.name)
            self.camera = SimulatedCamera(
                self._patch, noise=self.spec.noise, optics=self.spec.optics, clock=self.clock,
                seed=self.spec.seed, fixed_pattern_dn=self.spec.fixed_pattern_dn, state_key=self._state_key,
                camera_id=f"gonio simulated camera ({self.spec.material.__class__.__name__}, {self.material.plugin})",
                kind="linear" if self.spec.camera_output == "linear" else "raw", response=self.spec.response,
                dng_dir=dng_dir if self.spec.camera_output == "dng" else None, keep_dng=self.spec.dng_dir is not None,
            )  # fmt: skip
            _active.append(self)
        return self

    def start_pose(self) -> dict[str, float]:
        """Joint angles (degrees) the axes stand at when the rig starts: the rest pose (0), or ``start``."""
        return {a.name: self._start.get(a.name, min(max(0.0, a.min_deg), a.max_deg)) for a in self.axes}

    def _start_axes(self) -> None:
        """Bring up what moves the joints: one virtual servo per joint, at ``start_pose()``."""
        ids = [int(a.address) for a in self.axes]
        at = self.start_pose()
        positions = {int(a.address): round(a.to_units(at[a.name])) for a in self.axes}
        bus = VirtualDynamixelBus(ids, self.spec.baudrate, self.clock, seed=self.spec.seed, positions=positions)
        bus.start()
        self.bus = bus

    def physical_units(self, axis: Axis) -> float:
        """Where ``axis``'s joint physically stands now, in device units (servo ticks, backlash included)."""
        if self.bus is None:
            raise SimulatedRigError("the simulated rig is not running")
        return self.bus.servo(int(axis.address)).physical_position_ticks()

    def __enter__(self) -> SimulatedRig:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Stop the bus and the camera; safe to call twice."""
        with _ACTIVE_LOCK:
            if self.camera is not None:
                self.camera.close()
            if self.bus is not None:
                self.bus.close()
            if self._dng_tmp is not None:
                self._dng_tmp.cleanup()
                self._dng_tmp = None
            if self in _active:
                _active.remove(self)

    @property
    def port(self) -> str:
        """Device path of the virtual bus."""
        if self.bus is None:
            raise SimulatedRigError("the simulated rig is not running: use it as a context manager or call start()")
        return self.bus.port

    def open_link(self, options: DynamixelOptions | None = None, latency_timer_ms: float = 60.0) -> DynamixelLink:
        """A Dynamixel link to this rig's bus on its clock (the controller side of the simulation)."""
        return DynamixelLink.open(
            self.port, self.axes, baudrate=self.spec.baudrate, clock=self.clock, options=options,
            latency_timer_ms=latency_timer_ms,
        )  # fmt: skip

    def joints_now(self) -> Joints:
        """Joint angles in degrees the servos physically hold now (backlash included)."""
        return Joints.from_dict({a.name: a.to_degrees(self.physical_units(a)) for a in self.axes})

    def show(self, reference: bool, reading: int | None = None) -> None:
        """Put the reference tile (True) or the sample (False) in view of the camera.

        ``reading`` names the reference reading (the runner's slot). Noise is drawn per state, and the tile at
        the reference pose is the same state every time: without it every reference reading of a run would
        repeat one noise draw, and the run's calibration could never average down. A slot, not a count of
        presentations, keeps a resumed run's readings equal to an uninterrupted run's.
        """
        self._reading = reading if reference else None
        if reference:
            self._showing, self._shown = Lambert(self.spec.reference_albedo), self._reference_material
        else:
            self._showing, self._shown = self.spec.material, self.material

    def _state_key(self) -> tuple[object, ...]:
        ticks = tuple(round(self.physical_units(a), 3) for a in self.axes)
        key: tuple[object, ...] = (ticks, repr(self._showing))
        if self.flat_source.state != "off":
            key = (*key, self.flat_source.state)
        return key if self._reading is None else (*key, self._reading)

    def radiance_now(self, full_frame: bool = False) -> npt.NDArray[np.float64]:
        """Radiance (W/(m^2 sr)) the camera sees now (the ROI, or the whole frame), from the servos' physical pose."""
        return self._radiance(full_frame)

    def _patch(self) -> SensorPatch:
        """What the camera sees: the flat-field source while one is in use, else the rendered ROI's window."""
        if self.flat_source.state != "off":
            return self.flat_source.patch()
        pose = world_pose(self.spec.geometry, self.joints_now())
        return roi_patch(lambda box: self._radiance(crop=box, pose=pose), self.renderer.roi(pose),
                         self.spec.camera.resolution, self.spec.camera_output == "dng")  # fmt: skip

    def _radiance(
        self, full_frame: bool = False, crop: tuple[int, int, int, int] | None = None, pose: RigPose | None = None
    ) -> npt.NDArray[np.float64]:
        pose = pose if pose is not None else world_pose(self.spec.geometry, self.joints_now())
        if crop is None and not full_frame:
            crop = self.renderer.roi(pose)
        self.renders += 1
        image = self.renderer.render(pose, self._shown, crop=crop, key=repr(self._showing))
        if self.spec.light_drift_per_s:
            return np.asarray(image, dtype=np.float64) * (1.0 + self.spec.light_drift_per_s * self.clock.now())
        return np.asarray(image, dtype=np.float64)


class SimulatedReference:
    """The simulated rig's flip-in reference tile: swaps the rendered material; satisfies ReferenceTarget."""

    def __init__(self, rig: SimulatedRig) -> None:
        self._rig = rig

    @property
    def description(self) -> str:
        """The tile and its albedo."""
        return f"simulated Lambertian tile, albedo {self._rig.spec.reference_albedo!r}"

    def present(self, slot: int) -> None:
        """Swap the reference tile in for the run's reading ``slot``."""
        self._rig.show(True, reading=slot)

    def withdraw(self) -> None:
        """Swap the sample back in."""
        self._rig.show(False)
