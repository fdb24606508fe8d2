"""The simulated rig's sample shape: read from [sample], rendered for the sample, flat for the tiles swapped in."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import model as m
from model.mitsuba.materials import to_mitsuba
from rig.instrument.kinematics import world_pose
from rig.instrument.sample_surface import FLAT, SampleShape
from rig.run.config.files import load_rig
from simulator.from_config import spec_from
from simulator.render.spec import CameraSpec
from simulator.rig import SimRigSpec, SimulatedRig

pytestmark = pytest.mark.mitsuba

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


def test_the_rig_file_gives_the_simulated_rig_its_sample_shape() -> None:
    assert spec_from(load_rig(EXAMPLES / "rig_simulated_sphere.toml")).sample_shape == SampleShape("sphere", 0.02)
    assert spec_from(load_rig(EXAMPLES / "rig_simulated.toml")).sample_shape == FLAT


def test_the_sample_renders_curved_and_the_reference_tile_flat() -> None:
    sphere = SampleShape("sphere", 0.015)
    spec = SimRigSpec(material=m.Lambert(0.5), seed=2, camera=CameraSpec((24, 24)), sample_shape=sphere)
    with SimulatedRig(spec) as rig:
        pose = world_pose(spec.geometry, rig.joints_now())
        full = (0, 0, 24, 24)
        sample = rig.radiance_now(crop=full)
        want = rig.renderer.render(pose, to_mitsuba(spec.material), crop=full, key=repr(spec.material),
                                   seed=spec.seed, shape=sphere)  # fmt: skip
        np.testing.assert_array_equal(sample, want)
        rig.show(True)
        tile = rig.radiance_now(crop=full)
        flat = rig.renderer.render(pose, to_mitsuba(m.Lambert(spec.reference_albedo)), crop=full,
                                   key=repr(m.Lambert(spec.reference_albedo)), seed=spec.seed, shape=FLAT)  # fmt: skip
        np.testing.assert_array_equal(tile, flat)
        # The sphere fills less of the frame than the 50 mm square does: its corners are black.
        assert np.count_nonzero(sample[..., 0] == 0) > np.count_nonzero(tile[..., 0] == 0)
