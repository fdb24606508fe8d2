"""The run's ETA leaves out the kernel warm-up and the first point's one-time costs (wall time driven by hand)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

import rig.run.measuring.runner as runner_module
from acquisition.frame import Camera, Frame
from rig.run.measuring.progress import Eta, format_eta
from rig.run.measuring.runner import Runner
from rig.run.measuring.warm_up import kernels_cached, notify_before_compiling, warm_up
from rig.run.session import capture_settings, make_plan, manifest, options_for
from rig.run.storage.store import RunStore
from simulator.from_config import rig_from
from tests.run_helpers import FlakyCamera, in_plane_sweep, open_link, sim_rig


class Wall:
    """A wall clock that moves only when told to."""

    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t

    def advance(self, seconds: float) -> None:
        self.t += seconds


def test_the_estimate_uses_the_first_point_until_a_second_is_done_then_only_the_later_ones() -> None:
    wall = Wall()
    eta = Eta(wall)
    wall.advance(50.0)  # before start: not the run's
    eta.start(10)
    assert eta.remaining_s() is None and format_eta(None) == "ETA ?"
    wall.advance(12.0)  # the first point, with its one-time costs
    eta.point_done()
    assert eta.remaining_s() == pytest.approx(9 * 12.0)
    for _ in range(3):
        wall.advance(2.0)
        eta.point_done()
    assert eta.per_point_s() == pytest.approx(2.0)
    assert eta.remaining_s() == pytest.approx(6 * 2.0)
    assert format_eta(3725.4) == "ETA 1:02:05"


class SlowFirstCamera(FlakyCamera):
    """Passes captures through, costing 31 s of wall time for the first (a first render) and 1 s after."""

    def __init__(self, camera: Camera, wall: Wall) -> None:
        super().__init__(camera, {})
        self._wall = wall

    def capture(self) -> Frame:
        self._wall.advance(1.0 if self.captures else 31.0)
        return super().capture()


def test_the_runner_warms_up_before_the_first_point_and_its_eta_excludes_both(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    wall = Wall()
    warmed: list[float] = []

    def slow_warm_up(noise: Any) -> None:
        warmed.append(wall())
        wall.advance(100.0)  # a cold numba cache

    monkeypatch.setattr(runner_module, "warm_up", slow_warm_up)
    rig = sim_rig(reference={"kind": "none"})
    # Fixed exposures, no darks: one capture per point, so each point costs its capture's wall time.
    sweep = in_plane_sweep([20.0, 40.0], [10.0, 30.0, 50.0], exposures_s=[0.02], dark_frames=0)
    plan = make_plan(rig, sweep)
    options = options_for(rig, sweep, False)
    store = RunStore.create(tmp_path / "run", manifest(rig, sweep, plan, options))
    with rig_from(rig) as sim:
        assert sim.camera is not None
        camera = SlowFirstCamera(sim.camera, wall)
        runner = Runner(plan, store, open_link(sim, rig), camera, sim.clock, rig.geometry,
                        capture_settings(rig, sweep), options=options, wall_clock=wall)  # fmt: skip
        seen: list[float | None] = []
        done = runner.eta.point_done

        def point_done() -> None:
            done()
            seen.append(runner.eta.remaining_s())

        runner.eta.point_done = point_done  # type: ignore[method-assign]
        try:
            runner.run()
        finally:
            store.close()
    n = len(plan.points)
    assert n >= 4 and camera.captures == n and len(warmed) == 1
    assert runner.warm_up_s == pytest.approx(100.0)
    # After the first point: its own 31 s per point, not the warm-up's 100 s on top.
    assert seen[0] == pytest.approx((n - 1) * 31.0)
    # From the second point on: the later points' 1 s each, the first point's one-time cost left out.
    assert seen[1:] == pytest.approx([(n - k) * 1.0 for k in range(2, n + 1)])


def test_a_run_with_nothing_left_to_measure_does_not_warm_up(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[object] = []
    monkeypatch.setattr(runner_module, "warm_up", calls.append)
    rig = sim_rig(reference={"kind": "none"})
    sweep = in_plane_sweep([20.0], [10.0, 30.0], exposures_s=[0.02], dark_frames=0)
    plan = make_plan(rig, sweep)
    options = options_for(rig, sweep, False)
    store = RunStore.create(tmp_path / "run", manifest(rig, sweep, plan, options))
    with rig_from(rig) as sim:
        assert sim.camera is not None
        args = (plan, store, open_link(sim, rig), sim.camera, sim.clock, rig.geometry, capture_settings(rig, sweep))
        Runner(*args, options=options).run()
        assert len(calls) == 1
        Runner(*args, options=options).run()  # everything is in the journal: a resume with nothing to do
        assert len(calls) == 1
    store.close()


def test_the_compiled_passes_load_at_the_first_large_merge_after_the_notice_if_uncached(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import numpy as np

    import acquisition.hdr.kernel as kernel
    from acquisition.hdr.merge import merge_linear
    from acquisition.noise import SensorNoise

    noise = SensorNoise()

    def bracket(side: int) -> list[Frame]:
        data = np.full((side, side, 3), noise.black_level_dn + 300, dtype=np.uint16)
        data[0, 0] += 1
        return [Frame(data, "linear", t, black_level=noise.black_level_dn, white_level=noise.white_level_dn)
                for t in (0.01, 0.04)]  # fmt: skip

    shown: list[str] = []
    warm_up(noise)
    monkeypatch.setattr(kernel, "cached", lambda: False)  # as on a first run
    notify_before_compiling(lambda: shown.append("compiling"))
    merge_linear(bracket(8), noise)  # an ROI crop: the numpy pass, nothing to compile
    assert shown == []
    merge_linear(bracket(64), noise)  # 12288 values a frame: the compiled passes
    merge_linear(bracket(64), noise, weighting="inverse_variance")
    assert shown == ["compiling"]  # once
    monkeypatch.undo()
    shown.clear()
    notify_before_compiling(lambda: shown.append("compiling"))
    merge_linear(bracket(64), noise)
    assert shown == [] and kernels_cached()  # compiled with cache=True: the next process loads, not compiles
