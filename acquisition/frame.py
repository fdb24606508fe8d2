"""A captured frame and the camera interface every backend (real or simulated) satisfies."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, Protocol, runtime_checkable

import numpy as np
import numpy.typing as npt

from model.errors import GonioError

FrameKind = Literal["raw", "linear", "8bit"]
"""``raw``: a CFA mosaic (H, W) in sensor counts; ``linear``: demosaiced or mono linear counts (H, W[, C]);
``8bit``: a gamma-encoded display image (H, W[, C]) from a camera without RAW output."""


class FrameError(GonioError, ValueError):
    """A frame is unusable: missing or contradictory metadata, wrong shape, or unreadable data."""


@dataclass(frozen=True)
class Frame:
    """One exposure as the camera delivered it, with what the camera confirmed about it.

    Parameters
    ----------
    data:
        Pixel values in sensor counts (digital numbers), not black-subtracted.
    kind:
        See ``FrameKind``.
    exposure_s:
        Exposure time in seconds as confirmed by the camera or the file's metadata (not as requested).
    gain:
        Analogue gain (ISO / 100 for still cameras, linear factor for machine-vision cameras); 1 if none.
    black_level:
        Black level in counts: one number, or one per CFA position in ``cfa_pattern`` order.
    white_level:
        Highest count the sensor delivers (saturation is measured per camera; this is the file's claim).
    cfa_pattern:
        The 2x2 colour filter layout, e.g. ``"RGGB"``, for ``raw`` frames; None otherwise.
    timestamp_s:
        Capture time in seconds on the acquiring clock.
    camera_id:
        Identity of the camera (make, model, serial where known).
    source:
        Where the frame came from (file path), for error messages; None for frames straight from memory.
    origin_xy:
        The sensor pixel (x, y) that pixel (0, 0) of ``data`` is: (0, 0) for a full frame, the window's
        offset for a camera reading out a window (ROI readout). Per-pixel corrections (a flat field) use it.
    """

    data: npt.NDArray[np.generic]
    kind: FrameKind
    exposure_s: float
    gain: float = 1.0
    black_level: float | tuple[float, ...] = 0.0
    white_level: float = 65535.0
    cfa_pattern: str | None = None
    timestamp_s: float = 0.0
    camera_id: str = "unknown"
    source: str | None = None
    extra: dict[str, object] = field(default_factory=dict, compare=False)
    origin_xy: tuple[int, int] = (0, 0)

    def __post_init__(self) -> None:
        where = f"frame from {self.source}" if self.source else f"frame from {self.camera_id}"
        if self.kind not in ("raw", "linear", "8bit"):
            raise FrameError(f"{where}: kind = {self.kind!r}, expected 'raw', 'linear' or '8bit'")
        if not _positive(self.exposure_s):
            raise FrameError(f"{where}: exposure_s = {self.exposure_s!r}, expected a positive number of seconds")
        if not _positive(self.gain):
            raise FrameError(f"{where}: gain = {self.gain!r}, expected a positive number")
        if self.data.ndim not in (2, 3):
            raise FrameError(f"{where}: data has shape {self.data.shape}, expected (H, W) or (H, W, C)")
        if self.data.size == 0:
            raise FrameError(f"{where}: data has shape {self.data.shape}: the frame holds no pixels")
        if self.kind == "raw" and self.data.ndim != 2:
            raise FrameError(f"{where}: a raw mosaic must be 2-D, got shape {self.data.shape}")
        if self.cfa_pattern is not None and (len(self.cfa_pattern) != 4 or set(self.cfa_pattern) - set("RGB")):
            raise FrameError(f"{where}: cfa_pattern = {self.cfa_pattern!r}, expected 4 letters of R, G, B")
        blacks = self.black_level if isinstance(self.black_level, tuple) else (self.black_level,)
        if any(not b < self.white_level for b in blacks):
            raise FrameError(
                f"{where}: black level {self.black_level!r} is not below white level {self.white_level!r}"
            )

    @property
    def shape(self) -> tuple[int, ...]:
        """Shape of the pixel data."""
        return tuple(self.data.shape)


def _positive(x: float) -> bool:
    """Finite and > 0 (a Python or numpy number)."""
    return bool(np.isfinite(x) and x > 0)


@dataclass(frozen=True)
class ExposureSettings:
    """What a camera actually applied: exposure in seconds and gain (may differ from the request)."""

    exposure_s: float
    gain: float = 1.0


@runtime_checkable
class Camera(Protocol):
    """A camera as the runner uses it: set exposure, capture, report what was used, close."""

    @property
    def identity(self) -> str:
        """Make, model and serial where known."""
        ...

    def set_exposure(self, exposure_s: float, gain: float | None = None) -> ExposureSettings:
        """Request an exposure in seconds (and a gain); return the settings the camera applied."""
        ...

    def capture(self) -> Frame:
        """Take one frame at the current settings."""
        ...

    def close(self) -> None:
        """Release the device."""
        ...
