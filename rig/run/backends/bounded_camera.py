"""Every wait on the camera is bounded: a capture that never returns becomes a camera fault, not a hung run.

A camera backend talks to hardware (USB, GigE, a tethering folder) and can block forever or hand back
nothing. ``BoundedCamera`` wraps any ``Camera`` and runs each call in a worker thread that the runner
waits on for at most a deadline: the exposure being taken (``exposure_factor`` times it, for the readout
and transfer of long frames) plus ``slack_s``. A call past its deadline raises ``CameraTimeout``; a
capture that returns something other than a ``Frame`` raises ``CameraError``. Both are camera faults to
the runner, which then leaves the rig safe (exit 4).

The deadline is wall time, as it must be for a real device; ``slack_s`` is generous (a minute by
default) so that a loaded host never turns into a camera fault. A thread left blocked in a dead driver is
a daemon: it cannot keep the process from exiting, and after a timeout the camera is not called again.

One worker thread serves all calls of a camera, in order (starting a thread per call was slow on a loaded host,
with several calls a point); it ends when the camera is closed or dropped.
"""

from __future__ import annotations

import queue
import threading
import time
import weakref
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from acquisition.frame import Camera, ExposureSettings, Frame
from model.errors import CameraFault

T = TypeVar("T")


class CameraError(CameraFault, RuntimeError):
    """The camera answered with something that is not what was asked for (no frame, a wrong type)."""


class CameraTimeout(CameraError):
    """A camera call did not return within its deadline; the camera is not used again."""


class BoundedCamera:
    """A ``Camera`` whose every call returns within a deadline derived from the exposure (see the module doc)."""

    def __init__(self, camera: Camera, *, slack_s: float = 60.0, exposure_factor: float = 2.0) -> None:
        if not slack_s > 0:
            raise ValueError(f"slack_s = {slack_s!r}: expected a positive number of seconds")
        self._camera = camera
        self.slack_s = float(slack_s)
        self.exposure_factor = float(exposure_factor)
        self._exposure_s = 0.0
        self._dead: str | None = None
        # The camera call running now: its name, its exposure (s), when it started (monotonic s).
        self._now: tuple[str, float, float] = ("", 0.0, 0.0)
        self._jobs: queue.SimpleQueue[Callable[[], None] | None] = queue.SimpleQueue()
        self._worker: threading.Thread | None = None

    @property
    def wrapped(self) -> Camera:
        """The camera whose calls this one bounds (its own settings, e.g. the simulated camera's full_frame)."""
        return self._camera

    def _submit(self, job: Callable[[], None]) -> None:
        if self._worker is None:
            # The thread holds the queue only, never self, so a dropped camera is collected and its
            # finaliser tells the thread to end.
            self._worker = threading.Thread(target=_serve, args=(self._jobs,), name="camera calls", daemon=True)
            self._worker.start()
            weakref.finalize(self, self._jobs.put, None)
        self._jobs.put(job)

    @property
    def identity(self) -> str:
        """The wrapped camera's identity."""
        return self._camera.identity

    def _call(self, what: str, call: Callable[[], T], exposure_s: float = 0.0) -> T:
        if self._dead is not None:
            raise CameraTimeout(f"{self._camera.identity}: {what} refused: {self._dead}")
        box: dict[str, Any] = {}
        # A plain lock, held until the worker releases it: cheaper than an Event (no condition, no waiter list),
        # several times a point on the controller's thread.
        done = threading.Lock()
        done.acquire()

        def work() -> None:
            try:
                box["value"] = call()
            except BaseException as exc:  # handed to the waiting thread, which raises it
                box["error"] = exc
            finally:
                done.release()

        self._now = (what, exposure_s, time.monotonic())
        self._submit(work)
        while True:
            name, exposed_s, since = self._now  # one read: the worker may move it on meanwhile
            deadline = self.slack_s + self.exposure_factor * exposed_s
            left = since + deadline - time.monotonic()
            if done.acquire(timeout=min(max(left, 0.0), threading.TIMEOUT_MAX)):
                break
            if self._now[2] == since:  # the same camera call is still running, past its deadline
                self._dead = f"an earlier call ({name}) did not return within {deadline:g} s"
                raise CameraTimeout(
                    f"{self._camera.identity}: {name} did not return within {deadline:g} s (exposure {exposed_s:g} "
                    f"s + {self.slack_s:g} s slack): the camera or its driver hangs; check its cable and power"
                )
        if "error" in box:
            raise box["error"]
        return box["value"]

    def _step(self, what: str, exposure_s: float = 0.0) -> None:
        """The worker starts the next camera call of a batch: it gets a deadline of its own (exposure in s)."""
        self._now = (what, exposure_s, time.monotonic())

    def set_exposure(self, exposure_s: float, gain: float | None = None) -> ExposureSettings:
        """Set the exposure (s); returns what the camera applied."""
        applied = self._call("set_exposure", lambda: self._camera.set_exposure(exposure_s, gain))
        if not isinstance(applied, ExposureSettings):
            raise CameraError(f"{self._camera.identity}: set_exposure returned {applied!r}, not ExposureSettings")
        self._exposure_s = float(applied.exposure_s)
        return applied

    def capture(self) -> Frame:
        """One frame at the exposure set, within the deadline."""
        return self._frame("capture", self._camera.capture)

    def exposed_frames(
        self, exposure_s: float, frames: int = 1, *, dark: bool = False
    ) -> tuple[ExposureSettings, list[Frame]]:
        """Set the exposure (s) and take ``frames`` frames (dark ones with ``dark``): what was applied, the frames.

        The same camera calls as ``set_exposure`` then ``capture`` (or ``capture_dark``) each time, in one
        hand-off to the worker instead of 1 + ``frames``: each wake-up of the waiting thread costs the controller's
        thread. Each of those calls keeps its own deadline, as if made one at a time.
        """
        take = self._camera.capture_dark if dark else self._camera.capture  # type: ignore[attr-defined]
        what = "capture_dark" if dark else "capture"

        def work() -> tuple[object, list[object]]:
            applied = self._camera.set_exposure(exposure_s, None)
            if not isinstance(applied, ExposureSettings):
                return applied, []  # refused below, before any frame is taken (as set_exposure does)
            self._exposure_s = float(applied.exposure_s)
            return applied, [self._take(take, what, i, frames) for i in range(frames)]

        applied, taken = self._call("set_exposure", work)
        if not isinstance(applied, ExposureSettings):
            raise CameraError(f"{self._camera.identity}: set_exposure returned {applied!r}, not ExposureSettings")
        for frame in taken:
            if not isinstance(frame, Frame):
                raise CameraError(f"{self._camera.identity}: {what} returned {frame!r} instead of a Frame")
        return applied, taken  # type: ignore[return-value]

    def exposed_series(
        self, requests: Sequence[tuple[float, int]], *, dark: bool = False
    ) -> list[tuple[ExposureSettings, list[Frame]]]:
        """``exposed_frames(t, n, dark=dark)`` for each (t in seconds, n) in order, in one hand-off to the worker.

        The same camera calls in the same order, stopping where the sequence of calls would have stopped
        (a wrong answer to set_exposure, a capture that is not a Frame, an exception), and the same errors.
        A point's darks at two exposures took two hand-offs, each a wake-up of the controller's thread.
        Each of those calls keeps its own deadline, as if made one at a time.
        """
        take = self._camera.capture_dark if dark else self._camera.capture  # type: ignore[attr-defined]
        what = "capture_dark" if dark else "capture"

        def work() -> list[tuple[object, list[object]]]:
            done: list[tuple[object, list[object]]] = []
            for k, (exposure_s, frames) in enumerate(requests):
                if k:
                    self._step("set_exposure")
                applied = self._camera.set_exposure(exposure_s, None)
                if not isinstance(applied, ExposureSettings):
                    done.append((applied, []))
                    break
                self._exposure_s = float(applied.exposure_s)
                taken = [self._take(take, what, i, frames) for i in range(frames)]
                done.append((applied, taken))
                if not all(isinstance(frame, Frame) for frame in taken):
                    break
            return done

        answers = self._call("set_exposure", work)
        for applied, taken in answers:
            if not isinstance(applied, ExposureSettings):
                raise CameraError(f"{self._camera.identity}: set_exposure returned {applied!r}, not ExposureSettings")
            for frame in taken:
                if not isinstance(frame, Frame):
                    raise CameraError(f"{self._camera.identity}: {what} returned {frame!r} instead of a Frame")
        return answers  # type: ignore[return-value]

    def _take(self, take: Callable[[], object], what: str, i: int, frames: int) -> object:
        """Frame ``i`` of ``frames`` of a batch, on the worker, under a deadline of its own."""
        self._step(f"{what} {i + 1} of {frames}" if frames > 1 else what, self._exposure_s)
        return take()

    def __getattr__(self, name: str) -> Any:
        # capture_dark exists only where the wrapped camera has it (the runner asks with getattr).
        if name.startswith("_"):
            raise AttributeError(name)
        found = getattr(self._camera, name)
        if name == "capture_dark":
            return lambda: self._frame("capture_dark", found)
        return found

    def _frame(self, what: str, take: Callable[[], Frame]) -> Frame:
        frame = self._call(what, take, self._exposure_s)
        if not isinstance(frame, Frame):
            raise CameraError(f"{self._camera.identity}: {what} returned {frame!r} instead of a Frame")
        return frame

    def close(self) -> None:
        """Close the wrapped camera (within the slack; a hung close is left to its daemon thread)."""
        if self._dead is None:
            try:
                self._call("close", self._camera.close)
            finally:
                self._jobs.put(None)  # the worker ends once the close (and anything before it) is done
                self._jobs, self._worker = queue.SimpleQueue(), None  # a call after close gets a new one


def _serve(jobs: queue.SimpleQueue[Callable[[], None] | None]) -> None:
    """Run camera calls in order until told to stop (None)."""
    while True:
        job = jobs.get()
        if job is None:
            return
        job()
        del job  # the call's closure holds the camera: a dropped camera must be collectable while we wait
