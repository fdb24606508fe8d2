"""simulator.render.scene and .view: the rig's Mitsuba scene at one pose, where its camera looks and what it sees.

The references are independent of Mitsuba's scene code: radiance from the point-source law evaluated per
pixel on geometry computed here in numpy, Mitsuba's own BSDF ``eval`` in the kinematics' local frame for
the anisotropic check, and Mitsuba's documented texture conventions (rectangle uv = (x + 1, y + 1) / 2,
checkerboard colour0 where exactly one of frac(u), frac(v) exceeds 1/2) for the sample's axes.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import RigPose, forward, inverse, require
from simulator.render.renderer import render_radiance, roi_mean, roi_radiance
from simulator.render.scene import build_scene, sample_to_world
from simulator.render.spec import CameraSpec, LightSpec
from simulator.render.view import camera_view, default_roi, pixel_on_sample
from tests.mitsuba_helpers import bsdf_eval_cos
from tests.simulator.render.render_helpers import (
    ANGLES,
    CAMERA,
    DIFFUSE,
    GEOMETRY,
    INTENSITY,
    POINT,
    half_space_texture,
    lambert_per_pixel,
    mirrored_through_sample,
    pose_at,
    texture_at_local,
)

pytestmark = pytest.mark.mitsuba


def test_default_roi_is_centred_and_on_the_central_quarter_of_the_sample() -> None:
    for resolution in ((64, 64), (65, 48)):
        camera = CameraSpec(resolution=resolution)
        width, height = resolution
        for angles in ANGLES:
            pose = pose_at(*angles)
            x0, y0, x1, y1 = default_roi(GEOMETRY, pose, POINT, camera)
            assert x0 + x1 == width and y0 + y1 == height  # symmetric about the image centre
            py, px = np.mgrid[y0:y1, x0:x1] + 0.5
            _, uv = pixel_on_sample(camera_view(GEOMETRY, pose, camera), pose, px, py)
            assert np.all(np.abs(uv[..., 0]) <= 0.25 * GEOMETRY.sample_width_m)
            assert np.all(np.abs(uv[..., 1]) <= 0.25 * GEOMETRY.sample_height_m)
            # Grown until blocked: one more pixel each way leaves the region (or the image) in x and in y.
            for grown in ((x0 - 1, y0, x1 + 1, y1), (x0, y0 - 1, x1, y1 + 1)):
                gy, gx = np.mgrid[grown[1] : grown[3], grown[0] : grown[2]] + 0.5
                _, guv = pixel_on_sample(camera_view(GEOMETRY, pose, camera), pose, gx, gy)
                assert np.any(np.abs(guv[..., 0]) > 0.25 * GEOMETRY.sample_width_m) or np.any(
                    np.abs(guv[..., 1]) > 0.25 * GEOMETRY.sample_height_m
                )


def test_sample_to_world_maps_local_axes() -> None:
    pose = pose_at(30.0, 40.0, 70.0, 250.0)
    m = sample_to_world(GEOMETRY, pose)
    np.testing.assert_allclose(m[:3, 0], 0.5 * GEOMETRY.sample_width_m * pose.sample_tangent)
    np.testing.assert_allclose(m[:3, 1], 0.5 * GEOMETRY.sample_height_m * pose.sample_bitangent)
    np.testing.assert_allclose(m[:3, 2], pose.sample_normal)
    np.testing.assert_allclose(m[:3, 3], pose.sample_centre_m)
    assert np.linalg.det(m[:3, :3]) > 0  # right-handed, as Mitsuba's rectangle frame


@pytest.mark.parametrize("angles", [(30.0, 40.0, 45.0, 250.0), (60.0, 300.0, 45.0, 135.0)])
def test_local_axes_appear_where_the_camera_projects_them(angles: tuple[float, float, float, float]) -> None:
    pose = pose_at(*angles)
    view = camera_view(GEOMETRY, pose, CAMERA)
    for axis, direction in ((0, pose.sample_tangent), (1, pose.sample_bitangent)):
        spec = half_space_texture(axis)
        image = render_radiance(build_scene(GEOMETRY, pose, spec, POINT, CAMERA), "scalar_rgb")
        size = (GEOMETRY.sample_width_m, GEOMETRY.sample_height_m)[axis]
        colours = []
        for sign in (1.0, -1.0):
            px, py = view.project(pose.sample_centre_m + sign * 0.25 * size * direction)
            local = [0.0, 0.0]
            local[axis] = 0.5 * sign
            want = texture_at_local(spec, *local)
            got = image[int(py), int(px)]
            # The pixel's colour is the texture's there, up to the (grey) shading factor.
            np.testing.assert_allclose(got / got.sum(), want / want.sum(), atol=1e-3, err_msg=f"axis {axis} {sign}")
            colours.append(want)
        assert not np.allclose(*colours)  # the two halves differ, so a flipped axis would fail


def test_anisotropic_lobe_follows_the_tangent() -> None:
    """A GGX conductor with alpha_u != alpha_v against Mitsuba's eval in the kinematics' local frame."""
    angles = (40.0, 0.0, 40.0, 150.0)  # the half vector lies mostly along local y
    pose = pose_at(*angles)
    directions = forward(GEOMETRY, require(inverse(GEOMETRY, *angles)))
    camera = CameraSpec(resolution=(64, 64), spp=4, roi=(30, 30, 34, 34))  # small: the lobe varies over the sample
    cos_i = directions.wi[2]
    renders, evals = [], []
    for alpha_u, alpha_v in ((0.1, 0.4), (0.4, 0.1)):
        spec = {"type": "roughconductor", "distribution": "ggx", "alpha_u": alpha_u, "alpha_v": alpha_v,
                "material": "Al"}
        renders.append(roi_radiance(GEOMETRY, pose, spec, POINT, camera, variant="scalar_rgb"))
        f = bsdf_eval_cos("scalar_rgb", spec, directions.wi[None], directions.wo[None])[0] / directions.wo[2]
        evals.append(f * INTENSITY * cos_i / GEOMETRY.light_radius_m**2)
    for got, want in zip(renders, evals, strict=True):
        np.testing.assert_allclose(got, want, rtol=0.03)
    # Swapping the axes changes the answer tenfold (the lobe is wide along y in the first): the test can tell.
    assert np.all(renders[1] < 0.2 * renders[0])


def test_camera_looks_at_the_sample_centre() -> None:
    """The sample centre projects to the image centre, and every pixel on the sample has its own radiance.

    Comparing each interior pixel (not just a symmetric mean) pins the image's orientation: at these poses
    the radiance changes by up to 1.6 % per pixel, so a mirrored or rotated image would fail.
    """
    camera = CameraSpec(resolution=(64, 64), spp=64)  # sub-pixel jitter 0.04 px rms: 0.06 % at that gradient
    py, px = np.mgrid[0:64, 0:64] + 0.5
    for angles in ANGLES:
        pose = pose_at(*angles)
        view = camera_view(GEOMETRY, pose, camera)
        np.testing.assert_allclose(view.project(pose.sample_centre_m), [32.0, 32.0], atol=1e-9)
        image = render_radiance(build_scene(GEOMETRY, pose, DIFFUSE, POINT, camera), "scalar_rgb")
        want = lambert_per_pixel(pose, camera, (0, 0, 64, 64))
        _, uv = pixel_on_sample(view, pose, px, py)
        # Pixels whose centre is well inside the sample (edge pixels are partly covered).
        interior = (np.abs(uv[..., 0]) < 0.4 * GEOMETRY.sample_width_m) & (
            np.abs(uv[..., 1]) < 0.4 * GEOMETRY.sample_height_m
        )
        assert interior[31:33, 31:33].all() and interior.sum() > 100
        np.testing.assert_allclose(image[interior, 0], want[interior], rtol=5e-3, err_msg=f"angles {angles}")
        outside = np.isnan(uv[..., 0]) | (np.abs(uv[..., 0]) > 0.6 * GEOMETRY.sample_width_m) | (
            np.abs(uv[..., 1]) > 0.6 * GEOMETRY.sample_height_m
        )
        assert np.all(image[outside] == 0.0)


def test_top_down_view_uses_another_up_vector() -> None:
    """A camera on the arm axis (world z) cannot use z as its up vector; the view must still be right."""
    pose = RigPose(
        sample_centre_m=np.zeros(3),
        sample_normal=np.array([0.0, 0.0, 1.0]),
        sample_tangent=np.array([1.0, 0.0, 0.0]),
        sample_bitangent=np.array([0.0, 1.0, 0.0]),
        light_position_m=0.5 * np.array([math.sin(math.radians(40.0)), 0.0, math.cos(math.radians(40.0))]),
        camera_position_m=np.array([0.0, 0.0, 0.5]),
    )
    view = camera_view(GEOMETRY, pose, CAMERA)
    assert abs(view.up @ view.forward) < 1e-12 and np.all(np.isfinite(view.up))
    roi = default_roi(GEOMETRY, pose, POINT, CAMERA)
    got = roi_radiance(GEOMETRY, pose, DIFFUSE, POINT, CAMERA, variant="scalar_rgb")
    np.testing.assert_allclose(got, lambert_per_pixel(pose, CAMERA, roi).mean(), rtol=2e-3)
    # The light lies towards world +x: pixels on that side are brighter, where the camera model puts them.
    image = render_radiance(build_scene(GEOMETRY, pose, DIFFUSE, POINT, CAMERA), "scalar_rgb")
    (xa, ya), (xb, yb) = view.project(np.array([[0.01, 0.0, 0.0], [-0.01, 0.0, 0.0]]))
    assert image[int(ya), int(xa), 0] > 1.02 * image[int(yb), int(xb), 0]


def test_back_side_renders_black() -> None:
    pose = pose_at(30.0, 0.0, 45.0, 180.0)
    behind_camera = replace(pose, camera_position_m=mirrored_through_sample(pose, pose.camera_position_m))
    behind_light = replace(pose, light_position_m=mirrored_through_sample(pose, pose.light_position_m))
    theta_o = np.degrees(np.arccos(behind_camera.camera_position_m @ pose.sample_normal / GEOMETRY.camera_radius_m))
    assert theta_o == pytest.approx(135.0)
    for p in (behind_camera, behind_light):
        image = render_radiance(build_scene(GEOMETRY, p, DIFFUSE, POINT, CAMERA), "scalar_rgb")
        assert np.all(image == 0.0)
    # Sanity: the centre pixel of the mirrored camera does see the sample (its back), so black means unlit.
    view = camera_view(GEOMETRY, behind_camera, CAMERA)
    _, uv = pixel_on_sample(view, behind_camera, np.array(32.0), np.array(32.0))
    assert np.all(np.abs(uv) < 1e-9)


def test_spot_light_matches_point_inside_its_beam_and_is_dark_outside() -> None:
    geometry = RigGeometry(beam_half_angle_deg=1.0)  # 8.7 mm spot radius: a few pixels across at 64x64
    spot = LightSpec(kind="spot", intensity=INTENSITY)
    pose = pose_at(30.0, 0.0, 0.0, 0.0, geometry)
    roi = default_roi(geometry, pose, spot, CAMERA)
    view = camera_view(geometry, pose, CAMERA)
    image = render_radiance(build_scene(geometry, pose, DIFFUSE, spot, CAMERA), "scalar_rgb")
    point = render_radiance(build_scene(geometry, pose, DIFFUSE, POINT, CAMERA), "scalar_rgb")
    np.testing.assert_allclose(roi_mean(image, roi), roi_mean(point, roi), rtol=1e-3)
    # Pixels whose sample point lies beyond the cutoff get no light.
    py, px = np.mgrid[0:64, 0:64] + 0.5
    p, _ = pixel_on_sample(view, pose, px, py)
    axis = -pose.light_position_m / np.linalg.norm(pose.light_position_m)
    to_p = p - pose.light_position_m
    off_deg = np.degrees(np.arccos(np.clip((to_p @ axis) / np.linalg.norm(to_p, axis=-1), -1, 1)))
    outside = np.nan_to_num(off_deg, nan=90.0) > 1.05 * geometry.beam_half_angle_deg
    assert outside.sum() > 100 and np.all(image[outside] == 0.0)
    assert image[~outside].max() > 0


def test_specs_reject_bad_values() -> None:
    with pytest.raises(ValueError, match="kind"):
        LightSpec(kind="area")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="intensity"):
        LightSpec(intensity=-1.0)
    with pytest.raises(ValueError, match="roi"):
        CameraSpec(resolution=(16, 16), roi=(0, 0, 17, 4))
    with pytest.raises(ValueError, match="spp"):
        CameraSpec(spp=0)
    with pytest.raises(ValueError, match="beam width"):
        LightSpec(kind="spot", cutoff_deg=1.0, beam_width_deg=2.0).cone_deg(GEOMETRY)
    with pytest.raises(ValueError, match="single pose"):
        build_scene(GEOMETRY, RigPose(*(np.zeros((2, 3)) for _ in range(6))), DIFFUSE, POINT, CAMERA)
    assert math.isclose(CAMERA.fov(GEOMETRY), GEOMETRY.camera_fov_deg)
    # Lists are accepted and stored as tuples: specs are cache keys, so they must hash.
    spec = CameraSpec(resolution=[32, 16], roi=[0, 0, 8, 8])  # type: ignore[arg-type]
    assert hash(spec) and spec.resolution == (32, 16) and spec.roi == (0, 0, 8, 8)
    assert hash(LightSpec(intensity=[1, 2, 3])) and LightSpec(intensity=[1, 2, 3]).rgb() == (1.0, 2.0, 3.0)  # type: ignore[arg-type]
