"""A camera driven by vendor tethering software that drops each shot as a file into a folder.

Many still and scientific cameras are controlled best by their own software (Canon EOS Utility, Nikon
Camera Control, Capture One, smartshooter, a vendor SDK demo): it sets the exposure, fires the shutter
and writes RAW, DNG or TIFF files into a hot folder. ``TetheredFolderCamera`` watches that folder:
``capture()`` returns the next file that appears after the previous capture (files already there when
the camera was made are ignored), once it is completely written, decoded through ``read_frame`` and
checked against the requested exposure. The frame's ``extra["triggered_s"]`` is the camera clock's time (s)
when the shot was fired (the trigger run, or the shot request left): its exposure begins then, long before
the file has been written and found, which is when ``capture()`` returns.
"""

from __future__ import annotations

import fnmatch
import math
import os
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

from acquisition.cameras import CameraError, ClockLike, RealTimeClock
from acquisition.cameras.shot_request import withdraw_request, write_request
from acquisition.files.images import read_frame
from acquisition.files.metadata import DEFAULT_EXPOSURE_RTOL, ReadOptions, check_exposure
from acquisition.frame import ExposureSettings, Frame, FrameError

DEFAULT_PATTERNS: tuple[str, ...] = (
    "*.dng",
    "*.DNG",
    "*.tif",
    "*.tiff",
    "*.cr2",
    "*.cr3",
    "*.nef",
    "*.arw",
    "*.raf",
    "*.orf",
    "*.rw2",
    "*.pef",
    "*.kdc",
)
"""File patterns, matched case-insensitively; JPEGs are left out so RAW+JPEG shooting yields one frame per shot."""

Trigger = Callable[[ExposureSettings], None]
"""Tells the tethering software to take one shot with the given settings (e.g. a CLI call or a socket message)."""


class TetheredFolderCamera:
    """Frames from files that tethering software writes into ``folder``; exposures in seconds.

    Parameters
    ----------
    folder:
        The hot folder the tethering software writes into.
    pattern:
        Glob patterns of files to pick up, matched case-insensitively against file names.
    timeout_s:
        How long ``capture()`` waits for a new, complete file before raising TimeoutError.
    clock:
        Time source for polling and timestamps (``rig.instrument.clock`` clocks fit); real time by default.
    poll_interval_s:
        Time between two looks at the folder.
    trigger:
        Optional callable invoked at the start of each ``capture()`` with the requested settings, to
        make the tethering software shoot. Without it, something else (the software's own remote, a
        lab's script, a person, the rehearsal rig of ``gonio sim rig``) must shoot: each capture after a
        ``set_exposure`` leaves a shot request in the folder saying what to shoot
        (:mod:`acquisition.cameras.shot_request`), and waits for the file.
    stable_polls:
        A file counts as completely written when its size and modification time are the same on this
        many consecutive polls. Writers that write to a temporary name and rename (``write_dng`` does)
        are complete at once: 1 is enough for them.
    settle_s:
        A file that fails to decode is retried while it keeps changing; once it has been unchanged for
        this long the decode error is raised.
    exposure_rtol:
        Relative tolerance between the requested exposure (and gain) and what the file reports.
    accept_unconfirmed_exposure:
        If true, a file without exposure metadata is given the requested exposure
        (``extra["exposure_source"] == "caller"``); if false (default) it is a FrameError.

    Files are told apart by name, oldest (modification time) first: configure the tethering software
    to give every shot a new name (a counter), not to overwrite one file. A file that fails to decode
    or disagrees with the request is consumed, so the next ``capture()`` moves on to the next file.
    """

    def __init__(
        self,
        folder: str | os.PathLike[str],
        pattern: Sequence[str] = DEFAULT_PATTERNS,
        *,
        timeout_s: float = 30.0,
        clock: ClockLike | None = None,
        poll_interval_s: float = 0.1,
        trigger: Trigger | None = None,
        stable_polls: int = 2,
        settle_s: float = 2.0,
        exposure_rtol: float = DEFAULT_EXPOSURE_RTOL,
        accept_unconfirmed_exposure: bool = False,
    ) -> None:
        self.folder = Path(folder)
        if not self.folder.is_dir():
            raise FileNotFoundError(f"tethered camera: folder {self.folder} does not exist or is not a directory")
        if not (timeout_s > 0 and poll_interval_s > 0 and stable_polls >= 1 and settle_s >= 0):
            raise ValueError(
                f"tethered camera: timeout_s={timeout_s!r}, poll_interval_s={poll_interval_s!r}, "
                f"stable_polls={stable_polls!r}, settle_s={settle_s!r}: expected positive values (settle_s >= 0)"
            )
        self.patterns = tuple(p.lower() for p in pattern)
        self.timeout_s = float(timeout_s)
        self.poll_interval_s = float(poll_interval_s)
        self.clock: ClockLike = clock if clock is not None else RealTimeClock()
        self.trigger = trigger
        self.stable_polls = int(stable_polls)
        self.settle_s = float(settle_s)
        self.exposure_rtol = float(exposure_rtol)
        self.accept_unconfirmed_exposure = accept_unconfirmed_exposure
        self._requested: ExposureSettings | None = None
        self._requested_gain: float | None = None
        self._identity: str | None = None
        self._closed = False
        self._shots = 0
        self._fired_s = 0.0  # camera clock (s) when the last shot was fired
        self._seen: set[str] = {p.name for p in self._matching()}

    # -- Camera protocol -------------------------------------------------------------------------

    @property
    def identity(self) -> str:
        """Camera make and model from the last file's metadata, else the folder being watched."""
        return self._identity or f"tethered camera at {self.folder}"

    def set_exposure(self, exposure_s: float, gain: float | None = None) -> ExposureSettings:
        """Record the requested exposure (seconds) and gain; the tethering software applies them.

        Returns the request: what the camera really used is only known from the next file, and
        ``capture()`` checks it against this request.
        """
        if not (math.isfinite(exposure_s) and exposure_s > 0):
            raise ValueError(f"tethered camera at {self.folder}: exposure {exposure_s!r} s is not a positive number")
        if gain is not None and not (math.isfinite(gain) and gain > 0):
            raise ValueError(f"tethered camera at {self.folder}: gain {gain!r} is not a positive number")
        self._requested_gain = gain
        self._requested = ExposureSettings(float(exposure_s), 1.0 if gain is None else float(gain))
        return self._requested

    def capture(self) -> Frame:
        """Trigger (if configured) and return the next new, completely written file as a Frame.

        Raises TimeoutError naming the folder when no complete new file arrives within ``timeout_s``,
        and FrameError naming the file when it cannot be decoded or its exposure disagrees with the
        request.
        """
        if self._closed:
            raise CameraError(f"tethered camera at {self.folder} is closed")
        request: Path | None = None
        self._fired_s = self.clock.now()
        if self.trigger is not None:
            if self._requested is None:
                raise CameraError(f"tethered camera at {self.folder}: call set_exposure() before a triggered capture")
            self.trigger(self._requested)
        elif self._requested is not None:
            # Without a trigger something else shoots: tell it what (acquisition.cameras.shot_request).
            try:
                request = write_request(self.folder, self._requested, self._shots)
            except OSError as exc:
                raise CameraError(f"tethered camera: cannot leave a shot request in {self.folder}: {exc}") from exc
        self._shots += 1
        try:
            return self._wait_for_file()
        finally:
            if request is not None:
                withdraw_request(request)

    def _wait_for_file(self) -> Frame:
        """The next new, completely written file as a Frame (see ``capture``)."""
        start = self.clock.now()
        deadline = start + self.timeout_s
        # name -> (size, mtime_ns), consecutive identical observations
        observed: dict[str, tuple[tuple[int, int], int]] = {}
        failed: dict[str, tuple[tuple[int, int], float, FrameError]] = {}
        while True:
            for path in self._new_files():
                try:
                    st = path.stat()
                except FileNotFoundError:  # renamed or deleted between listing and stat
                    observed.pop(path.name, None)
                    continue
                state = (st.st_size, st.st_mtime_ns)
                previous = observed.get(path.name)
                count = previous[1] + 1 if previous and previous[0] == state else 1
                observed[path.name] = (state, count)
                if st.st_size == 0 or count < self.stable_polls:
                    break  # keep the order of arrival: wait for this file before looking at later ones
                if path.name in failed:
                    failed_state, failed_at, error = failed[path.name]
                    if failed_state == state:
                        if self.clock.now() - failed_at >= self.settle_s:
                            self._seen.add(path.name)
                            raise error
                        break
                try:
                    fallback = None if self._requested is None else self._requested.exposure_s
                    frame = read_frame(path, ReadOptions(exposure_s=fallback, timestamp_s=self.clock.now()))
                except FrameError as exc:
                    failed[path.name] = (state, self.clock.now(), exc)
                    break
                self._seen.add(path.name)
                return self._accept(frame, path)
            now = self.clock.now()
            if now >= deadline:
                raise TimeoutError(
                    f"tethered camera: no new complete file matching {', '.join(self.patterns)} appeared in "
                    f"{self.folder} after waiting {now - start:.3g} s (timeout {self.timeout_s:g} s)"
                )
            self.clock.sleep(self.poll_interval_s)

    def close(self) -> None:
        """Stop using the folder (files are left where they are)."""
        self._closed = True

    # -- helpers ---------------------------------------------------------------------------------

    def discard_pending(self) -> list[Path]:
        """Mark every matching file now in the folder as seen, so the next capture waits for a newer one."""
        pending = self._new_files()
        self._seen.update(p.name for p in pending)
        return pending

    def _matching(self) -> list[Path]:
        try:
            entries = list(os.scandir(self.folder))
        except OSError as exc:
            raise CameraError(f"tethered camera: cannot list folder {self.folder}: {exc}") from exc
        out = []
        for entry in entries:
            name = entry.name
            if name.startswith((".", "~")) or not entry.is_file():
                continue  # hidden and lock files are where writers stage data before renaming
            if any(fnmatch.fnmatchcase(name.lower(), p) for p in self.patterns):
                out.append(Path(entry.path))
        return out

    def _new_files(self) -> list[Path]:
        """Unseen matching files, oldest first (modification time, then name)."""
        stamped = []
        for path in self._matching():
            if path.name in self._seen:
                continue
            try:
                stamped.append((path.stat().st_mtime_ns, path.name, path))
            except FileNotFoundError:
                continue
        return [p for _, _, p in sorted(stamped)]

    def _accept(self, frame: Frame, path: Path) -> Frame:
        where = f"tethered camera at {self.folder}: {path}"
        extra = dict(frame.extra)
        if self._requested is not None:
            if extra.get("exposure_source") == "caller" and not self.accept_unconfirmed_exposure:
                raise FrameError(
                    f"{where}: the file has no exposure time, so the requested {self._requested.exposure_s:.6g} s "
                    "cannot be confirmed (pass accept_unconfirmed_exposure=True to trust the request)"
                )
            check_exposure(frame.exposure_s, self._requested.exposure_s, where, self.exposure_rtol)
            if self._requested_gain is not None and extra.get("iso"):
                if abs(frame.gain - self._requested_gain) > self.exposure_rtol * self._requested_gain:
                    raise FrameError(
                        f"{where}: gain {frame.gain:.4g} (ISO {extra['iso']:g}) in the file disagrees with the "
                        f"requested gain {self._requested_gain:.4g}"
                    )
            extra["requested_exposure_s"] = self._requested.exposure_s
        elif extra.get("exposure_source") == "caller":
            raise FrameError(f"{where}: the file has no exposure time and none was requested")
        extra["triggered_s"] = self._fired_s
        camera_id = frame.camera_id
        if camera_id == "unknown":
            camera_id = f"tethered camera at {self.folder}"
        else:
            self._identity = camera_id
        return replace(frame, camera_id=camera_id, extra=extra)
