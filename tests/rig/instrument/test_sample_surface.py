"""The sample's surface (rig/instrument/sample_surface.py): intersections, normals, tangents and local angles."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rig.instrument.alignment import Alignment, aligned_forward, aligned_pose
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Joints, RigPose, world_pose
from rig.instrument.sample_surface import SampleShape, local_angles, surface_hits

G = RigGeometry()
R = 0.02
SPHERE, CYLINDER, FLAT = SampleShape("sphere", R), SampleShape("cylinder", R), SampleShape()
angle = st.floats(-60.0, 60.0)


def _pose(tilt: float = 20.0, roll: float = 35.0, light: float = 40.0, camera: float = -30.0) -> RigPose:
    return world_pose(G, Joints(light=light, camera=camera, tilt=tilt, roll=roll))


def _ray_at(target: np.ndarray, direction: np.ndarray, back: float = 0.4) -> tuple[np.ndarray, np.ndarray]:
    d = np.asarray(direction, dtype=float) / np.linalg.norm(direction)
    return np.asarray(target) - back * d, d[None, :]


def test_a_shape_refuses_radii_that_do_not_fit_its_kind() -> None:
    with pytest.raises(ValueError, match="flat sample"):
        SampleShape("flat", 0.01)
    with pytest.raises(ValueError, match="radius > 0"):
        SampleShape("sphere", 0.0)
    with pytest.raises(ValueError, match="finite"):
        SampleShape("cylinder", math.nan)
    with pytest.raises(ValueError, match="expected one of"):
        SampleShape("cone", 0.01)  # type: ignore[arg-type]


@pytest.mark.parametrize("shape", [FLAT, SPHERE, CYLINDER], ids=lambda s: s.kind)
def test_a_ray_straight_down_the_normal_meets_the_top_at_the_sample_centre(shape: SampleShape) -> None:
    pose = _pose()
    n = np.asarray(pose.sample_normal)
    o, d = _ray_at(pose.sample_centre_m, -n)
    hits = surface_hits(shape, G, pose, o, d)
    assert hits.hit.tolist() == [True]
    np.testing.assert_allclose(hits.point_m[0], pose.sample_centre_m, atol=1e-15)
    np.testing.assert_allclose(hits.normal[0], n, atol=1e-15)
    np.testing.assert_allclose(hits.tangent[0], pose.sample_tangent, atol=1e-15)


@given(angle, angle, angle, angle, st.floats(0.0, 2.0), st.floats(-180.0, 180.0),
       st.tuples(st.floats(-2.0, 2.0), st.floats(-2.0, 2.0), st.floats(-2.0, 2.0)))
@settings(max_examples=60, deadline=None)
def test_the_flat_central_ray_gives_the_directions_the_runner_records(
    light: float, camera: float, tilt: float, roll: float, wedge: float, azimuth: float, offset: tuple
) -> None:
    joints = Joints(light=light, camera=camera, tilt=tilt, roll=roll)
    for alignment in (Alignment(), Alignment(tilt_zero_deg=0.3, sample_tilt_deg=wedge,
                                             sample_tilt_azimuth_deg=azimuth, sample_offset_mm=offset)):
        pose = aligned_pose(G, joints, alignment)
        camera_m = np.asarray(pose.camera_position_m)
        central = pose.aim() - camera_m
        hits = surface_hits(FLAT, G, pose, camera_m, (central / np.linalg.norm(central))[None, :])
        recorded = aligned_forward(G, joints, alignment)
        if not hits.hit[0]:  # a grazing view past the square's edge: the runner's point is off the sample
            continue
        got = local_angles(hits, pose.light_position_m, camera_m)
        for name in ("theta_i", "phi_i", "theta_o", "phi_o"):
            want, value = float(getattr(recorded, name)), float(getattr(got, f"{name}_deg")[0])
            if name.startswith("phi") and min(float(recorded.theta_i), float(recorded.theta_o)) < 1e-6:
                continue  # phi is undefined at the pole
            assert abs((value - want + 180.0) % 360.0 - 180.0) < 1e-9, (name, value, want)


def test_local_angles_match_the_geometry_of_each_hit() -> None:
    pose = _pose()
    rng = np.random.default_rng(3)
    camera = np.asarray(pose.camera_position_m)
    targets = pose.sample_centre_m + rng.uniform(-0.015, 0.015, (200, 3))
    dirs = targets - camera
    for shape in (SPHERE, CYLINDER, FLAT):
        hits = surface_hits(shape, G, pose, camera, dirs / np.linalg.norm(dirs, axis=1, keepdims=True))
        assert hits.hit.sum() > 20
        ang = local_angles(hits, pose.light_position_m, camera)
        to_light = pose.light_position_m - hits.point_m
        dist = np.linalg.norm(to_light, axis=1)
        np.testing.assert_allclose(ang.light_distance_m, dist, rtol=1e-14)
        cos_i = np.sum(hits.normal * to_light, axis=1) / dist
        np.testing.assert_allclose(np.cos(np.radians(ang.theta_i_deg)), cos_i, atol=1e-12)
        # phi_i: the light's direction projected on the tangent plane, measured from the tangent towards n x t.
        bitangent = np.cross(hits.normal, hits.tangent)
        phi = np.degrees(np.arctan2(np.sum(to_light * bitangent, 1), np.sum(to_light * hits.tangent, 1)))
        np.testing.assert_allclose(ang.phi_i_deg, phi, atol=1e-9)
        to_cam = camera - hits.point_m
        cos_o = np.sum(hits.normal * to_cam, axis=1) / np.linalg.norm(to_cam, axis=1)
        np.testing.assert_allclose(np.cos(np.radians(ang.theta_o_deg)), cos_o, atol=1e-12)
        assert np.all(ang.theta_o_deg[hits.hit] < 90.0)  # whatever the camera sees faces it


@given(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(-0.03, 0.03),
       st.floats(-0.03, 0.03), st.floats(-0.03, 0.03))
@settings(max_examples=200, deadline=None)
def test_curved_hits_lie_on_the_surface_with_an_orthonormal_frame(dx: float, dy: float, dz: float,
                                                                 px: float, py: float, pz: float) -> None:
    pose = _pose()
    direction = np.array([dx, dy, dz])
    if np.linalg.norm(direction) < 1e-3:
        return
    o, d = _ray_at(pose.sample_centre_m + np.array([px, py, pz]), direction)
    n = np.asarray(pose.sample_normal)
    b = np.asarray(pose.sample_bitangent)
    centre = pose.sample_centre_m - R * n
    for shape in (SPHERE, CYLINDER):
        hits = surface_hits(shape, G, pose, o, d)
        for field in (hits.point_m, hits.normal, hits.tangent):
            assert np.all(np.isfinite(field))
        if not hits.hit[0]:
            continue
        p = hits.point_m[0]
        radial = p - centre if shape.kind == "sphere" else p - centre - ((p - centre) @ b) * b
        assert abs(np.linalg.norm(radial) - R) < 1e-12
        np.testing.assert_allclose(hits.normal[0], radial / R, atol=1e-10)
        assert abs(np.linalg.norm(hits.tangent[0]) - 1.0) < 1e-12
        assert abs(hits.tangent[0] @ hits.normal[0]) < 1e-12
        assert hits.normal[0] @ d[0] <= 1e-12  # met from outside
        # the nearest meeting: the naive quadratic's smaller root, from an independent formula
        oc = o - centre
        if shape.kind == "cylinder":
            oc, dd = oc - (oc @ b) * b, d[0] - (d[0] @ b) * b
        else:
            dd = d[0]
        a2, b2, c2 = dd @ dd, 2 * oc @ dd, oc @ oc - R * R
        t0 = (-b2 - math.sqrt(max(b2 * b2 - 4 * a2 * c2, 0.0))) / (2 * a2)
        assert np.linalg.norm(o + t0 * d[0] - p) < 1e-9


def test_rays_grazing_the_silhouettes_stay_finite_and_split_cleanly() -> None:
    pose = _pose(tilt=0.0, roll=0.0)
    n, t, b = (np.asarray(v) for v in (pose.sample_normal, pose.sample_tangent, pose.sample_bitangent))
    centre = pose.sample_centre_m - R * n
    # Each ray passes the centre (the axis) at R + gap: inside the silhouette, on it, or just past it.
    for shape, across, along in ((SPHERE, t, b), (SPHERE, b, t), (CYLINDER, t, n)):
        for gap, expect in ((-1e-9, True), (0.0, True), (1e-9, False)):
            origin = centre + (R + gap) * across - 0.3 * along
            hits = surface_hits(shape, G, pose, origin, along[None, :])
            assert hits.hit.tolist() == [expect], (shape.kind, gap)
            assert np.all(np.isfinite(hits.point_m)) and np.all(np.isfinite(hits.normal))
            if expect:
                assert abs(hits.normal[0] @ along) < 1e-3  # the silhouette: the normal is across the ray
                ang = local_angles(hits, pose.light_position_m, pose.camera_position_m)
                assert np.all(np.isfinite([ang.theta_i_deg, ang.phi_i_deg, ang.theta_o_deg, ang.phi_o_deg]))


def test_the_flat_square_ends_at_its_edges_and_has_no_lit_back() -> None:
    pose = _pose(tilt=0.0, roll=0.0)
    n, t = np.asarray(pose.sample_normal), np.asarray(pose.sample_tangent)
    edge = pose.sample_centre_m + 0.5 * G.sample_width_m * t
    for offset, expect in ((0.0, True), (-1e-9, True), (1e-9, False)):
        hits = surface_hits(FLAT, G, pose, *_ray_at(edge + offset * t, -n))
        assert hits.hit.tolist() == [expect]
    back = surface_hits(FLAT, G, pose, pose.sample_centre_m - 0.3 * n, n[None, :])
    assert back.hit.tolist() == [False]
    parallel = surface_hits(FLAT, G, pose, pose.sample_centre_m + 0.01 * n - 0.3 * t, t[None, :])
    assert parallel.hit.tolist() == [False]


def test_misses_carry_finite_filler_values() -> None:
    pose = _pose()
    n = np.asarray(pose.sample_normal)
    away = np.stack([n, -n])  # one ray leaves the sample, one passes far beside it
    origin = pose.sample_centre_m + 0.3 * n + 0.2 * np.asarray(pose.sample_tangent)
    for shape in (FLAT, SPHERE, CYLINDER):
        hits = surface_hits(shape, G, pose, origin, away)
        assert not hits.hit.any()
        np.testing.assert_array_equal(hits.point_m, np.broadcast_to(pose.sample_centre_m, (2, 3)))
        ang = local_angles(hits, pose.light_position_m, pose.camera_position_m)
        assert np.all(np.isfinite(ang.light_distance_m)) and np.all(np.isfinite(ang.theta_i_deg))


def test_the_sphere_tangent_follows_longitude_about_the_bitangent_and_survives_its_poles() -> None:
    pose = _pose()
    n, t, b = (np.asarray(v) for v in (pose.sample_normal, pose.sample_tangent, pose.sample_bitangent))
    centre = pose.sample_centre_m - R * n
    for pole in (b, -b):
        hits = surface_hits(SPHERE, G, pose, *_ray_at(centre + R * pole, -pole))
        assert hits.hit[0]
        np.testing.assert_allclose(hits.normal[0], pole, atol=1e-12)
        np.testing.assert_allclose(hits.tangent[0], t, atol=1e-12)
    # On the great circle in the T-n plane, the tangent is T turned with the normal (its projection).
    normal = math.cos(0.7) * n + math.sin(0.7) * t
    hits = surface_hits(SPHERE, G, pose, *_ray_at(centre + R * normal, -normal))
    np.testing.assert_allclose(hits.tangent[0], math.cos(0.7) * t - math.sin(0.7) * n, atol=1e-12)


def test_the_cylinder_is_open_along_the_bitangent_and_as_long_as_the_sample() -> None:
    pose = _pose(tilt=0.0, roll=0.0)
    n, b = np.asarray(pose.sample_normal), np.asarray(pose.sample_bitangent)
    half = 0.5 * G.sample_height_m
    for along, expect in ((half * 0.999, True), (half * 1.001, False)):
        hits = surface_hits(CYLINDER, G, pose, *_ray_at(pose.sample_centre_m + along * b, -n))
        assert hits.hit.tolist() == [expect]
    # Looking down the axis through the open end meets only the inside: not a lit hit.
    inside = surface_hits(CYLINDER, G, pose, pose.sample_centre_m - 0.5 * R * n + 0.3 * b, -b[None, :])
    assert inside.hit.tolist() == [False]
    # Down the axis exactly: no crossing of the side at all.
    axis = surface_hits(CYLINDER, G, pose, pose.sample_centre_m - R * n + 0.3 * b, -b[None, :])
    assert axis.hit.tolist() == [False]
