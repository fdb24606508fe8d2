"""How an adaptive sweep spends its captures: budget, rounds, candidates, and the capture mode dials."""

from __future__ import annotations

import math
from dataclasses import dataclass

#: The capture mode dials' values: the sweep file's [capture] mode (and "auto") and motion.
MODES = ("point", "image", "auto")
MOTIONS = ("stop", "continuous")
#: The sweep file's bounds on tile_px (pixels) and scan_speed_deg_s (deg/s), rig/run/config/schema.py Capture.
MAX_TILE_PX = 512
MAX_SCAN_SPEED_DEG_S = 30.0


@dataclass(frozen=True)
class AdaptiveSettings:
    """How an adaptive sweep spends its captures.

    budget: captures (poses) in all; initial: captures of the first (space-filling) round; batch: captures per
    later round; candidates: pool size before the reachability filter; max_theta_deg: largest zenith
    (deg) of candidates and of the error pairs; target_snr: the SNR goal of each sample (a point's reading, or
    in image mode each tile's); reference_snr: the reference readings' SNR goal (None: the rig's
    ``[reference] target_snr``); seed: pool and fits.

    The capture mode dials mean what the sweep file's ``[capture]`` keys of the same names mean: ``mode``
    "point" or "image" for every round, or "auto" (``rig.run.adaptive.modes``: the first round in image mode
    where the camera resolves the sample into many tiles, later rounds in point mode, either continuous where
    a round's plan has long scan runs and ``motion`` allows it); ``tile_px`` image mode's tile side (pixels,
    None: the default); ``motion`` "stop" or "continuous"; ``scan_speed_deg_s`` the scanning joint's speed
    (deg/s, None: the default). A capture is one pose: in image mode it gives one sample per tile, and the
    budget still counts captures.

    Each round is its own run with a reference reading before and after, so a sweep of 100 takes about 18
    readings where one run of 1000 at ``every = 25`` takes 42. A matte sample's fit is one scale per channel,
    i.e. all calibration: the references need SNR x sqrt(42 / 18) to calibrate as well as that long run.
    """

    budget: int = 100
    initial: int = 20
    batch: int = 10
    candidates: int = 6000
    max_theta_deg: float = 70.0
    target_snr: float = 100.0
    reference_snr: float | None = None
    starts: int = 4
    seed: int = 0
    mode: str = "point"
    tile_px: int | None = None
    motion: str = "stop"
    scan_speed_deg_s: float | None = None

    def __post_init__(self) -> None:
        if not 1 <= self.initial <= self.budget or self.batch < 1 or self.candidates < self.budget:
            raise ValueError(
                f"adaptive settings: need 1 <= initial ({self.initial}) <= budget ({self.budget}), batch "
                f"({self.batch}) >= 1 and candidates ({self.candidates}) >= budget"
            )
        if not 0.0 < self.max_theta_deg <= 90.0:
            raise ValueError(f"adaptive settings: max_theta_deg ({self.max_theta_deg}) must be a zenith in (0, 90]")
        if not self.target_snr > 0 or (self.reference_snr is not None and not self.reference_snr > 0):
            raise ValueError(f"adaptive settings: target_snr ({self.target_snr}) and reference_snr "
                             f"({self.reference_snr}) must be > 0")  # fmt: skip
        self._check_modes()

    def _check_modes(self) -> None:
        """The capture mode dials, by the sweep file's rules (rig/run/config/schema.py Capture)."""
        if self.mode not in MODES:
            raise ValueError(f"adaptive settings: mode = {self.mode!r}: expected one of {', '.join(MODES)}")
        if self.motion not in MOTIONS:
            raise ValueError(f"adaptive settings: motion = {self.motion!r}: expected one of {', '.join(MOTIONS)}")
        if self.tile_px is not None:
            whole = isinstance(self.tile_px, int) and not isinstance(self.tile_px, bool)
            if not (whole and 1 <= self.tile_px <= MAX_TILE_PX):
                raise ValueError(f"adaptive settings: tile_px = {self.tile_px!r}: expected a whole number of pixels "
                                 f"from 1 to {MAX_TILE_PX}")  # fmt: skip
            if self.mode == "point":
                raise ValueError(f"adaptive settings: tile_px = {self.tile_px} has no meaning with mode = 'point' "
                                 "(each capture reads the camera's ROI): use mode 'image' or 'auto'")  # fmt: skip
        if self.scan_speed_deg_s is not None:
            v = self.scan_speed_deg_s
            if not (math.isfinite(v) and 0.0 < v <= MAX_SCAN_SPEED_DEG_S):
                raise ValueError(f"adaptive settings: scan_speed_deg_s = {v!r}: expected deg/s > 0 and at most "
                                 f"{MAX_SCAN_SPEED_DEG_S:g}")  # fmt: skip
            if self.motion != "continuous":
                raise ValueError(f"adaptive settings: scan_speed_deg_s = {v:g} has no meaning with motion = "
                                 f"{self.motion!r} (every capture at rest): use motion 'continuous'")  # fmt: skip
