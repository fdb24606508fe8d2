"""The rehearsal: one simulated rig served to gonio's real backends, as a lab's hardware would be.

``gonio sim rig`` brings up the virtual servos (a Dynamixel bus) or the virtual GRBL controller of a rig on a
pseudo-terminal, and in place of the camera a *tethering program*: it writes the sensor's whole frames as
DNG files into a hot folder, rendered by Mitsuba from the pose the virtual axes physically hold. gonio then
runs a hardware rig file (``[link] kind = "dynamixel"`` or ``"grbl"`` on that port, ``[camera] backend =
"folder"`` on that folder) exactly as it runs a real rig: ``dynamixel_sdk`` or pyserial on the pty, the
folder camera reading DNG files through rawpy.

The rig served is the rig file's own: a hardware file's geometry, axes (ids or letters, gear ratios,
zeros, limits) and camera ROI, and its ``[simulation]`` table if it has one (material, sensor,
misalignment; the defaults otherwise); or a simulated rig file (``examples/rig_misaligned.toml``) on the
link ``--link`` names, for which :func:`controller_rig_text` writes the hardware rig file a controller
uses for it. A hardware file's sensor is the smallest whose centre is its ROI's centre (the camera is aimed
at the sample): ``[2000, 1300, 2200, 1500]`` gives 4200 x 2800 pixels.

What shoots: a request the folder camera leaves (:mod:`acquisition.cameras.shot_request`, when the rig file
has no trigger), or ``capture SECONDS`` typed on the rehearsal's input. Only a window around the ROI is
exposed while the sample or the tile is in view (a run reads nothing else); the rest of the frame holds the
sensor's dark level under one fixed draw of read noise. With the board, the flat light or the lens cap in
place, the whole sensor is exposed (calibrations read whole frames).

What an operator does at a real rig is typed on the rehearsal's input too (:data:`SCENES`): ``scene tile``
puts the reference tile on the stage, ``scene board`` the ChArUco board, ``scene flat`` a uniform light
before the lens, ``scene dark`` the lens cap, ``scene sample`` the sample back.
"""

from __future__ import annotations

import dataclasses
import math
import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np
import numpy.typing as npt

from acquisition.board import ChArUcoBoard
from acquisition.cameras.shot_request import take_requests
from acquisition.frame import Frame
from model.errors import InputError
from rig.run.config.files import RigConfig
from simulator.camera.simulated import DNG_MIN_SIDE, SensorPatch, SimulatedCamera, window_around
from simulator.from_config import rig_from, spec_from
from simulator.render.spec import CameraSpec
from simulator.rig import SimRigSpec, SimulatedRig

Box = tuple[int, int, int, int]

#: What the operator can put in view: the sample, the reference tile, the calibration board, a uniform
#: light before the lens (camera calibration), the lens cap.
SCENES = ("sample", "tile", "board", "flat", "dark")
#: A hardware rig file without an ROI reads whole frames: a small sensor keeps each render quick.
SENSOR_WITHOUT_ROI = (64, 64)
#: The frames kept in the hot folder (the oldest go): a run of a thousand points would fill a disk.
KEEP_FRAMES = 32


class RehearsalError(InputError, ValueError):
    """The rig file cannot be rehearsed as given (a sensor size that does not hold the ROI, a link it lacks)."""


def rehearsal_link(rig: RigConfig, link: str | None) -> str:
    """The link the rehearsal serves: a hardware file's own, or ``link`` (default ``[simulation] link``)."""
    kind = rig.file.link.kind
    if kind in ("dynamixel", "grbl"):
        if link is not None and link != kind:
            raise RehearsalError(f"{rig.path}: link.kind = {kind!r}: --link {link} names another link than the file's")
        return kind
    if kind != "simulated":
        raise RehearsalError(f"{rig.path}: link.kind = {kind!r}: the rehearsal serves 'dynamixel' or 'grbl' links")
    return link or rig.file.simulation.link


def sensor_size(rig: RigConfig, resolution: tuple[int, int] | None = None) -> tuple[int, int]:
    """The rehearsal's sensor (width, height) in pixels: ``resolution``, or as the module docstring says."""
    cam = rig.file.camera
    if resolution is None:
        if cam.backend == "simulated":
            resolution = cam.resolution
        elif cam.roi is None:
            resolution = SENSOR_WITHOUT_ROI
        else:
            x0, y0, x1, y1 = cam.roi
            resolution = (x0 + x1 + (x0 + x1) % 2, y0 + y1 + (y0 + y1) % 2)
    w, h = resolution
    if cam.roi is not None and cam.backend != "simulated" and (cam.roi[2] > w or cam.roi[3] > h):
        raise RehearsalError(f"{rig.path}: camera.roi = {list(cam.roi)} does not fit a sensor of {w} x {h} pixels")
    return int(w), int(h)


def rehearsal_spec(rig: RigConfig, link: str, *, resolution: tuple[int, int] | None = None,
                   speed: float = 1.0) -> SimRigSpec:  # fmt: skip
    """The simulated rig of a rig file as the rehearsal serves it (time ``speed`` times real time)."""
    cam = rig.file.camera
    simulated = cam.backend == "simulated"
    camera = CameraSpec(resolution=sensor_size(rig, resolution), spp=cam.spp if simulated else 4,
                        variant=cam.variant if simulated else None)  # fmt: skip
    spec = spec_from(rig, camera=camera)
    axes = spec.axes if rig.file.link.kind != "simulated" or link == rig.file.simulation.link else None
    return dataclasses.replace(spec, time_scale=speed, axes=axes, camera_output="raw")


def rehearsal_rig(rig: RigConfig, link: str, spec: SimRigSpec) -> SimulatedRig:
    """The (unstarted) simulated rig on ``link``: virtual servos or a virtual GRBL controller."""
    file = rig.file.model_copy(update={"simulation": rig.file.simulation.model_copy(update={"link": link})})
    return rig_from(dataclasses.replace(rig, file=file), spec=spec)


def controller_roi(rig: RigConfig, sensor: tuple[int, int]) -> Box:
    """The ROI (pixels) a controller reads: a hardware file's own, else a centred box an eighth of the sensor."""
    if rig.file.camera.backend != "simulated" and rig.file.camera.roi is not None:
        x0, y0, x1, y1 = rig.file.camera.roi
        return (x0, y0, x1, y1)
    w, h = sensor
    side = max(2, min(w, h) // 8 // 2 * 2)
    x0, y0 = (w - side) // 2 // 2 * 2, (h - side) // 2 // 2 * 2
    return (x0, y0, x0 + side, y0 + side)


class Tether:
    """The rehearsal's camera end: shoots whole-sensor DNG frames into ``folder``; see the module docstring.

    ``roi`` is the box a run reads (None: whole frames always). Frames are named ``IMG_NNNNNN.dng``; only the
    newest ``keep`` are kept.
    """

    def __init__(self, sim: SimulatedRig, folder: Path, roi: Box | None, *, keep: int = KEEP_FRAMES) -> None:
        if keep < 2:
            raise RehearsalError(f"keep = {keep!r}: expected at least 2 frames (one being read, one being written)")
        self.sim = sim
        self.folder = folder
        self.roi = roi
        self.keep = keep
        self.scene = "sample"
        self.lock = threading.Lock()
        self.written: list[Path] = []
        # A camera's counter goes on across sessions: a name already in the folder is one a watcher has seen.
        self.shots = max((int(p.stem[4:]) for p in folder.glob("IMG_*.dng") if p.stem[4:].isdigit()), default=0)
        spec = sim.spec
        self.sensor = spec.camera.resolution
        self.camera = SimulatedCamera(
            self._patch, noise=spec.noise, optics=spec.optics, kind="raw", clock=sim.clock, seed=spec.seed,
            fixed_pattern_dn=spec.fixed_pattern_dn, state_key=sim.state_key,
            stray_counts_per_s=spec.stray_light_counts_s, response=spec.response,
            camera_id="gonio rehearsal camera (RAW)", min_exposure_s=1e-6, max_exposure_s=3600.0,
        )  # fmt: skip
        self._background: npt.NDArray[np.float32] | None = None
        self._client = 0

    def _patch(self, full_frame: bool = False) -> SensorPatch:
        sim = self.sim
        if sim.flat_source.state != "off":
            return sim.flat_source.patch()
        if self.roi is None or self.scene == "board":
            return SensorPatch(sim.radiance_now(full_frame=True), sensor=self.sensor)
        window = window_around(self.roi, self.sensor, DNG_MIN_SIDE)
        box = (window[0], window[1], window[2], window[3])
        return SensorPatch(sim.radiance_now(crop=box), origin_xy=(box[0], box[1]), sensor=self.sensor)

    def set_scene(self, scene: str, board: ChArUcoBoard | None = None, alpha: float = 0.01) -> None:
        """Put ``scene`` (one of :data:`SCENES`) in view, as an operator at the rig would."""
        if scene not in SCENES:
            raise RehearsalError(f"scene {scene!r}: expected one of {', '.join(SCENES)}")
        with self.lock:
            flat = self.sim.flat_source
            flat.restore()
            if scene == "tile":
                self.sim.show(True)
            elif scene == "board":
                self.sim.board.present_board(board or ChArUcoBoard(), alpha)
            else:
                self.sim.show(False)
                if scene == "flat":
                    flat.illuminate()
                elif scene == "dark":
                    flat.darken()
            self.scene = scene
            self.camera.restart_streams()

    def shoot(self, exposure_s: float, gain: float = 1.0) -> Path:
        """Expose one frame (seconds, linear gain) and write it as a DNG of the whole sensor; returns its path."""
        from acquisition.files.dng import write_dng  # here: tifffile loads when the first frame is written

        if not (math.isfinite(exposure_s) and exposure_s > 0):
            raise RehearsalError(f"exposure {exposure_s!r} s: expected a positive number of seconds")
        if not (math.isfinite(gain) and gain > 0):
            raise RehearsalError(f"gain {gain!r}: expected a positive number")
        with self.lock:
            self.camera.set_exposure(exposure_s, gain)
            frame = self._whole(self.camera.capture())
            self.shots += 1
            path = self.folder / f"IMG_{self.shots:06d}.dng"
            self.folder.mkdir(parents=True, exist_ok=True)
            write_dng(path, frame, exposure_s=frame.exposure_s, iso=100.0 * frame.gain, camera_id=self.camera.identity)
            self.written.append(path)
            for old in self.written[: -self.keep]:
                old.unlink(missing_ok=True)
            del self.written[: -self.keep]
        return path

    def _whole(self, frame: Frame) -> Frame:
        """A window's frame placed on the whole sensor, the rest at the dark level under fixed read noise."""
        w, h = self.sensor
        data = np.asarray(frame.data)
        if data.shape == (h, w):
            return frame
        noise = self.camera.noise
        if self._background is None:
            draw = np.random.default_rng([self.sim.spec.seed, 104729]).standard_normal((h, w))
            self._background = draw.astype(np.float32)
        sigma = noise.read_noise_e / noise.e_per_dn * frame.gain
        level = noise.black_level_dn + noise.dark_current_e_per_s * frame.exposure_s / noise.e_per_dn * frame.gain
        full = np.clip(np.rint(level + sigma * self._background), 0, noise.white_level_dn).astype(data.dtype)
        x0, y0 = frame.origin_xy
        full[y0 : y0 + data.shape[0], x0 : x0 + data.shape[1]] = data
        return dataclasses.replace(frame, data=full, origin_xy=(0, 0), cfa_pattern=self.camera.cfa_pattern)

    def answer_requests(self) -> list[Path]:
        """Shoot every shot request the folder camera has left (oldest first); returns the frames written.

        Noise is drawn per state of the rig (:meth:`SimulatedRig.state_key`), a stream restarted by each
        scene an operator sets and by each new controller process: a resumed run's readings then see the
        draws an uninterrupted run's saw, as on the simulated backend, whose camera lives with the run.
        """
        shot = []
        for request in take_requests(self.folder):
            if request.client != self._client:
                self._client = request.client
                self.camera.restart_streams()
            shot.append(self.shoot(request.exposure_s, request.gain))
        return shot

    def serve(self, stop: threading.Event, poll_s: float = 0.005, on_error: Callable[[str], None] = print) -> None:
        """Answer shot requests until ``stop`` is set (polling the folder every ``poll_s`` wall seconds)."""
        while not stop.is_set():
            try:
                self.answer_requests()
            except Exception as exc:  # the rehearsal serves on: the controller times out and says why
                on_error(f"error: shot request not answered: {exc}")
            stop.wait(poll_s)


#: The controller's folder poll (s) in a rig file the rehearsal writes: frames arrive whole, so polls can be quick.
REHEARSAL_POLL_S = 0.02


def _toml(value: object) -> str:
    """A TOML value of a string, number, boolean or list of those."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _table(name: str, keys: dict[str, object]) -> list[str]:
    return [f"[{name}]", *(f"{k} = {_toml(v)}" for k, v in keys.items() if v is not None), ""]


def controller_rig_text(rig: RigConfig, sim: SimulatedRig, link: str, folder: Path, roi: Box) -> str:
    """The hardware rig file a controller runs the rehearsal of a simulated rig file with (TOML text).

    It says only what a lab knows of its rig: the drawn geometry, the link on the rehearsal's port, the
    axes as the virtual servos or steppers are set up, the folder camera on the hot folder and the ROI, a
    reference tile placed by hand. The simulated file's ``[simulation]`` (its misalignment included) stays
    hidden, as a real rig's imperfections are.
    """
    f = rig.file
    geometry = f.geometry.model_dump(exclude_defaults=True, exclude={"limits", "calibration"})
    if f.geometry.calibration is not None:
        geometry["calibration"] = str((Path(rig.path).parent / f.geometry.calibration).resolve())
    lines = [f"# The controller's side of the rehearsal of {rig.path} ({link}), written by gonio sim rig.",
             f"name = {_toml(f.name + ' (rehearsal)')}", "", *_table("geometry", geometry)]  # fmt: skip
    limits = f.geometry.limits.model_dump(exclude_defaults=True)
    if limits:
        lines += _table("geometry.limits", {k: list(v) for k, v in limits.items()})
    baudrate = sim.spec.baudrate if link == "dynamixel" else 115200
    lines += _table("link", {"kind": link, "port": sim.port, "baudrate": baudrate,
                             "move_timeout_s": f.link.move_timeout_s, "on_stop": f.link.on_stop})  # fmt: skip
    for axis in sim.axes:
        address = {"id": axis.address} if link == "dynamixel" else {"letter": axis.address}
        lines += _table(f"axes.{axis.name}", {
            **address, "units_per_degree": None if link == "dynamixel" else axis.units_per_degree,
            "gear_ratio": axis.gear_ratio, "direction": axis.direction, "zero_offset_deg": axis.zero_offset_deg,
            "min_deg": axis.min_deg, "max_deg": axis.max_deg, "max_speed_deg_s": axis.max_speed_deg_s,
            "max_accel_deg_s2": axis.max_accel_deg_s2,
        })  # fmt: skip
    cam = f.camera
    # The rehearsal renames each frame into the folder whole (write_dng), so one poll that sees it is enough;
    # a real tethering program may write in place and needs the folder camera's default two polls.
    camera: dict[str, object] = {"backend": "folder", "folder": str(folder), "roi": list(roi),
                                 "min_exposure_s": cam.min_exposure_s, "max_exposure_s": cam.max_exposure_s,
                                 "stable_polls": 1, "poll_interval_s": REHEARSAL_POLL_S,
                                 "calibration": cam.calibration, "flat_field": cam.flat_field}  # fmt: skip
    for key in ("calibration", "flat_field"):
        if isinstance(camera[key], str):
            camera[key] = str((Path(rig.path).parent / str(camera[key])).resolve())
    lines += _table("camera", camera)
    if cam.calibration is None:
        lines += _table("camera.noise", cam.noise.model_dump())
    ref = f.reference
    lines += _table("reference", {"kind": "manual" if ref.kind == "simulated" else ref.kind,
                                  "albedo": list(ref.albedo) if isinstance(ref.albedo, tuple) else ref.albedo,
                                  "albedo_std_error": ref.albedo_std_error, "theta_i_deg": ref.theta_i_deg,
                                  "theta_o_deg": ref.theta_o_deg, "every": ref.every,
                                  "target_snr": ref.target_snr})  # fmt: skip
    if f.metadata.as_dict():
        lines += _table("metadata", f.metadata.as_dict())
    return "\n".join(lines)
