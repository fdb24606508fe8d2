"""The runner end to end on the simulated rig: known materials measured, faults survived or stopped safely.

Every test that moves, references, stops or faults runs on both links the simulated rig has: virtual
Dynamixel servos and a virtual GRBL controller (``link``); each fault has its GRBL counterpart.

One file past 400 lines on purpose: it mirrors one module, ``rig.run.measuring.runner``.
"""

from __future__ import annotations

import dataclasses
import json
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rig.run.config.files import RigConfig, SweepConfig, parse, sweep_config
from rig.run.config.schema import SweepFile
from rig.run.measuring.runner import DriftWarning, Runner, RunStopped
from rig.run.session import (
    capture_settings,
    make_plan,
    manifest,
    options_for,
    reference_settings,
    start_run,
)
from rig.run.storage.store import RunStore, RunStoreError
from rig.run.tables.samples import build_rows
from simulator.from_config import rig_from, spec_from
from simulator.grbl_rig import SimulatedGrblRig
from simulator.rig import SimulatedRig
from tests.run_helpers import (
    GOLD,
    LINKS,
    FlakyCamera,
    in_plane_sweep,
    left_safe,
    open_link,
    read_rows,
    run_outcome,
    sim_rig,
    truth_and_measured,
)

pytestmark = pytest.mark.mitsuba


@pytest.fixture(params=LINKS)
def link(request: pytest.FixtureRequest) -> str:
    """What moves the simulated joints: virtual Dynamixel servos or a virtual GRBL controller."""
    return str(request.param)


def test_a_sweep_measures_a_lambertian_sample_within_its_uncertainty(tmp_path: Path, link: str) -> None:
    rig = sim_rig(on=link)
    sweep = in_plane_sweep([20.0, 50.0], [-60.0, -30.0, 0.0, 30.0, 60.0])
    summary = start_run(rig, sweep, tmp_path / "run", progress=False)
    rows = read_rows(summary.table)
    assert len(rows) == summary.measured == 10
    truth, got, se = truth_and_measured(rows, rig)
    np.testing.assert_allclose(truth, 0.5 / np.pi)
    z = (got - truth) / se
    assert np.all(np.abs(z) < 4.5), z
    assert np.median(np.abs(got / truth - 1)) < 0.01
    store = RunStore.read(tmp_path / "run")
    kinds = [r["kind"] for r in store.records()]
    assert kinds.count("point") == 10 and kinds.count("reference") == 3  # before, after 6 points, at the end
    assert store.status()["state"] == "finished"
    assert store.manifest["sweep"]["sweep"]["kind"] == "in_plane"


def test_a_rough_metal_matches_its_model_away_from_the_specular_peak(tmp_path: Path, link: str) -> None:
    rig = sim_rig(GOLD, on=link)
    sweep = in_plane_sweep([40.0], [-70.0, -50.0, -20.0, 0.0, 15.0, 60.0, 75.0])
    rows = read_rows(start_run(rig, sweep, tmp_path / "run", progress=False).table)
    truth, got, se = truth_and_measured(rows, rig)
    assert np.all(np.abs(got - truth) < 4.5 * se), (got - truth) / se
    # The measured angles are the read-back, not the plan's: servo ticks of 0.088 deg or steps of 0.1125 deg show.
    target = np.array([float(r["target_theta_o_deg"]) for r in rows])
    measured = np.array([float(r["theta_o_deg"]) for r in rows])
    assert np.all(np.abs(measured - target) < 0.2) and np.any(measured != target)


def _run(
    tmp_path: Path,
    rig: RigConfig,
    sweep: SweepConfig,
    actions: Callable[[SimulatedRig], dict[int, Callable[[], None]]] | None = None,
    *,
    drift_per_s: float = 0.0,
) -> tuple[RunStore, SimulatedRig, Any]:
    """Run with a camera that misbehaves on cue: the (closed) store, the rig, and (outcome, whether left safe)."""
    plan = make_plan(rig, sweep)
    spec = spec_from(rig)
    if drift_per_s:
        from dataclasses import replace

        spec = replace(spec, light_drift_per_s=drift_per_s)
    store = RunStore.create(tmp_path / "run", manifest(rig, sweep, plan, options_for(rig, sweep, False)))
    with rig_from(rig, spec=spec) as sim:
        assert sim.camera is not None
        camera = FlakyCamera(sim.camera, actions(sim) if actions else {})
        outcome: Any = run_outcome(sim, rig, sweep, plan, store, camera)
        safe = left_safe(sim)
    return RunStore.read(tmp_path / "run"), sim, (outcome, safe)


SWEEP = ([10.0, 45.0], [-30.0, 20.0, 50.0])  # 6 points, fixed exposures keep the capture count predictable


def _sweep() -> SweepConfig:
    return in_plane_sweep(*SWEEP, exposures_s=[0.02], dark_frames=0)


def test_a_camera_error_once_is_retried_and_the_run_completes(tmp_path: Path, link: str) -> None:
    def fail() -> None:
        raise OSError("USB transfer failed")

    store, _, (outcome, safe) = _run(tmp_path, sim_rig(on=link), _sweep(), lambda sim: {4: fail})
    assert not isinstance(outcome, RunStopped)
    events = [r for r in store.records() if r["kind"] == "event"]
    assert [e["event"] for e in events] == ["camera_error"] and "USB transfer failed" in events[0]["message"]
    assert len(read_rows(outcome.table)) == 6
    assert safe  # shut down with torque off (the default policy), or GRBL idle


def test_a_camera_that_keeps_failing_stops_the_run_safely_and_keeps_the_points(tmp_path: Path, link: str) -> None:
    def fail() -> None:
        raise RuntimeError("camera disconnected")

    # Capture 1 is the first reference; captures 2..4 the first three points; 5 on all fail.
    failing = dict.fromkeys(range(5, 20), fail)
    store, _, (outcome, safe) = _run(tmp_path, sim_rig(on=link), _sweep(), lambda sim: failing)
    assert isinstance(outcome, RunStopped) and outcome.cause == "camera"
    assert len([r for r in store.records() if r["kind"] == "point"]) == 3
    assert store.status()["state"] == "stopped" and "camera disconnected" in store.status()["reason"]
    assert safe


def test_ctrl_c_stops_motion_and_the_journal_keeps_every_point(tmp_path: Path, link: str) -> None:
    def interrupt() -> None:
        raise KeyboardInterrupt

    store, _, (outcome, safe) = _run(tmp_path, sim_rig(on=link), _sweep(), lambda sim: {3: interrupt})
    assert isinstance(outcome, RunStopped) and outcome.cause == "interrupted"
    assert len([r for r in store.records() if r["kind"] == "point"]) == 1
    assert "interrupted" in store.status()["reason"]
    assert safe


def test_hold_policy_keeps_torque_on_when_a_run_stops(tmp_path: Path) -> None:
    # Dynamixel only: whether idle steppers stay energised is GRBL's own setting ($1), not the run's.
    def interrupt() -> None:
        raise KeyboardInterrupt

    rig = sim_rig(link={"on_stop": "hold"})
    _, sim, (outcome, safe) = _run(tmp_path, rig, _sweep(), lambda sim: {3: interrupt})
    assert isinstance(outcome, RunStopped) and not safe
    assert sim.bus is not None and all(sim.bus.servo(int(a.address)).torque_enabled for a in sim.axes)


def _overload(sim: SimulatedRig) -> Callable[[], None]:
    """A joint's drive gives up: a servo shuts down on overload, a GRBL limit switch trips (ALARM:1)."""

    def fault() -> None:
        if isinstance(sim, SimulatedGrblRig):
            sim.controller.trip_hard_limit()
        else:
            sim.bus.servo(2).inject_hardware_error(0x20)  # type: ignore[union-attr]

    return fault


def test_a_servo_overload_mid_run_is_a_hardware_stop(tmp_path: Path, link: str) -> None:
    # On GRBL the counterpart is a limit switch tripping mid-run.
    store, _, (outcome, safe) = _run(tmp_path, sim_rig(on=link), _sweep(), lambda sim: {3: _overload(sim)})
    assert isinstance(outcome, RunStopped) and outcome.cause == "hardware"
    assert ("hard limit" if link == "grbl" else "overload") in str(outcome).lower(), outcome
    assert len([r for r in store.records() if r["kind"] == "point"]) == 2  # the capture of point 2 completed
    assert safe


def test_a_servo_overload_is_recovered_when_the_rig_allows_reboots(tmp_path: Path) -> None:
    rig = sim_rig(link={"allow_reboot": True})  # Dynamixel only: a GRBL alarm is never cleared behind a run's back
    _, _, (outcome, _) = _run(tmp_path, rig, _sweep(), lambda sim: {3: _overload(sim)})
    assert not isinstance(outcome, RunStopped), outcome
    assert len(read_rows(outcome.table)) == 6


def test_lost_replies_are_retried_by_the_link(tmp_path: Path, link: str) -> None:
    def lossy(sim: SimulatedRig) -> dict[int, Callable[[], None]]:
        def drop() -> None:
            if isinstance(sim, SimulatedGrblRig):
                sim.controller.drop_status_reports(1)
            else:
                sim.bus.servo(1).faults.drop_replies = 1  # type: ignore[union-attr]

        return {2: drop, 4: drop}

    _, _, (outcome, _) = _run(tmp_path, sim_rig(on=link), _sweep(), lossy)
    assert not isinstance(outcome, RunStopped), outcome


def test_a_stalled_joint_times_out_twice_and_stops_the_run(tmp_path: Path, link: str) -> None:
    def stall(sim: SimulatedRig) -> dict[int, Callable[[], None]]:
        def block() -> None:
            if isinstance(sim, SimulatedGrblRig):
                sim.controller.stall()  # a stepper losing steps against a jam: GRBL stays in Run
            else:
                sim.bus.servo(1).faults.stall_short_ticks = 40  # type: ignore[union-attr]

        return {2: block}

    rig = sim_rig(on=link, link={"move_timeout_s": 5.0})
    store, _, (outcome, safe) = _run(tmp_path, rig, _sweep(), stall)
    assert isinstance(outcome, RunStopped) and outcome.cause == "hardware"
    events = [r["event"] for r in store.records() if r["kind"] == "event"]
    assert events == ["move_timeout", "move_timeout"]
    assert len([r for r in store.records() if r["kind"] == "point"]) == 1
    assert safe


def test_reference_drift_is_flagged_and_corrected_by_interpolation(tmp_path: Path, link: str) -> None:
    rig = sim_rig(on=link, reference={"every": 3, "drift_sigma": 4.0})
    with pytest.warns(DriftWarning, match="reference drifted"):
        store, _, (outcome, _) = _run(tmp_path, rig, _sweep(), drift_per_s=0.05)
    assert not isinstance(outcome, RunStopped)
    drift = [r for r in store.records() if r["kind"] == "event" and r["event"] == "drift"]
    assert drift
    truth, got, _ = truth_and_measured(read_rows(outcome.table), rig)
    # The same points against the reference before each of them only, i.e. without the drift correction.
    records = store.records()
    first_only = [r for r in records if r["kind"] != "reference" or r["slot"] == 0]
    uncorrected = build_rows(first_only, rig.geometry.joint_names, albedo=0.99, albedo_std_error=0.005)
    _, raw, _ = truth_and_measured([{k: str(v) for k, v in row.items()} for row in uncorrected], rig)
    assert np.max(np.abs(raw / truth - 1)) > 0.1
    assert np.max(np.abs(got / truth - 1)) < 0.5 * np.max(np.abs(raw / truth - 1))


def test_two_runs_never_share_a_directory(tmp_path: Path, link: str) -> None:
    rig, sweep = sim_rig(on=link), _sweep()
    start_run(rig, sweep, tmp_path / "run", progress=False)
    with pytest.raises(RunStoreError, match="run"):
        start_run(rig, sweep, tmp_path / "run", progress=False)
    assert json.loads((tmp_path / "run" / "status.json").read_text())["state"] == "finished"


def test_a_bracket_planned_from_a_dark_point_that_clips_at_a_glossy_peak_is_metered_afresh(
    tmp_path: Path, link: str
) -> None:
    # A glossy lobe seen right after a dark off-peak point: the bracket planned from the dark level clips
    # every ROI pixel, which must lead to fresh metering (not a camera fault, nor a mean of the unclipped).
    glossy = {"model": "CookTorrance", "alpha": 0.1, "eta": [0.18, 0.42, 1.37], "k": [3.42, 2.35, 1.77]}
    rig = sim_rig(glossy, on=link, camera={"roi": [14, 14, 18, 18]})
    doc = {"sweep": {"kind": "list", "order": False, "points": [[30.0, 0.0, 70.0, 90.0], [30.0, 0.0, 30.0, 180.0]]},
           "capture": {"target_snr": 100.0}}  # fmt: skip
    sweep = sweep_config(parse(doc, SweepFile, "t.toml"), "t.toml")
    summary = start_run(rig, sweep, tmp_path / "run", progress=False)
    rows = read_rows(summary.table)
    truth, got, se = truth_and_measured(rows, rig)
    assert truth[1, 1] / truth[0, 1] > 300  # the second point is far brighter: the plan must clip
    assert np.all(np.abs(got - truth) < 4.5 * se), (got - truth) / se
    events = [r for r in RunStore.read(tmp_path / "run").records() if r["kind"] == "point"]
    assert any("metered afresh" in n for n in events[1]["notes"]), events[1]


def test_reference_readings_of_a_run_are_independent_draws(tmp_path: Path, link: str) -> None:
    # The tile at the reference pose is one state; the simulator draws noise per state, so each reading
    # needs its own slot in the key, or all of a run's references repeat one draw and never average down.
    rig = sim_rig(on=link, reference={"every": 1, "target_snr": 100.0})
    # A fixed bracket: the same exposures every time, so only the noise can tell the readings apart.
    sweep = in_plane_sweep([20.0], [-40.0, -20.0, 10.0, 30.0, 50.0, 60.0, 70.0], exposures_s=[0.02, 0.005])
    summary = start_run(rig, sweep, tmp_path / "run", progress=False)
    later = [r for r in RunStore.read(tmp_path / "run").records() if r["kind"] == "reference"]
    assert summary.references == len(later) >= 6
    assert len({tuple(r["exposures_s"]) for r in later}) == 1
    reading = np.array([r["reading"] for r in later])
    se = np.array([r["reading_std_error"] for r in later])
    assert len({tuple(row) for row in reading}) == len(later)
    # Scatter between readings as their own errors predict (chi2 with (n - 1) x 3 degrees of freedom).
    chi2, dof = float(np.sum(((reading - reading.mean(axis=0)) / se) ** 2)), 3 * (len(later) - 1)
    assert 0.25 * dof < chi2 < 2.5 * dof, (chi2, dof)


def test_a_pulled_cable_is_a_hardware_stop_with_the_journal_intact(tmp_path: Path, link: str) -> None:
    def unplug(sim: SimulatedRig) -> dict[int, Callable[[], None]]:
        # The device end of the line goes: the port answers EIO.
        if isinstance(sim, SimulatedGrblRig):
            assert sim.grbl is not None
            return {3: sim.grbl.stop}
        assert sim.bus is not None
        return {3: sim.bus.close}

    store, _, (outcome, _) = _run(tmp_path, sim_rig(on=link), _sweep(), unplug)
    assert isinstance(outcome, RunStopped) and outcome.cause == "hardware", outcome
    assert "unplugged" in str(outcome)
    assert len([r for r in store.records() if r["kind"] == "point"]) == 2
    assert store.status()["state"] == "stopped"


def test_a_capture_that_never_returns_is_a_camera_fault_with_the_rig_safe(tmp_path: Path, link: str) -> None:
    release = threading.Event()

    def hang() -> None:
        release.wait()  # a driver stuck in a USB transfer: never returns until the test lets it go

    try:
        # The deadline is twice the exposure plus capture_timeout_s; a hung call exceeds any deadline.
        rig = sim_rig(on=link, camera={"capture_timeout_s": 0.5})
        store, _, (outcome, safe) = _run(tmp_path, rig, _sweep(), lambda sim: {3: hang})
    finally:
        release.set()
    assert isinstance(outcome, RunStopped) and outcome.cause == "camera", outcome
    assert "did not return within" in str(outcome)
    assert len([r for r in store.records() if r["kind"] == "point"]) == 1
    assert safe


def test_a_camera_that_returns_nothing_is_a_camera_fault_not_an_attribute_error(tmp_path: Path, link: str) -> None:
    class NoFrame(FlakyCamera):
        def capture(self) -> Any:
            self.captures += 1
            return None if self.captures >= 3 else self._camera.capture()

    rig, sweep = sim_rig(on=link), _sweep()
    plan = make_plan(rig, sweep)
    store = RunStore.create(tmp_path / "run", manifest(rig, sweep, plan, options_for(rig, sweep, False)))
    with rig_from(rig) as sim:
        assert sim.camera is not None
        runner = Runner(plan, store, open_link(sim, rig), NoFrame(sim.camera, {}), sim.clock,
                        rig.geometry, capture_settings(rig, sweep), reference=reference_settings(rig),
                        target=sim.reference, options=options_for(rig, sweep, False))  # fmt: skip
        with pytest.raises(RunStopped, match="returned None instead of a Frame") as stopped:
            runner.run()
        store.close()
        assert stopped.value.cause == "camera"
        assert left_safe(sim)


class BlackFrames(FlakyCamera):
    """Light captures come back black (the sensor's black level only) while ``black`` says so."""

    def __init__(self, camera: Any, black: Callable[[int], bool]) -> None:
        super().__init__(camera, {})
        self._black = black

    def capture(self) -> Any:
        frame = super().capture()
        if not self._black(self.captures):
            return frame
        level = np.asarray(frame.black_level, dtype=np.float64)
        data = np.broadcast_to(np.round(level), frame.data.shape).astype(frame.data.dtype)
        return dataclasses.replace(frame, data=data)


def _run_black(tmp_path: Path, black: Callable[[int], bool], link: str) -> tuple[RunStore, Any]:
    rig = sim_rig(on=link)
    sweep = in_plane_sweep([20.0], [-40.0, 0.0, 40.0], dark_frames=0)
    plan = make_plan(rig, sweep)
    store = RunStore.create(tmp_path / "run", manifest(rig, sweep, plan, options_for(rig, sweep, False)))
    with rig_from(rig) as sim:
        assert sim.camera is not None
        runner = Runner(plan, store, open_link(sim, rig), BlackFrames(sim.camera, black),
                        sim.clock, rig.geometry, capture_settings(rig, sweep), reference=reference_settings(rig),
                        target=sim.reference, options=options_for(rig, sweep, False))  # fmt: skip
        try:
            outcome: Any = runner.run()
        except RunStopped as exc:
            outcome = exc
        store.close()
    return RunStore.read(tmp_path / "run"), outcome


def test_a_black_bracket_is_metered_afresh_before_the_point_is_accepted(tmp_path: Path, link: str) -> None:
    seen: list[int] = []

    def black(n: int) -> bool:  # the first bracket after the first point comes back black, once
        points = [r for r in RunStore.read(tmp_path / "run").records() if r["kind"] == "point"]
        if len(points) == 1 and not seen:
            seen.append(n)
        return bool(seen) and n in range(seen[0], seen[0] + 2)

    store, outcome = _run_black(tmp_path, black, link)
    assert not isinstance(outcome, RunStopped), outcome
    points = sorted((r for r in store.records() if r["kind"] == "point"), key=lambda r: r["position"])
    assert any("left the ROI dark: metered afresh" in note for note in points[1]["notes"]), points[1]["notes"]
    assert not any(p["dark"] for p in points)
    rows = read_rows(outcome.table)
    truth, got, se = truth_and_measured(rows, sim_rig(on=link))
    assert np.all(np.abs(got - truth) < 4.5 * se), (got - truth) / se


def test_a_point_that_stays_black_is_flagged_dark_in_journal_and_table(tmp_path: Path, link: str) -> None:
    def black(n: int) -> bool:  # the lens cap goes on after the first point; references are exempt below
        points = [r for r in RunStore.read(tmp_path / "run").records() if r["kind"] == "point"]
        refs = [r for r in RunStore.read(tmp_path / "run").records() if r["kind"] == "reference"]
        return len(points) >= 1 and len(refs) < 2 and len(points) < 3

    store, outcome = _run_black(tmp_path, black, link)
    assert not isinstance(outcome, RunStopped), outcome
    points = sorted((r for r in store.records() if r["kind"] == "point"), key=lambda r: r["position"])
    assert [p["dark"] for p in points] == [False, True, True]
    assert "dark even after metering" in points[1]["notes"][-1]
    rows = sorted(read_rows(outcome.table), key=lambda r: int(r["index"]))
    by_index = {int(r["index"]): r["dark"] for r in rows}
    assert [by_index[p["index"]] for p in points] == ["false", "true", "true"]
