"""BoundedCamera runs every call of a camera on one worker thread, in order, and lets that thread go."""

from __future__ import annotations

import gc
import threading
import time

import numpy as np
import pytest

from acquisition.frame import ExposureSettings, Frame
from rig.run.backends.bounded_camera import BoundedCamera, CameraError, CameraTimeout


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


class DarkCamera(RecordingCamera):
    """A recording camera with dark frames, whose set_exposure can be made to answer wrongly."""

    answer: object = None

    def set_exposure(self, exposure_s: float, gain: float | None = None) -> ExposureSettings:
        applied = super().set_exposure(exposure_s * 2, gain)  # a camera that applies what it can, not what was asked
        return applied if self.answer is None else self.answer  # type: ignore[return-value]

    def capture_dark(self) -> Frame:
        self.calls.append(("capture_dark", threading.get_ident()))
        return Frame(np.ones((2, 2)), "linear", 0.01)


def test_exposed_frames_makes_the_same_calls_in_one_hand_off() -> None:
    inner = DarkCamera()
    camera = BoundedCamera(inner)
    applied, frames = camera.exposed_frames(0.01)
    assert applied.exposure_s == 0.02 and len(frames) == 1 and not frames[0].data.any()
    applied, darks = camera.exposed_frames(0.04, 3, dark=True)
    assert applied.exposure_s == 0.08 and [f.data.sum() for f in darks] == [4.0] * 3
    assert [c[0] for c in inner.calls] == ["set_exposure", "capture", "set_exposure"] + ["capture_dark"] * 3
    assert len({c[1] for c in inner.calls}) == 1 and threading.get_ident() not in {c[1] for c in inner.calls}
    camera.close()


def test_exposed_frames_refuses_a_wrong_answer_before_any_frame() -> None:
    inner = DarkCamera()
    inner.answer = "ok"
    camera = BoundedCamera(inner)
    with pytest.raises(CameraError, match="set_exposure returned 'ok'"):
        camera.exposed_frames(0.01, 2, dark=True)
    assert [c[0] for c in inner.calls] == ["set_exposure"]
    camera.close()


def test_a_hung_exposed_frame_times_out() -> None:
    inner = RecordingCamera()
    camera = BoundedCamera(inner, slack_s=0.2, exposure_factor=0.0)
    inner.block.clear()
    with pytest.raises(CameraTimeout, match=r"did not return within 0\.2 s"):
        camera.exposed_frames(0.01)
    with pytest.raises(CameraTimeout, match="refused"):
        camera.exposed_frames(0.01)
    inner.block.set()


class SlowCamera(RecordingCamera):
    """A camera whose every capture takes ``capture_s`` of wall time, and whose n-th capture hangs."""

    def __init__(self, capture_s: float, hang_at: int | None = None) -> None:
        super().__init__()
        self.capture_s, self.hang_at = capture_s, hang_at

    def capture(self) -> Frame:
        self.calls.append(("capture", threading.get_ident()))
        if sum(c[0] == "capture" for c in self.calls) == self.hang_at:
            self.block.clear()
            self.block.wait()
        threading.Event().wait(self.capture_s)  # the camera's own time, not a test waiting on it
        return Frame(np.zeros((2, 2)), "linear", 0.01)


def test_each_call_of_a_batch_keeps_its_own_deadline() -> None:
    # Three captures of 1 s each under a 2 s slack: one at a time each is well within its deadline, so a batch of
    # them must be too (a deadline for the batch as a whole would end it at 2 s, in the second capture).
    camera = BoundedCamera(SlowCamera(1.0), slack_s=2.0, exposure_factor=0.0)
    applied, frames = camera.exposed_frames(0.01, 3)
    assert applied.exposure_s == 0.01 and len(frames) == 3
    answers = camera.exposed_series([(0.01, 2), (0.02, 1)])
    assert [len(taken) for _, taken in answers] == [2, 1]
    camera.close()


def test_a_hung_call_inside_a_batch_is_named() -> None:
    inner = SlowCamera(0.0, hang_at=2)
    camera = BoundedCamera(inner, slack_s=0.2, exposure_factor=0.0)
    with pytest.raises(CameraTimeout, match=r"capture 2 of 3 did not return within 0\.2 s"):
        camera.exposed_frames(0.01, 3)
    with pytest.raises(CameraTimeout, match=r"refused: an earlier call \(capture 2 of 3\)"):
        camera.exposed_frames(0.01)
    inner.block.set()


class ScriptedCamera(DarkCamera):
    """A dark camera whose n-th set_exposure or dark frame answers as scripted (a wrong type, an error)."""

    def __init__(self, bad_exposure: int | None = None, bad_dark: int | None = None, fail_dark: int | None = None):
        super().__init__()
        self.bad_exposure, self.bad_dark, self.fail_dark = bad_exposure, bad_dark, fail_dark
        self.n_exposures = self.n_darks = 0

    def set_exposure(self, exposure_s: float, gain: float | None = None) -> ExposureSettings:
        self.n_exposures += 1
        applied = super().set_exposure(exposure_s, gain)
        return "no" if self.n_exposures == self.bad_exposure else applied  # type: ignore[return-value]

    def capture_dark(self) -> Frame:
        self.n_darks += 1
        frame = super().capture_dark()
        if self.n_darks == self.fail_dark:
            raise OSError("the camera went away")
        return "not a frame" if self.n_darks == self.bad_dark else frame  # type: ignore[return-value]


def one_by_one(camera: BoundedCamera, requests: list[tuple[float, int]]) -> list[tuple[ExposureSettings, list[Frame]]]:
    return [camera.exposed_frames(t, n, dark=True) for t, n in requests]


def outcome(make: object, requests: list[tuple[float, int]], series: bool) -> tuple[object, list[str], int]:
    inner = make()  # type: ignore[operator]
    camera = BoundedCamera(inner)
    submitted = 0
    submit = camera._submit

    def counting(job: object) -> None:
        nonlocal submitted
        submitted += 1
        submit(job)  # type: ignore[arg-type]

    camera._submit = counting  # type: ignore[method-assign]
    try:
        answers = camera.exposed_series(requests, dark=True) if series else one_by_one(camera, requests)
        result: object = [(a.exposure_s, [f.data.sum() for f in frames]) for a, frames in answers]
    except (CameraError, OSError) as exc:
        result = (type(exc), str(exc))
    finally:
        camera.close()
    return result, [c[0] for c in inner.calls], submitted


@pytest.mark.parametrize("make", [ScriptedCamera, lambda: ScriptedCamera(bad_exposure=2),
                                  lambda: ScriptedCamera(bad_exposure=1), lambda: ScriptedCamera(bad_dark=2),
                                  lambda: ScriptedCamera(bad_dark=3), lambda: ScriptedCamera(fail_dark=2)])  # fmt: skip
def test_exposed_series_makes_the_calls_of_one_exposure_at_a_time(make: object) -> None:
    requests = [(0.01, 2), (0.04, 1), (0.1, 2)]
    series, alone = outcome(make, requests, True), outcome(make, requests, False)
    assert series[:2] == alone[:2]  # the same answers or errors, the same camera calls
    # one hand-off for the series (and one for close), against one an exposure reached
    assert series[2] == 2 and alone[2] == 1 + alone[1].count("set_exposure")
