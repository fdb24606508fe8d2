"""One pose of float joints takes kinematics_scalar's path: the same directions, to the bit, as numpy's."""

import itertools

import numpy as np
import pytest

from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import forward
from rig.instrument.kinematics_scalar import forward_one
from rig.instrument.kinematics_types import Directions, Joints

SPECIAL = [0.0, -0.0, 90.0, -90.0, 180.0, -180.0, 45.0, 1e-9, -1e-12, 89.99999999, 360.0, 9.755859375, -13.0078125]


def numpy_path(geometry: RigGeometry, joints: Joints) -> Directions:
    """The numpy path, forced by handing it 0-d arrays (forward_one takes plain floats only)."""
    return forward(geometry, Joints.from_dict({k: np.asarray(v) for k, v in joints.as_dict().items()}))


def same(a: Directions, b: Directions) -> bool:
    angles = [(a.theta_i, b.theta_i), (a.phi_i, b.phi_i), (a.theta_o, b.theta_o), (a.phi_o, b.phi_o)]
    # repr tells -0.0 from 0.0, which == does not (an azimuth's sign of zero reaches the journal)
    return all(repr(float(x)) == repr(float(y)) for x, y in angles) and all(
        np.array_equal(u, v) and np.array_equal(np.signbit(u), np.signbit(v)) for u, v in ((a.wi, b.wi), (a.wo, b.wo))
    )


@pytest.mark.parametrize("layout", ["four_axis", "in_plane", "fixed_camera"])
def test_float_pose_matches_numpy_bit_for_bit(layout: str) -> None:
    geometry = RigGeometry(layout=layout, plane_azimuth_deg=30.0, camera_azimuth_deg=-20.0)  # type: ignore[arg-type]
    names = geometry.joint_names
    rng = np.random.default_rng(5)
    poses = [dict(zip(names, (float(v) for v in rng.uniform(-180, 180, len(names))), strict=True))
             for _ in range(3000)]  # fmt: skip
    poses += [dict(zip(names, combo, strict=True)) for combo in itertools.product(SPECIAL, repeat=len(names))
              if rng.random() < 4000 / len(SPECIAL) ** len(names)]  # fmt: skip
    for pose in poses:
        joints = Joints.from_dict(pose)
        fast = forward_one(geometry, joints)
        assert fast is not None
        assert forward(geometry, joints) is not None
        assert same(fast, numpy_path(geometry, joints)), pose


def test_anything_but_one_float_pose_takes_numpy() -> None:
    geometry = RigGeometry()
    assert forward_one(geometry, Joints(light=10.0, camera=-5.0, tilt=0.0, roll=np.float64(1.0))) is None
    assert forward_one(geometry, Joints(light=10.0, camera=-5.0, tilt=0.0, roll=1)) is None
    assert forward_one(geometry, Joints(light=10.0, camera=-5.0, tilt=0.0)) is None
    with pytest.raises(ValueError, match="joints"):
        forward(geometry, Joints(light=10.0, camera=-5.0, tilt=0.0))
    many = forward(geometry, Joints(light=np.array([10.0, 20.0]), camera=-5.0, tilt=0.0, roll=0.0))
    assert np.shape(many.theta_i) == (2,)
