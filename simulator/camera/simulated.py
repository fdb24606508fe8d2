"""The simulated camera: a radiance image of the current pose in, frames of a bracket out, like a real camera.

``SimulatedCamera`` satisfies ``acquisition.frame.Camera``, so the runner cannot tell it from a real one.
It asks a *radiance source* for the scene's radiance in W/(m^2 sr) at the moment of capture (the
simulated rig renders it with Mitsuba from the pose the virtual servos actually hold, cached per pose),
turns it into counts per second through the optics (``CameraOptics``), and lets the sensor model draw
each exposure: shot noise, dark current, read noise, full well, black and white levels, a fixed-pattern
offset, quantisation and the optional 8-bit response curve. Exposures take simulated time on the
camera's clock, so a run on a ``ManualClock`` costs no real waiting.

With ``dng_dir`` set, RAW frames are written as DNG files and read back through ``acquisition.files.raw``, the
path a real camera's files take. LibRaw refuses images under 22 pixels a side, so a source that renders
only around its ROI returns a :class:`SensorPatch`: a window of the sensor at least that large, where it
lies on the sensor, and the ROI inside it. The camera exposes the window, writes and reads it back, and
delivers the ROI with its place on the sensor (``Frame.origin_xy``) and the CFA phase of that place.

The sensor's hidden flaws (vignetting, pixel response non-uniformity, non-linearity:
:class:`simulator.camera.pixels.PixelResponse`) are defined over the whole sensor and applied where the
window lies, so calibrations made from full frames apply to the windows a run reads.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import threading
from collections.abc import Callable, Hashable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.typing as npt

from acquisition.cfa import shift_pattern
from acquisition.frame import ExposureSettings, Frame, FrameKind
from acquisition.noise import SensorNoise
from rig.instrument.clock import Clock, ManualClock
from simulator.camera.pixels import PixelResponse
from simulator.camera.sensor import ToneCurve, as_generator, capture, srgb_curve

PLANCK_J_S = 6.62607015e-34
LIGHT_M_S = 299_792_458.0

#: Windows written as DNG are at least this many pixels a side (LibRaw refuses fewer than 22).
DNG_MIN_SIDE = 24

#: Sub-exposures a frame taken while the scene moves is rendered at (at the middles of equal slices of the
#: exposure) and averaged: the motion blur of a continuous scan. Few, because each is a render; a frame of a scan
#: spans a small fraction of the sweep's step, over which the radiance is near linear in the angle.
BLUR_SAMPLES = 4


@dataclass(frozen=True, eq=False)
class SensorPatch:
    """A window of the sensor's radiance: (H, W, 3) W/(m^2 sr), its sensor origin and the part to deliver.

    ``origin_xy`` is the sensor pixel of the window's pixel (0, 0); ``roi`` the box (x0, y0, x1, y1) of the
    window the camera delivers (None: all of it); ``sensor`` the whole sensor's (width, height) (None: the
    window is the whole sensor).
    """

    radiance: npt.NDArray[np.float64]
    origin_xy: tuple[int, int] = (0, 0)
    roi: tuple[int, int, int, int] | None = None
    sensor: tuple[int, int] | None = None


RadianceSource = Callable[..., "npt.NDArray[np.float64] | SensorPatch"]
"""Returns the radiance (W/(m^2 sr)) the camera sees now, (H, W, 3), or a :class:`SensorPatch` of it; called
with ``full_frame=True`` when the camera is set to deliver whole frames (a source that renders only an ROI
renders everything then)."""


def window_around(box: tuple[int, int, int, int], resolution: tuple[int, int], min_side: int) -> tuple[int, ...]:
    """A window (x0, y0, x1, y1) holding ``box``, at least ``min_side`` a side, on even pixels, inside the sensor.

    Even origins keep a window's CFA phase that of the sensor; the window shrinks only where the sensor does.
    """
    out = []
    for lo, hi, size in ((box[0], box[2], resolution[0]), (box[1], box[3], resolution[1])):
        side = min(max(hi - lo, min_side), size)
        start = min(max(lo - (side - (hi - lo)) // 2, 0), size - side)
        start -= start % 2
        end = min(max(start + side, hi), size)
        out.append((start, end))
    return (out[0][0], out[1][0], out[0][1], out[1][1])


@dataclass(frozen=True)
class CameraOptics:
    """What turns scene radiance into photo-electrons: lens, pixel and quantum efficiency.

    Parameters
    ----------
    quantum_efficiency:
        Photo-electrons per photon at ``wavelength_m`` (0..1).
    pixel_pitch_m:
        Pixel side in metres (square pixels).
    f_number:
        Working f-number of the lens; the image irradiance is L * pi / (4 N^2) * transmission.
    transmission:
        Lens and filter transmission (0..1).
    wavelength_m:
        Wavelength used to count photons per joule (one effective wavelength for all channels).
    """

    quantum_efficiency: float = 0.6
    pixel_pitch_m: float = 5.0e-6
    f_number: float = 8.0
    transmission: float = 0.9
    wavelength_m: float = 550e-9

    def __post_init__(self) -> None:
        for key, lo, hi in (("quantum_efficiency", 0.0, 1.0), ("transmission", 0.0, 1.0)):
            value = getattr(self, key)
            if not lo < value <= hi:
                raise ValueError(f"CameraOptics.{key} = {value!r}: expected a number in ({lo:g}, {hi:g}]")
        for key in ("pixel_pitch_m", "f_number", "wavelength_m"):
            value = getattr(self, key)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"CameraOptics.{key} = {value!r}: expected a positive finite number")

    def electrons_per_radiance(self) -> float:
        """Photo-electrons per second per pixel for a radiance of 1 W/(m^2 sr)."""
        irradiance = math.pi / (4.0 * self.f_number**2) * self.transmission  # W/m^2 per W/(m^2 sr)
        photons_per_joule = self.wavelength_m / (PLANCK_J_S * LIGHT_M_S)
        return irradiance * self.pixel_pitch_m**2 * photons_per_joule * self.quantum_efficiency

    def counts_per_radiance(self, noise: SensorNoise) -> float:
        """Counts per second at gain 1 for a radiance of 1 W/(m^2 sr)."""
        return self.electrons_per_radiance() / noise.e_per_dn


class SimulatedCamera:
    """A camera whose frames come from a radiance source and the sensor model; see the module docstring.

    ``fixed_pattern_dn`` is the RMS of a per-pixel offset drawn once from ``seed`` (dark signal
    non-uniformity); dark frames carry it, so subtracting them removes it. ``min_exposure_s`` and
    ``max_exposure_s`` bound what ``set_exposure`` applies, like a real camera's shutter range.

    ``state_key`` (optional) names the scene's state (the simulated rig gives the servos' physical
    positions and the material in view). With it, each frame's noise is drawn from the seed, that state
    and the frame's number since the state last changed, instead of from one stream for the camera's
    life: a run resumed after a crash then sees exactly the noise an uninterrupted run saw.
    """

    def __init__(
        self,
        source: RadianceSource,
        *,
        noise: SensorNoise | None = None,
        optics: CameraOptics | None = None,
        kind: FrameKind = "linear",
        cfa_pattern: str = "RGGB",
        tone_curve: ToneCurve = srgb_curve,
        fixed_pattern_dn: float = 0.0,
        min_exposure_s: float = 1e-5,
        max_exposure_s: float = 30.0,
        clock: Clock | None = None,
        seed: int = 0,
        dng_dir: Path | None = None,
        camera_id: str = "gonio simulated camera",
        state_key: Callable[[], Hashable] | None = None,
        stray_counts_per_s: float = 0.0,
        response: PixelResponse | None = None,
        keep_dng: bool = True,
        moving: Callable[[], bool] | None = None,
    ) -> None:
        if not 0 < min_exposure_s < max_exposure_s:
            raise ValueError(
                f"exposure range [{min_exposure_s!r}, {max_exposure_s!r}] s: expected 0 < min < max"
            )
        if fixed_pattern_dn < 0:
            raise ValueError(f"fixed_pattern_dn = {fixed_pattern_dn!r}: expected an RMS >= 0 counts")
        if not (math.isfinite(stray_counts_per_s) and stray_counts_per_s >= 0):
            raise ValueError(f"stray_counts_per_s = {stray_counts_per_s!r}: expected counts per second >= 0")
        self.stray_counts_per_s = float(stray_counts_per_s)
        #: Deliver whole frames (geometry calibration) instead of the ROI a run reads.
        self.full_frame = False
        if dng_dir is not None and kind != "raw":
            raise ValueError(f"dng_dir needs kind='raw' (DNG holds a CFA mosaic), got kind={kind!r}")
        self._source = source
        #: Whether the scene moves now (the simulated rig: a servo mid-move); a frame then averages BLUR_SAMPLES
        #: renders along the exposure, the source called with ``like=`` the frame's first window.
        self._moving = moving
        self.noise = noise or SensorNoise()
        self.optics = optics or CameraOptics()
        self.kind: FrameKind = kind
        self.cfa_pattern = cfa_pattern
        self.tone_curve = tone_curve
        self.fixed_pattern_dn = fixed_pattern_dn
        self.min_exposure_s = min_exposure_s
        self.max_exposure_s = max_exposure_s
        self.clock: Clock = clock or ManualClock()
        self.dng_dir = Path(dng_dir) if dng_dir is not None else None
        self.keep_dng = keep_dng
        self.response = response or PixelResponse()
        if state_key is not None and not isinstance(seed, int):
            raise ValueError(f"state_key needs an int seed (it derives one stream per state), got {seed!r}")
        self._rng = as_generator(seed)
        self._seed = seed
        self._state_key = state_key
        self._state: tuple[str, int] | None = None
        self._fpn_seed = seed + 7919  # the offset map must not depend on how many frames came before
        self._fpn: dict[tuple[int, ...], npt.NDArray[np.float32]] = {}
        self._settings = ExposureSettings(exposure_s=min(max(0.01, min_exposure_s), max_exposure_s), gain=1.0)
        self._camera_id = camera_id
        self._lock = threading.Lock()
        self._frames = 0
        self.closed = False

    @property
    def identity(self) -> str:
        """Make, model and serial of the simulated camera."""
        return self._camera_id

    def set_exposure(self, exposure_s: float, gain: float | None = None) -> ExposureSettings:
        """Apply an exposure in seconds (clamped to the shutter range) and a gain; return what was applied."""
        self._require_open()
        if not (math.isfinite(exposure_s) and exposure_s > 0):
            raise ValueError(f"{self.identity}: exposure_s = {exposure_s!r}, expected a positive number of seconds")
        g = self._settings.gain if gain is None else float(gain)
        if not (math.isfinite(g) and g > 0):
            raise ValueError(f"{self.identity}: gain = {gain!r}, expected a positive number")
        t = min(max(exposure_s, self.min_exposure_s), self.max_exposure_s)
        self._settings = ExposureSettings(exposure_s=t, gain=g)
        return self._settings

    def _patch(self) -> SensorPatch:
        got = self._source(full_frame=True) if self.full_frame else self._source()
        patch = got if isinstance(got, SensorPatch) else SensorPatch(np.asarray(got, dtype=np.float64))
        radiance = np.asarray(patch.radiance, dtype=np.float64)
        if radiance.ndim != 3 or radiance.shape[2] != 3:
            raise ValueError(f"{self.identity}: radiance source gave shape {radiance.shape}, expected (H, W, 3)")
        return patch

    def rate_counts_per_s(self) -> npt.NDArray[np.float64]:
        """The scene as the sensor sees it now: counts per second at gain 1, (H, W, 3) (the whole window)."""
        return np.asarray(self._patch().radiance, dtype=np.float64) * self.optics.counts_per_radiance(self.noise)

    def capture(self) -> Frame:
        """One frame at the current settings; takes ``exposure_s`` of the camera's clock."""
        self._require_open()
        with self._lock:
            patch = self._patch()
            rate = np.asarray(patch.radiance, dtype=np.float64) * self.optics.counts_per_radiance(self.noise)
            if self._moving is not None and self._moving():
                return self._expose(self._blurred(patch), patch, dark=False)
            # Ambient light reaches the sensor whenever the shutter is open, whatever the lamp does.
            return self._expose(rate + self.stray_counts_per_s if self.stray_counts_per_s else rate, patch, dark=False)

    def _blurred(self, patch: SensorPatch) -> Callable[[], npt.NDArray[np.float64]]:
        """The counts/s of a frame along the motion: renders at BLUR_SAMPLES times inside the exposure, averaged.

        Called at the exposure's start; advances the clock to the last sub-exposure's middle, so the scene is
        rendered where the servos physically are then (``_expose`` sleeps the rest of the exposure).
        """

        def rate() -> npt.NDArray[np.float64]:
            t, start = self._settings.exposure_s, self.clock.now()
            total = np.zeros_like(np.asarray(patch.radiance, dtype=np.float64))
            for k in range(BLUR_SAMPLES):
                self.clock.sleep(max(0.0, start + (k + 0.5) * t / BLUR_SAMPLES - self.clock.now()))
                sub = self._source(like=patch)
                total += np.asarray(sub.radiance if isinstance(sub, SensorPatch) else sub, dtype=np.float64)
            out = total / BLUR_SAMPLES * self.optics.counts_per_radiance(self.noise)
            return out + self.stray_counts_per_s if self.stray_counts_per_s else out

        return rate

    def capture_dark(self) -> Frame:
        """One frame with the shutter closed at the current settings (black, dark current, offsets, noise)."""
        self._require_open()
        with self._lock:
            patch = self._patch()
            return self._expose(np.zeros(patch.radiance.shape), patch, dark=True)

    def _offsets(self, shape: tuple[int, ...], patch: SensorPatch) -> npt.NDArray[np.float32] | None:
        if self.fixed_pattern_dn == 0:
            return None
        # Over the whole sensor when the window says where it lies, so a pixel keeps its offset in every window.
        full = shape if patch.sensor is None else (patch.sensor[1], patch.sensor[0], *shape[2:])
        if full not in self._fpn:
            gen = np.random.default_rng(self._fpn_seed)
            self._fpn[full] = (gen.standard_normal(full) * self.fixed_pattern_dn).astype(np.float32)
        x0, y0 = patch.origin_xy
        return self._fpn[full][y0 : y0 + shape[0], x0 : x0 + shape[1]]

    def _pixel_gain(self, shape: tuple[int, ...], patch: SensorPatch) -> npt.NDArray[np.float64] | None:
        if self.response.flat:
            return None
        sensor = patch.sensor if patch.sensor is not None else (shape[1], shape[0])
        return self.response.window(sensor, patch.origin_xy, (shape[0], shape[1]))

    def _generator(self, dark: bool) -> np.random.Generator:
        if self._state_key is None:
            return self._rng
        # Python's hash() is salted per process; a resumed run needs the same stream in a new process.
        digest = hashlib.blake2b(repr((self._state_key(), dark)).encode(), digest_size=8).hexdigest()
        n = self._state[1] + 1 if self._state is not None and self._state[0] == digest else 0
        self._state = (digest, n)
        return np.random.default_rng([self._seed, int(digest, 16), n])

    def _expose(self, rate: npt.NDArray[np.float64] | Callable[[], npt.NDArray[np.float64]], patch: SensorPatch, *,
                dark: bool) -> Frame:  # fmt: skip
        t, g = self._settings.exposure_s, self._settings.gain
        rng = self._generator(dark)
        start = self.clock.now()
        along = callable(rate)  # a frame along the motion: the clock runs during its renders
        rate = rate() if callable(rate) else rate
        # The sensor's CFA phase at the window's origin: the pattern is the sensor's, not the window's.
        pattern = shift_pattern(self.cfa_pattern, *patch.origin_xy) if self.kind == "raw" else None
        shape = rate.shape[:2] if self.kind == "raw" else rate.shape
        offsets = self._offsets(tuple(shape), patch)
        light = {"pixel_gain": self._pixel_gain(tuple(shape), patch), "nonlinearity": self.response.nonlinearity}
        if dark:
            frame = capture(np.zeros(shape), self.noise, t, rng, gain=g, kind=self.kind, cfa_pattern=pattern,
                            camera_id=self.identity, timestamp_s=start, offset_dn=offsets,
                            nonlinearity=self.response.nonlinearity)  # fmt: skip
        else:
            frame = capture(rate, self.noise, t, rng, gain=g, kind=self.kind, cfa_pattern=pattern,
                            tone_curve=self.tone_curve, camera_id=self.identity, timestamp_s=start,
                            offset_dn=offsets, **light)  # type: ignore[arg-type]  # fmt: skip
        self.clock.sleep(max(0.0, start + t - self.clock.now()) if along else t)
        self._frames += 1
        if self.dng_dir is not None:
            frame = self._through_dng(frame, dark)
        return _deliver(frame, patch)

    def _through_dng(self, frame: Frame, dark: bool) -> Frame:
        # Imported here: tifffile and rawpy serve only a camera that writes DNG files, and a run's start waits
        # for every import.
        from acquisition.files.dng import write_dng
        from acquisition.files.metadata import ReadOptions
        from acquisition.files.raw import read_raw

        assert self.dng_dir is not None
        self.dng_dir.mkdir(parents=True, exist_ok=True)
        path = self.dng_dir / f"{'dark' if dark else 'frame'}_{self._frames:06d}.dng"
        write_dng(path, frame, exposure_s=frame.exposure_s, iso=100.0 * frame.gain, camera_id=self.identity)
        try:
            return read_raw(path, ReadOptions(expected_exposure_s=frame.exposure_s, timestamp_s=frame.timestamp_s))
        finally:
            if not self.keep_dng:
                path.unlink(missing_ok=True)

    def restart_streams(self) -> None:
        """Draw the next frame's noise as the first of its state's stream, whatever the last frame's state was.

        A state's stream otherwise runs on while frames of that state follow each other; a rig whose camera
        outlives its controller (the rehearsal) restarts it where a new reading begins.
        """
        self._state = None

    def close(self) -> None:
        """Release the camera; later captures raise."""
        self.closed = True

    def _require_open(self) -> None:
        if self.closed:
            raise RuntimeError(f"{self.identity} is closed")


def _deliver(frame: Frame, patch: SensorPatch) -> Frame:
    """The part of a window's frame the camera delivers, with its place on the sensor and its CFA phase."""
    ox, oy = patch.origin_xy
    if patch.roi is None:
        return dataclasses.replace(frame, origin_xy=(ox, oy))
    x0, y0, x1, y1 = patch.roi
    changes: dict[str, object] = {"data": np.ascontiguousarray(frame.data[y0:y1, x0:x1]),
                                  "origin_xy": (ox + x0, oy + y0)}  # fmt: skip
    if frame.kind == "raw" and frame.cfa_pattern is not None:
        changes["cfa_pattern"] = shift_pattern(frame.cfa_pattern, x0, y0)
        if isinstance(frame.black_level, tuple) and len(frame.black_level) == 4:
            b = frame.black_level
            changes["black_level"] = tuple(b[((y0 + i) % 2) * 2 + (x0 + j) % 2] for i in range(2) for j in range(2))
    return dataclasses.replace(frame, **changes)  # type: ignore[arg-type]
