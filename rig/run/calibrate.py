"""``gonio calibrate camera``'s procedure: drive the camera and the flat source, fit, write the calibration.

1. The flat source lights the sensor; exposures double until the mean stops rising: the saturation
   exposure ``t_sat`` (extrapolated from the last frames below the plateau).
2. The photon-transfer series: ``steps`` exposures equally spaced up to ``over * t_sat`` (EMVA 1288's
   spacing), two flat frames each; then a flat-field series of ``flat_frames`` frames at half of ``t_sat``.
3. The lens capped (``darken``): two darks per exposure of the series, and darks for the flat field.
4. The fit (:mod:`acquisition.photon_transfer`, :mod:`acquisition.flatfield`).

Everything is whole frames: the camera's ROI plays no part. Capture time is the camera's clock's (the
simulated rig's simulated time, a real rig's real time), reported with the frames taken, because the
dial between fewer frames and accuracy is the operator's (``docs/benchmarks.md`` measures it).

:func:`write_calibration` writes ``camera_calibration.json`` (the fitted values, their standard errors,
the linearity error, every point) and ``flat_field.npz``, which a rig file names as ``[camera]
calibration`` and ``flat_field``; :func:`camera_noise` and :func:`camera_flat_field` read them back.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.exposure.spec import CameraTiming
from acquisition.files.atomic import atomic_path
from acquisition.flatfield import FlatField, FlatFieldError, estimate_flat_field
from acquisition.frame import Camera, Frame
from acquisition.noise import SensorNoise
from acquisition.photon_transfer import PhotonTransfer, PhotonTransferError, PtcPoint, fit_photon_transfer, pair_points
from model.version import gonio_version
from rig.instrument.clock import Clock
from rig.run.backends.flat_source import FlatSource
from rig.run.config.files import ConfigError, RigConfig

CALIBRATION_FORMAT = "gonio-camera-calibration/1"
CALIBRATION_FILE = "camera_calibration.json"
FLAT_FIELD_FILE = "flat_field.npz"


@dataclass(frozen=True)
class CalibrationSettings:
    """How much to measure: exposures of the series, flat-field frames, how far past saturation (a factor)."""

    steps: int = 32
    flat_frames: int = 16
    over: float = 1.15
    first_exposure_s: float = 1e-3

    def __post_init__(self) -> None:
        if self.steps < 6:
            raise ValueError(f"steps = {self.steps!r}: photon transfer needs at least 6 exposures")
        if self.flat_frames < 0 or self.flat_frames == 1:
            raise ValueError(f"flat_frames = {self.flat_frames!r}: expected 0 (no flat field) or at least 2")
        if not 1.0 < self.over <= 2.0:
            raise ValueError(f"over = {self.over!r}: expected a factor in (1, 2] past the saturation exposure")


@dataclass(frozen=True)
class CameraCalibration:
    """What a calibration found: the photon transfer, the flat field (or None), the frames and time it took."""

    ptc: PhotonTransfer
    flat: FlatField | None
    frames: int
    capture_time_s: float
    saturation_exposure_s: float
    camera_id: str
    source: str


def _mean_above_black(frame: Frame) -> float:
    black = np.mean(np.asarray(frame.black_level, dtype=np.float64))
    return float(np.mean(np.asarray(frame.data, dtype=np.float64)) - black)


def saturation_exposure(camera: Camera, timing: CameraTiming, start_s: float) -> tuple[float, int]:
    """The exposure (s) at which the lit sensor's mean stops rising, from frames at doubling exposures; frames taken."""
    t = min(max(start_s, timing.min_exposure_s), timing.max_exposure_s)
    history: list[tuple[float, float]] = []
    while True:
        applied = camera.set_exposure(t).exposure_s
        history.append((applied, _mean_above_black(camera.capture())))
        if len(history) >= 2:
            (t0, m0), (t1, m1) = history[-2], history[-1]
            if m1 < m0 * (1.0 + 0.5 * (t1 / t0 - 1.0)):
                # Past the knee: the last rising frame's rate, extended to the plateau, gives t_sat.
                rising = [(ta, ma) for ta, ma in history[:-1] if ma > 0]
                ta, ma = rising[-1] if rising else (t0, m0)
                return float(min(ta * m1 / max(ma, 1e-9), timing.max_exposure_s)), len(history)
        if applied >= timing.max_exposure_s:
            raise PhotonTransferError(f"the sensor does not saturate within the longest exposure "
                                      f"({timing.max_exposure_s:g} s): brighten the flat-field source")
        t = min(2.0 * applied, timing.max_exposure_s)


def calibrate_camera(
    camera: Camera,
    source: FlatSource,
    clock: Clock,
    timing: CameraTiming,
    settings: CalibrationSettings | None = None,
    progress: Callable[[str], None] | None = None,
) -> CameraCalibration:
    """Measure and fit the camera's photon transfer and flat field (see the module doc); restores the rig."""
    cfg = settings or CalibrationSettings()
    say = progress or (lambda _msg: None)
    start = clock.now()
    frames = 0
    flats: dict[float, list[Frame]] = {}
    flat_series: list[Frame] = []
    try:
        source.illuminate()
        t_sat, frames = saturation_exposure(camera, timing, cfg.first_exposure_s)
        say(f"saturation at about {t_sat:.4g} s")
        top = min(cfg.over * t_sat, timing.max_exposure_s)
        for i, t in enumerate(np.linspace(top / cfg.steps, top, cfg.steps)):
            applied = camera.set_exposure(max(float(t), timing.min_exposure_s)).exposure_s
            flats.setdefault(applied, []).extend(camera.capture() for _ in range(2))
            frames += 2
            say(f"photon transfer: exposure {i + 1} of {cfg.steps} ({applied:.4g} s)")
        t_flat = 0.0
        if cfg.flat_frames:
            t_flat = camera.set_exposure(0.5 * t_sat).exposure_s
            flat_series = [camera.capture() for _ in range(cfg.flat_frames)]
            frames += cfg.flat_frames
            say(f"flat field: {cfg.flat_frames} frames at {t_flat:.4g} s")
        source.darken()
        points: list[PtcPoint] = []
        for t, pair in sorted(flats.items()):
            camera.set_exposure(t)
            darks = [camera.capture() for _ in range(2)]
            frames += 2
            points += pair_points(t, pair, darks)
        flat_darks: list[Frame] = []
        if cfg.flat_frames:
            camera.set_exposure(t_flat)
            flat_darks = [camera.capture() for _ in range(max(2, cfg.flat_frames // 4))]
            frames += len(flat_darks)
        say(f"darks: {frames} frames in all")
    finally:
        source.restore()
    first = next(iter(flats.values()))[0]
    ptc = fit_photon_transfer(points, first.white_level)
    flat = estimate_flat_field(flat_series, flat_darks) if cfg.flat_frames else None
    return CameraCalibration(ptc, flat, frames, clock.now() - start, t_sat, camera.identity, source.description)


def calibration_json(cal: CameraCalibration, settings: CalibrationSettings) -> dict[str, Any]:
    """The ``camera_calibration.json`` document."""
    doc = {
        "format": CALIBRATION_FORMAT, "created_utc": datetime.now(UTC).isoformat(), "gonio_version": gonio_version(),
        "camera": cal.camera_id, "light": cal.source,
        "method": "photon transfer (EMVA 1288): flat pairs at equally spaced exposures up to saturation, dark pairs",
        "frames": cal.frames, "capture_time_s": cal.capture_time_s, "saturation_exposure_s": cal.saturation_exposure_s,
        "settings": {"steps": settings.steps, "flat_frames": settings.flat_frames, "over": settings.over},
        **cal.ptc.as_json(),
    }  # fmt: skip
    if cal.flat is not None:
        doc["flat_field"] = {"file": FLAT_FIELD_FILE, "frames": cal.flat.n_frames, "signal_dn": cal.flat.signal_dn,
                             "vignetting": cal.flat.vignetting, "prnu_rms": cal.flat.prnu_rms}  # fmt: skip
    return doc


def write_calibration(cal: CameraCalibration, settings: CalibrationSettings, out: str | Path) -> list[Path]:
    """Write ``camera_calibration.json`` (and ``flat_field.npz``) into the folder ``out``; the paths written."""
    folder = Path(out)
    folder.mkdir(parents=True, exist_ok=True)
    target = folder / CALIBRATION_FILE
    with atomic_path(target) as tmp:
        tmp.write_text(json.dumps(calibration_json(cal, settings), indent=1) + "\n", encoding="utf-8")
    written = [target]
    if cal.flat is not None:
        written.append(cal.flat.save(folder / FLAT_FIELD_FILE))
    return written


def _beside(rig: RigConfig, name: str) -> Path:
    p = Path(name).expanduser()
    return p if p.is_absolute() else rig.path.parent / p


def camera_noise(rig: RigConfig) -> SensorNoise:
    """The noise the controller assumes: ``[camera] calibration``'s fitted values, else ``[camera.noise]``."""
    cam = rig.file.camera
    if cam.calibration is None:
        return SensorNoise(**cam.noise.model_dump())
    path = _beside(rig, cam.calibration)
    if "noise" in cam.model_fields_set:
        raise ConfigError(f"{rig.path}: camera.calibration = {cam.calibration!r} and [camera.noise] both given: "
                          "the calibration's fitted values replace [camera.noise]; remove one")  # fmt: skip
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{rig.path}: camera.calibration = {cam.calibration!r}: no such file {path} "
                          "(write it with `gonio calibrate camera`)") from None  # fmt: skip
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{rig.path}: camera.calibration = {cam.calibration!r}: cannot read {path}: {exc}") from None
    if not isinstance(doc, dict) or doc.get("format") != CALIBRATION_FORMAT:
        raise ConfigError(f"{rig.path}: camera.calibration = {cam.calibration!r}: {path} is not a gonio camera "
                          f"calibration (format {CALIBRATION_FORMAT!r})")  # fmt: skip
    try:
        return SensorNoise(**{k: float(v) for k, v in doc["noise"].items()})
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"{rig.path}: camera.calibration = {cam.calibration!r}: {path}: bad noise: {exc}") from None


def camera_flat_field(rig: RigConfig) -> FlatField | None:
    """The flat field ``[camera] flat_field`` names, or None."""
    cam = rig.file.camera
    if cam.flat_field is None:
        return None
    try:
        return FlatField.load(_beside(rig, cam.flat_field))
    except FlatFieldError as exc:
        raise ConfigError(f"{rig.path}: camera.flat_field = {cam.flat_field!r}: {exc}") from None


def relative_errors(cal: CameraCalibration) -> dict[str, float]:
    """Each fitted value's standard error over its value (the dial's accuracy axis)."""
    p = cal.ptc
    return {k: getattr(p, k).std_error / abs(getattr(p, k).value) if getattr(p, k).value else math.inf
            for k in ("e_per_dn", "read_noise_e", "dark_current_e_per_s", "full_well_e")}  # fmt: skip
