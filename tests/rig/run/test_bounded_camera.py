"""BoundedCamera runs every call of a camera on one worker thread, in order, and lets that thread go."""

from __future__ import annotations

import gc
import threading
import time

import numpy as np
import pytest

from acquisition.frame import ExposureSettings, Frame
from rig.run.bounded_camera import BoundedCamera, CameraTimeout


class RecordingCamera:
    """A stand-in camera that notes which thread ran each call (the wrapper's behaviour is under test)."""

    identity = "recording camera"

    def __init__(self) -> None:
        self.calls: list[tuple[str, int]] = []
        self.block = threading.Event()
        self.block.set()

    def set_exposure(self, exposure_s: float, gain: float | None = None) -> ExposureSettings:
        self.calls.append(("set_exposure", threading.get_ident()))
        return ExposureSettings(exposure_s, gain or 1.0)

    def capture(self) -> Frame:
        self.calls.append(("capture", threading.get_ident()))
        self.block.wait()
        return Frame(np.zeros((2, 2)), "linear", 0.01)

    def close(self) -> None:
        self.calls.append(("close", threading.get_ident()))


def wait_until(done: object, what: str) -> None:
    deadline = time.monotonic() + 60.0
    while not done():  # type: ignore[operator]
        assert time.monotonic() < deadline, what
        threading.Event().wait(0.005)


def camera_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "camera calls"]


def test_calls_run_in_order_on_one_worker_thread_that_ends_on_close() -> None:
    before = set(camera_threads())
    inner = RecordingCamera()
    camera = BoundedCamera(inner)
    for t in (0.01, 0.02, 0.04):
        camera.set_exposure(t)
        camera.capture()
    camera.close()
    assert [c[0] for c in inner.calls] == ["set_exposure", "capture"] * 3 + ["close"]
    threads = {c[1] for c in inner.calls}
    assert len(threads) == 1 and threading.get_ident() not in threads
    wait_until(lambda: set(camera_threads()) <= before, "the worker did not end after close")


def test_a_dropped_camera_lets_its_worker_go() -> None:
    before = set(camera_threads())
    camera = BoundedCamera(RecordingCamera())
    camera.set_exposure(0.01)
    assert len(set(camera_threads()) - before) == 1
    del camera
    gc.collect()
    wait_until(lambda: set(camera_threads()) <= before, "the worker of a dropped camera is still running")


def test_a_hung_capture_times_out_and_the_camera_is_not_called_again() -> None:
    inner = RecordingCamera()
    camera = BoundedCamera(inner, exposure_factor=0.0)
    camera.set_exposure(0.01)
    inner.block.clear()
    camera.slack_s = 0.2  # only the capture that hangs gets a short deadline
    with pytest.raises(CameraTimeout, match=r"did not return within 0\.2 s"):
        camera.capture()
    with pytest.raises(CameraTimeout, match="refused"):
        camera.set_exposure(0.02)
    inner.block.set()
    assert [c[0] for c in inner.calls] == ["set_exposure", "capture"]
