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

import dataclasses
import math
import tempfile
import threading
from collections.abc import Hashable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from acquisition.board import ChArUcoBoard
from acquisition.noise import SensorNoise
from model.base import Model
from model.errors import GonioError
from model.lambert import Lambert
from model.mitsuba.materials import MitsubaMaterial, to_mitsuba
from rig.instrument.alignment import Alignment, aligned_pose
from rig.instrument.axis import Axis
from rig.instrument.clock import Clock, ManualClock, ScaledClock
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Joints, world_pose
from rig.instrument.links.dynamixel import DynamixelLink, DynamixelOptions
from rig.instrument.sample_surface import FLAT, SampleShape
from rig.run.config.files import default_axes
from simulator.camera.pixels import PixelResponse
from simulator.camera.simulated import CameraOptics, SensorPatch, SimulatedCamera
from simulator.camera.view import SimulatedFlatSource, roi_patch
from simulator.dynamixel.bus import VirtualDynamixelBus
from simulator.render.renderer import RadianceRenderer
from simulator.render.spec import CameraSpec, LightSpec

_ACTIVE_LOCK = threading.Lock()
_active: list[SimulatedRig] = []


class SimulatedRigError(GonioError, RuntimeError):
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
        Albedo of the Lambertian reference tile that ``rig.run.backends.reference`` swaps in for the sample.
    light_drift_per_s:
        Relative change of the light's intensity per second of rig time (0: a stable lamp), for drift tests.
    misalignment:
        The rig as it is built (joint zeros, the sample's wedge and offset): frames are rendered from the
        true pose (``rig.instrument.alignment.aligned_pose``), while the ROI is the one the controller
        would pick for the drawn pose. The controller is not told (it finds them by calibration).
    stray_light_counts_s:
        Ambient light reaching every pixel, in counts per second at gain 1 (not in dark frames).
    lamp_drift, lamp_warmup_s:
        A warming lamp: intensity times 1 + lamp_drift (1 - exp(-t / lamp_warmup_s)) at rig time t (s).
    settle_ticks:
        Each servo's load rests anywhere within this many encoder counts around its reading
        (``simulator.dynamixel.faults.ServoMechanics.settle_ticks``; 1: a real servo).
    backlash_deg:
        Play in every joint's gears, degrees of joint: the encoder (or GRBL's step count) does not see it, and the
        load lags the motor by half of it behind the direction the joint was last driven in.
    camera_output:
        "linear" (demosaiced counts), "raw" (a CFA mosaic) or "dng" (a mosaic written as a DNG file and read
        back through rawpy, the path a real camera's RAW files take); see ``simulator.camera.simulated``.
    response:
        The sensor's hidden vignetting, pixel response non-uniformity and non-linearity.
    dng_dir:
        Where "dng" frames are written and kept; None: a temporary folder, each file removed once read.
    sample_shape:
        The sample's surface (``[sample]``): flat, or a sphere or cylinder rendered as such. The reference tile
        and the calibration board swapped in for it are flat whatever it is.
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
    misalignment: Alignment = field(default_factory=Alignment)
    stray_light_counts_s: float = 0.0
    lamp_drift: float = 0.0
    lamp_warmup_s: float = 600.0
    settle_ticks: float = 0.0
    backlash_deg: float = 0.0
    camera_output: Literal["linear", "raw", "dng"] = "linear"
    response: PixelResponse = field(default_factory=PixelResponse)
    dng_dir: Path | None = None
    sample_shape: SampleShape = FLAT

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
        self.renderer = RadianceRenderer(self.spec.geometry, self.spec.light, self.spec.camera,
                                         shape=self.spec.sample_shape)  # fmt: skip
        self.bus: VirtualDynamixelBus | None = None
        self.camera: SimulatedCamera | None = None
        self.renders = 0
        self.reference = SimulatedReference(self)
        self.board = SimulatedBoard(self)
        self._showing: Hashable = self.spec.material
        self._reading: int | None = None
        self._shown: MitsubaMaterial | dict[str, Any] = self.material
        self._surface: SampleShape = self.spec.sample_shape  # what is in view: the sample's, or a flat swap-in
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
                seed=self.spec.seed, fixed_pattern_dn=self.spec.fixed_pattern_dn, state_key=self.state_key,
                stray_counts_per_s=self.spec.stray_light_counts_s,
                camera_id=f"gonio simulated camera ({self.spec.material.__class__.__name__}, {self.material.plugin})",
                kind="linear" if self.spec.camera_output == "linear" else "raw", response=self.spec.response,
                dng_dir=dng_dir if self.spec.camera_output == "dng" else None, keep_dng=self.spec.dng_dir is not None,
                moving=self.moving,
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
        for a in self.axes:
            mechanics = bus.servo(int(a.address)).mechanics
            mechanics.settle_ticks = self.spec.settle_ticks
            mechanics.backlash_ticks = self.spec.backlash_deg * a.units_per_joint_degree
        bus.start()
        self.bus = bus

    def physical_units(self, axis: Axis) -> float:
        """Where ``axis``'s joint physically stands now, in device units (servo ticks, backlash included)."""
        if self.bus is None:
            raise SimulatedRigError("the simulated rig is not running")
        return self.bus.servo(int(axis.address)).physical_position_ticks()

    def moving(self) -> bool:
        """Whether any joint is mid-move now (a frame taken then is blurred along the motion)."""
        return self.bus is not None and any(self.bus.servo(int(a.address)).state().profile_ongoing for a in self.axes)

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
            self._surface = FLAT
        else:
            self._showing, self._shown = self.spec.material, self.material
            self._surface = self.spec.sample_shape

    def show_material(self, key: Hashable, material: dict[str, Any]) -> None:
        """Put any Mitsuba material in view in place of the sample (``key`` names it for caches and noise)."""
        self._reading = None
        self._showing, self._shown = key, material
        self._surface = FLAT  # a board or tile swapped in for the sample is flat

    def state_key(self) -> tuple[object, ...]:
        """What the camera's noise stream is drawn for: where the joints stand, what is in view, which reading."""
        ticks = tuple(round(self.physical_units(a), 3) for a in self.axes)
        key: tuple[object, ...] = (ticks, repr(self._showing))
        if self.flat_source.state != "off":
            key = (*key, self.flat_source.state)
        return key if self._reading is None else (*key, self._reading)

    def radiance_now(
        self, full_frame: bool = False, crop: tuple[int, int, int, int] | None = None
    ) -> npt.NDArray[np.float64]:
        """Radiance (W/(m^2 sr)) the camera sees now (the ROI, a ``crop`` box, or the whole frame), from the servos."""
        return self._radiance(full_frame, crop)

    def lamp_factor(self) -> float:
        """The lamp's intensity now relative to its cold intensity (drift and warm-up at rig time)."""
        t = self.clock.now()
        warm = self.spec.lamp_drift * -math.expm1(-t / self.spec.lamp_warmup_s) if self.spec.lamp_drift else 0.0
        return (1.0 + self.spec.light_drift_per_s * t) * (1.0 + warm)

    def _patch(self, full_frame: bool = False, like: SensorPatch | None = None) -> SensorPatch:
        """What the camera sees: the flat-field source in use, else the ROI's window (``like``'s, for sub-exposures)."""
        if self.flat_source.state != "off":
            return self.flat_source.patch()
        if full_frame or (like is not None and like.sensor is None):
            return SensorPatch(self._radiance(full_frame=True))
        if like is not None:
            (x0, y0), (h, w) = like.origin_xy, like.radiance.shape[:2]
            return dataclasses.replace(like, radiance=self._radiance(crop=(x0, y0, x0 + w, y0 + h)))
        # The controller picks its ROI for the rig as drawn; the scene rendered is what the rig really is.
        box = self.renderer.roi(world_pose(self.spec.geometry, self.joints_now()))
        return roi_patch(lambda crop: self._radiance(crop=crop), box, self.spec.camera.resolution,
                         self.spec.camera_output == "dng")  # fmt: skip

    def _radiance(
        self, full_frame: bool = False, crop: tuple[int, int, int, int] | None = None
    ) -> npt.NDArray[np.float64]:
        joints = self.joints_now()
        true = aligned_pose(self.spec.geometry, joints, self.spec.misalignment)
        if crop is None and not full_frame:
            crop = self.renderer.roi(world_pose(self.spec.geometry, joints))
        self.renders += 1
        # The render's own sampling noise is part of each rig's noise: seeded like the sensor's.
        image = self.renderer.render(true, self._shown, crop=crop, key=repr(self._showing), seed=self.spec.seed,
                                     shape=self._surface)  # fmt: skip
        factor = self.lamp_factor()
        return np.asarray(image, dtype=np.float64) * factor if factor != 1.0 else np.asarray(image, dtype=np.float64)


class SimulatedBoard:
    """The simulated rig's calibration board: a ChArUco pattern under a glossy coat; satisfies BoardTarget."""

    def __init__(self, rig: SimulatedRig) -> None:
        self._rig = rig
        self._dir: tempfile.TemporaryDirectory[str] | None = None

    @property
    def description(self) -> str:
        """The board's material."""
        return "simulated ChArUco board under a GGX-rough clear coat (roughplastic)"

    def present_board(self, board: ChArUcoBoard, alpha: float) -> None:
        """Swap the board in for the sample (textured diffuse print under a coat of GGX ``alpha``, ior 1.5)."""
        if self._dir is None:
            self._dir = tempfile.TemporaryDirectory(prefix="gonio-board-")
        path = Path(self._dir.name) / f"board-{abs(hash((board, alpha)))}.png"
        if not path.exists():
            _write_board_texture(path, board, self._rig.spec.geometry)
        material = {
            "type": "roughplastic", "distribution": "ggx", "alpha": float(alpha), "int_ior": 1.5,
            "diffuse_reflectance": {"type": "bitmap", "filename": str(path), "raw": True, "filter_type": "bilinear"},
        }  # fmt: skip
        self._rig.show_material(("board", board, alpha), material)

    def withdraw_board(self) -> None:
        """Put the sample back."""
        self._rig.show(False)


def _write_board_texture(path: Path, board: ChArUcoBoard, geometry: RigGeometry, px_per_mm: float = 20.0) -> None:
    """The sample's face as a texture: the board centred on it, white around, printed black at 4 % reflectance."""
    import cv2

    printed = board.image(px_per_mm)
    w, h = round(geometry.sample_width_m * 1e3 * px_per_mm), round(geometry.sample_height_m * 1e3 * px_per_mm)
    if printed.shape[0] > min(w, h):
        raise SimulatedRigError(f"the {board.width_mm:g} mm board does not fit the {geometry.sample_width_m * 1e3:g} x "
                                f"{geometry.sample_height_m * 1e3:g} mm sample")  # fmt: skip
    face = np.full((h, w), 255, dtype=np.uint8)
    y0, x0 = (h - printed.shape[0]) // 2, (w - printed.shape[1]) // 2
    face[y0 : y0 + printed.shape[0], x0 : x0 + printed.shape[1]] = printed
    # Mitsuba's rectangle maps texture rows to its local +y: flipped, the print reads upright from the front.
    ink = (10 + face.astype(np.float64)[::-1] * (217 - 10) / 255).astype(np.uint8)
    cv2.imwrite(str(path), ink)


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
