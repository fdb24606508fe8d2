"""A run on a Dynamixel bus that loses replies: it keeps measuring at a rate near its loss, or stops saying why.

Simulated time throughout: a reply the virtual bus drops costs the link's reply window on the rig's clock
(``rig.instrument.links.dynamixel_bus``), not on the wall, so the rates compared are the rig's own.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from rig.run.measuring.runner import RunStopped
from rig.run.session import make_plan, manifest, options_for
from rig.run.storage.store import RunStore
from simulator.from_config import rig_from
from simulator.rig import SimulatedRig
from tests.run_helpers import FlakyCamera, in_plane_sweep, left_safe, run_outcome, sim_rig

pytestmark = pytest.mark.mitsuba


def _lossy_run(tmp_path: Path, drop: float) -> tuple[Any, RunStore, bool]:
    """A 6-point run whose servos drop each reply with probability ``drop`` once the first frame is taken."""
    rig = sim_rig()
    sweep = in_plane_sweep([10.0, 45.0], [-30.0, 20.0, 50.0], exposures_s=[0.02], dark_frames=0)
    plan = make_plan(rig, sweep)
    out = tmp_path / f"run-{drop:g}"
    store = RunStore.create(out, manifest(rig, sweep, plan, options_for(rig, sweep, False)))
    with rig_from(rig) as sim:
        assert sim.camera is not None

        def lose(sim: SimulatedRig = sim) -> None:
            assert sim.bus is not None
            for servo in sim.bus.servos:
                servo.faults.reseed(11 + servo.id)
                servo.faults.drop_probability = drop

        camera = FlakyCamera(sim.camera, {1: lose})
        outcome: Any = run_outcome(sim, rig, sweep, plan, store, camera)
        safe = left_safe(sim)
        dropped = sim.bus.stats.replies_dropped if sim.bus is not None else 0
    if drop:
        assert dropped > 0  # the fault was really there
    return outcome, RunStore.read(out), safe


def test_a_bus_losing_5_percent_of_replies_measures_near_the_loss_free_rate(tmp_path: Path) -> None:
    clean, _, _ = _lossy_run(tmp_path, 0.0)
    lossy, _, _ = _lossy_run(tmp_path, 0.05)
    assert not isinstance(lossy, RunStopped), lossy
    assert lossy.measured == clean.measured == 6
    clean_rate = clean.measured / clean.rig_time_s * 60.0
    lossy_rate = lossy.measured / lossy.rig_time_s * 60.0
    # Each lost reply (about 1 sync read in 5 at 5 % a servo) costs one reply window (122 ms) and a retry, never a
    # window grown to seconds: the rate stays within 20 % of the loss-free one (12.6 % slower when written).
    assert lossy_rate >= 0.8 * clean_rate, (lossy_rate, clean_rate)


def test_a_bus_losing_most_replies_stops_the_run_as_a_hardware_fault_naming_the_loss(tmp_path: Path) -> None:
    outcome, store, safe = _lossy_run(tmp_path, 0.6)
    assert safe  # torque off on every servo: the shutdown's writes are retried through the loss
    assert isinstance(outcome, RunStopped) and outcome.cause == "hardware"
    assert "lost" in str(outcome) and "% of the last" in str(outcome), outcome
    assert len([r for r in store.records() if r["kind"] == "point"]) <= 1
    assert store.status()["state"] != "finished"
