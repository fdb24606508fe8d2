"""Gear play the encoders cannot see, on both links of the simulated rig: the fault, and the one-sided approach.

The simulated joints have ``backlash_deg`` of play (``[simulation.misalignment]``): the load lags the motor by
half of it behind the last direction of motion, while the encoder (or GRBL's step count) reads the motor. The
controller knows the play (``[link] backlash_deg``); with ``[link] backlash_approach_deg`` it reaches every pose
from one side, so the load rests on a known flank (``rig.run.backlash``).
"""

from __future__ import annotations

from typing import Any

import pytest

from simulator.from_config import rig_from
from tests.run_helpers import GOLD, LINKS, open_link, sim_rig

pytestmark = pytest.mark.mitsuba

PLAY_DEG = 2.0


@pytest.fixture(params=LINKS)
def link(request: pytest.FixtureRequest) -> str:
    """What moves the simulated joints: virtual Dynamixel servos or a virtual GRBL controller."""
    return str(request.param)


def _rig(on: str) -> Any:
    return sim_rig(GOLD, on=on, simulation={"misalignment": {"backlash_deg": PLAY_DEG}})


def test_the_simulated_load_lags_its_motor_by_half_the_play(link: str) -> None:
    rig = _rig(link)
    with rig_from(rig) as sim:
        light = next(a for a in sim.axes if a.name == "light")
        motion = open_link(sim, rig)
        try:
            for start, sign in ((10.0, -1.0), (50.0, 1.0)):
                motion.move_to({"light": start})
                motion.wait_in_position(30.0)
                motion.move_to({"light": 30.0})
                read = motion.wait_in_position(30.0)["light"]
                load = light.to_degrees(sim.physical_units(light))
                # Driven up from 10 the load trails below the reading, driven down from 50 above it.
                assert load - read == pytest.approx(sign * PLAY_DEG / 2, abs=0.02), (start, load, read)
        finally:
            motion.shutdown()
