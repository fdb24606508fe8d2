"""The 8-bit path, for cameras without RAW output: camera-response calibration and HDR merge through OpenCV.

An 8-bit camera applies an unknown, non-linear tone curve before quantising, so a bracket is merged by
first recovering the inverse response (code -> relative exposure, per channel) with OpenCV's
``CalibrateDebevec`` (least squares with a smoothness term, on a grid of sample pixels) or
``CalibrateRobertson`` (iterative, on all pixels), storing it per camera (:meth:`ResponseCurve.save`,
:func:`calibrate_or_load`) and reusing it for every later bracket of that camera (``MergeDebevec`` or
``MergeRobertson``).

OpenCV's results need our flags: a pixel saturated in every frame comes back as 0 from Robertson and as
a plausible but wrong value from Debevec, and a pixel dark in every frame as 0 or a value set by
quantisation alone, with nothing to tell them apart. :func:`merge_8bit` flags, per pixel
and channel, codes >= ``saturated_code`` in every frame (:attr:`HdrFlag.SATURATED`; the radiance is
replaced by a lower bound, the shortest frame's code through the curve over its exposure, as the linear
merge does) and codes <= ``dark_code`` in every frame (:attr:`HdrFlag.DARK`; OpenCV's value is kept).
OpenCV weighs the channels of a pixel together, so one channel can be saturated in every frame while the
others are not: the flags are per channel for that reason.

Units: relative. OpenCV's curves have an arbitrary scale per channel (Debevec puts code 128 at 1), so the
radiance is in "curve units per second"; a reference target calibrates it. Variance: NaN, because the
8-bit path has no noise model (the tone curve, quantisation and the camera's processing are unknown); use
the scatter over a region of interest instead.
"""

from __future__ import annotations

import datetime
import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import cv2
import numpy as np
import numpy.typing as npt

from acquisition.files.atomic import atomic_path
from acquisition.frame import Frame, FrameError
from acquisition.hdr.bracket import check_bracket, describe_frame
from acquisition.hdr.merge import HdrFlag, HdrImage

Method = Literal["debevec", "robertson"]
METHODS: tuple[Method, ...] = ("debevec", "robertson")
#: File format version written by :meth:`ResponseCurve.save`.
FORMAT = "gonio.response/1"
LDR_SIZE = 256


@dataclass(frozen=True, eq=False)
class ResponseCurve:
    """A camera's calibrated inverse response: relative exposure (arbitrary units x seconds) per 8-bit code.

    Parameters
    ----------
    inverse:
        (256, C) float32, C = 1 or 3: OpenCV's inverse camera response, channel order as in the frames.
    method:
        ``"debevec"`` or ``"robertson"``: the calibration that produced it (and the default merge).
    camera_id:
        The camera it belongs to (``Frame.camera_id``).
    created:
        When it was calibrated, ISO 8601.
    opencv_version:
        ``cv2.__version__`` at calibration.
    params:
        The calibration's parameters (samples, smoothness, iterations, ...).
    """

    inverse: npt.NDArray[np.float32]
    method: Method
    camera_id: str
    created: str
    opencv_version: str = cv2.__version__
    params: dict[str, float | int | bool] = field(default_factory=dict)

    def __post_init__(self) -> None:
        inv = np.asarray(self.inverse, dtype=np.float32)
        if inv.ndim == 1:
            inv = inv[:, None]
        if inv.ndim != 2 or inv.shape[0] != LDR_SIZE or inv.shape[1] not in (1, 3):
            raise ValueError(f"ResponseCurve.inverse has shape {np.shape(self.inverse)}: expected (256, 1) or (256, 3)")
        if not np.all(np.isfinite(inv) & (inv > 0)):
            raise ValueError("ResponseCurve.inverse must be finite and positive (relative exposure per code)")
        if self.method not in METHODS:
            raise ValueError(f"ResponseCurve.method = {self.method!r}: expected one of {METHODS}")
        object.__setattr__(self, "inverse", np.ascontiguousarray(inv))

    @property
    def channels(self) -> int:
        """Number of colour channels the curve covers (1 or 3)."""
        return int(self.inverse.shape[1])

    def to_opencv(self) -> npt.NDArray[np.float32]:
        """The curve in OpenCV's layout: (256, 1, C) float32."""
        return np.ascontiguousarray(self.inverse[:, None, :])

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the curve to ``path`` (.json, or .npz) atomically: temporary file, then rename."""
        target = Path(path)
        meta = {
            "format": FORMAT, "method": self.method, "camera_id": self.camera_id, "created": self.created,
            "opencv_version": self.opencv_version, "params": self.params, "channels": self.channels,
        }
        with atomic_path(target) as tmp, open(tmp, "wb") as fh:
            if target.suffix == ".npz":
                np.savez(fh, inverse=self.inverse, meta=np.array(json.dumps(meta)))
            else:
                # float32 -> float -> repr round-trips exactly, so a JSON curve loads bit-identical.
                meta["inverse"] = [[float(v) for v in row] for row in self.inverse]
                fh.write(json.dumps(meta, indent=1).encode())
        return target

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> ResponseCurve:
        """Read a curve written by :meth:`save` (.json or .npz)."""
        source = Path(path)
        try:
            if source.suffix == ".npz":
                with np.load(source, allow_pickle=False) as z:
                    meta = json.loads(str(z["meta"]))
                    inverse = np.asarray(z["inverse"], dtype=np.float32)
            else:
                meta = json.loads(source.read_text())
                inverse = np.asarray(meta.pop("inverse"), dtype=np.float32)
            if meta.get("format") != FORMAT:
                raise ValueError(f"format {meta.get('format')!r}, expected {FORMAT!r}")
            return cls(
                inverse=inverse, method=meta["method"], camera_id=meta["camera_id"], created=meta["created"],
                opencv_version=meta["opencv_version"], params=dict(meta.get("params", {})),
            )
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise ValueError(f"{source}: not a readable response curve ({exc})") from exc


def check_8bit(frames: Sequence[Frame], *, min_exposures: int = 1) -> tuple[list[npt.NDArray[np.uint8]], int]:
    """Validate an 8-bit bracket; its images as OpenCV wants them, and the channel count (1 or 3)."""
    check_bracket(frames, ("8bit",))
    images = []
    for i, f in enumerate(frames):
        if f.data.dtype != np.uint8:
            raise FrameError(
                f"{describe_frame(i, f)} has dtype {f.data.dtype}: OpenCV's response calibration and merge "
                "take 8-bit (uint8) images only"
            )
        images.append(np.ascontiguousarray(f.data))
    channels = 1 if frames[0].data.ndim == 2 else frames[0].shape[2]
    if channels not in (1, 3):
        raise FrameError(f"{describe_frame(0, frames[0])} has {channels} channels: expected 1 or 3")
    distinct = sorted({f.exposure_s for f in frames})
    if len(distinct) < min_exposures:
        raise FrameError(
            f"{len(distinct)} distinct exposure(s) {distinct} s: the response calibration needs at least "
            f"{min_exposures}"
        )
    return images, channels


def _camera_of(frames: Sequence[Frame]) -> str:
    ids = {f.camera_id for f in frames}
    if len(ids) > 1:
        raise FrameError(f"the bracket mixes cameras {sorted(ids)}: a response curve belongs to one camera")
    return ids.pop()


def calibrate_response(
    frames: Sequence[Frame],
    method: Method = "debevec",
    *,
    samples: int = 70,
    smoothness: float = 10.0,
    random_samples: bool = False,
    max_iter: int = 30,
    threshold: float = 0.01,
    created: str | None = None,
) -> ResponseCurve:
    """Recover the inverse camera response (relative exposure per code) from a bracket of 8-bit frames.

    Needs at least two distinct exposures (seconds). Debevec: ``samples`` pixel locations on a grid (at
    random, from OpenCV's generator, if ``random_samples``), smoothness weight ``smoothness``. Robertson:
    ``max_iter`` Gauss-Seidel iterations or until the change falls below ``threshold``. ``created``
    (ISO 8601) defaults to now, UTC.
    """
    if method not in METHODS:
        raise ValueError(f"method = {method!r}: expected one of {METHODS}")
    images, channels = check_8bit(frames, min_exposures=2)
    times = np.array([f.exposure_s for f in frames], dtype=np.float32)
    params: dict[str, float | int | bool]
    calibrator: cv2.CalibrateCRF
    if method == "debevec":
        params = {"samples": samples, "smoothness": smoothness, "random_samples": random_samples}
        calibrator = cv2.createCalibrateDebevec(samples=samples, lambda_=smoothness, random=random_samples)
    else:
        params = {"max_iter": max_iter, "threshold": threshold}
        calibrator = cv2.createCalibrateRobertson(max_iter=max_iter, threshold=threshold)
    inverse = np.asarray(calibrator.process(images, times), dtype=np.float32).reshape(LDR_SIZE, channels)
    stamp = created or datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    return ResponseCurve(inverse=inverse, method=method, camera_id=_camera_of(frames), created=stamp, params=params)


def calibrate_or_load(
    path: str | os.PathLike[str],
    frames: Sequence[Frame],
    method: Method = "debevec",
    *,
    samples: int = 70,
    smoothness: float = 10.0,
    max_iter: int = 30,
    threshold: float = 0.01,
) -> ResponseCurve:
    """The camera's stored curve at ``path`` if there is one, else a new calibration on ``frames``, saved there.

    A stored curve for another camera, method or channel count is an error, not silently replaced.
    """
    target = Path(path)
    if target.exists():
        curve = ResponseCurve.load(target)
        _, channels = check_8bit(frames)
        camera = _camera_of(frames)
        if curve.method != method or curve.channels != channels or not _same_camera(curve.camera_id, camera):
            raise FrameError(
                f"{target} holds a {curve.method} curve for camera {curve.camera_id!r} with {curve.channels} "
                f"channel(s); asked for {method} on camera {camera!r} with {channels}: use another path or "
                "delete the file to recalibrate"
            )
        return curve
    curve = calibrate_response(
        frames, method, samples=samples, smoothness=smoothness, max_iter=max_iter, threshold=threshold
    )
    curve.save(target)
    return curve


def _same_camera(a: str, b: str) -> bool:
    return a == b or "unknown" in (a, b)


def merge_8bit(
    frames: Sequence[Frame],
    curve: ResponseCurve,
    *,
    method: Method | None = None,
    saturated_code: int = 254,
    dark_code: int = 1,
) -> HdrImage:
    """Merge an 8-bit bracket through its camera's response curve: relative radiance per second, flagged.

    ``method`` picks OpenCV's merge (default: the curve's calibration method). A pixel (per channel) is
    flagged saturated if its code is >= ``saturated_code`` in every frame, dark if <= ``dark_code`` in
    every frame; ``frames_used`` counts the frames with a code strictly between the two.
    """
    merge_method = method or curve.method
    if merge_method not in METHODS:
        raise ValueError(f"method = {merge_method!r}: expected one of {METHODS}")
    if not 0 <= dark_code < saturated_code <= 255:
        raise ValueError(f"need 0 <= dark_code ({dark_code}) < saturated_code ({saturated_code}) <= 255")
    images, channels = check_8bit(frames)
    if channels != curve.channels:
        raise FrameError(f"the frames have {channels} channel(s) but the response curve has {curve.channels}")
    camera = _camera_of(frames)
    if not _same_camera(curve.camera_id, camera):
        raise FrameError(f"the response curve is for camera {curve.camera_id!r}, the frames are from {camera!r}")
    times = np.array([f.exposure_s for f in frames], dtype=np.float32)
    merger = cv2.createMergeDebevec() if merge_method == "debevec" else cv2.createMergeRobertson()
    radiance = np.asarray(merger.process(images, times, curve.to_opencv()), dtype=np.float32)
    radiance = radiance.reshape(frames[0].shape)

    all_sat = np.ones(frames[0].shape, np.bool_)
    all_dark = np.ones(frames[0].shape, np.bool_)
    used = np.zeros(frames[0].shape, np.uint8)
    sat8, dark8 = np.uint8(saturated_code), np.uint8(dark_code)
    for img in images:
        high = img >= sat8
        low = img <= dark8
        all_sat &= high
        all_dark &= low
        used += ~(high | low)
    flags = np.where(all_sat, np.uint8(HdrFlag.SATURATED), np.uint8(0))
    flags |= np.where(all_dark, np.uint8(HdrFlag.DARK), np.uint8(0))

    if all_sat.any():
        shortest = int(np.argmin(times))
        codes = images[shortest][all_sat]
        chan = np.nonzero(all_sat)[2] if channels == 3 else np.zeros(codes.size, np.intp)
        radiance[all_sat] = curve.inverse[codes, chan] / frames[shortest].exposure_s

    metadata: dict[str, object] = {
        "method": f"opencv-{merge_method}",
        "units": "relative: response-curve units per second (arbitrary scale per channel)",
        "variance": "NaN: the 8-bit path has no noise model",
        "curve_method": curve.method,
        "curve_camera_id": curve.camera_id,
        "curve_created": curve.created,
        "opencv_version": cv2.__version__,
        "saturated_code": saturated_code,
        "dark_code": dark_code,
        "camera_id": camera,
        "kind": "8bit",
    }
    return HdrImage(
        radiance=radiance, variance=np.full(frames[0].shape, math.nan, np.float32), flags=flags,
        frames_used=used, exposures_s=tuple(float(t) for t in (f.exposure_s for f in frames)), metadata=metadata,
    )
