"""simulator.render.scene and simulator.render.renderer: the rig's Mitsuba scene, rendered radiance and its cache.

The references are independent of Mitsuba's scene code: radiance from the point-source law evaluated per
pixel on geometry computed here in numpy, Mitsuba's own BSDF ``eval`` in the kinematics' local frame for
the anisotropic check, and Mitsuba's documented texture conventions (rectangle uv = (x + 1, y + 1) / 2,
checkerboard colour0 where exactly one of frac(u), frac(v) exceeds 1/2) for the sample's axes.
"""

from __future__ import annotations

import math
from dataclasses import astuple, replace
from typing import Any

import drjit as dr
import mitsuba as mi
import mitsuba.scalar_rgb as mis
import numpy as np
import pytest

from model.lambert import Lambert
from model.mitsuba import variant as mv
from model.predict import predict_radiance
from model.radiometry import PointLight
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import RigPose, forward, inverse, require, world_pose
from simulator.render import renderer as render_module
from simulator.render.renderer import RadianceRenderer, render_radiance, roi_mean, roi_radiance
from simulator.render.scene import build_scene, sample_to_world
from simulator.render.spec import CameraSpec, LightSpec
from simulator.render.view import camera_view, default_roi, pixel_on_sample
from tests.mitsuba_helpers import ORACLE_VARIANTS, bsdf_eval_cos, require_variant, rgb

pytestmark = pytest.mark.mitsuba

GEOMETRY = RigGeometry()
ALBEDO = 0.5
INTENSITY = 2.0  # W/sr
DIFFUSE = {"type": "diffuse", "reflectance": rgb([ALBEDO] * 3)}
CAMERA = CameraSpec(resolution=(64, 64), spp=4)
POINT = LightSpec(intensity=INTENSITY)

#: (theta_i, phi_i, theta_o, phi_o) in degrees, spanning theta_i 0/30/60, theta_o 0/45/70 and several phi.
ANGLES = [
    (0.0, 0.0, 45.0, 180.0),
    (30.0, 0.0, 0.0, 0.0),
    (30.0, 40.0, 70.0, 250.0),
    (60.0, 0.0, 45.0, 90.0),
    (60.0, 300.0, 70.0, 135.0),
    (0.0, 0.0, 70.0, 30.0),
]


@pytest.fixture(autouse=True)
def _no_override(monkeypatch: pytest.MonkeyPatch) -> None:
    """Tests choose variants themselves, whatever the calling shell exports."""
    monkeypatch.delenv(mv.ENV_VAR, raising=False)


def pose_at(theta_i: float, phi_i: float, theta_o: float, phi_o: float, geometry: RigGeometry = GEOMETRY) -> RigPose:
    return world_pose(geometry, require(inverse(geometry, theta_i, phi_i, theta_o, phi_o)))


def lambert_per_pixel(pose: RigPose, camera: CameraSpec, box: tuple[int, int, int, int]) -> np.ndarray:
    """albedo/pi * I * cos(theta_i') / d^2 at each pixel centre of the box, from numpy geometry alone."""
    view = camera_view(GEOMETRY, pose, camera)
    x0, y0, x1, y1 = box
    py, px = np.mgrid[y0:y1, x0:x1] + 0.5
    p, _ = pixel_on_sample(view, pose, px, py)
    to_light = pose.light_position_m - p
    d = np.linalg.norm(to_light, axis=-1)
    cos_i = (to_light @ pose.sample_normal) / d
    return ALBEDO / np.pi * INTENSITY * cos_i / d**2


# ----------------------------------------------------------------------------------------------------------
# (a) radiance of a Lambertian sample against the point-source law


@pytest.mark.parametrize("variant", ORACLE_VARIANTS)
def test_lambertian_roi_matches_point_source_law(variant: str) -> None:
    require_variant(variant)
    for k, angles in enumerate(ANGLES):
        pose = pose_at(*angles)
        roi = default_roi(GEOMETRY, pose, POINT, CAMERA)
        assert (roi[2] - roi[0]) * (roi[3] - roi[1]) >= 16, f"ROI {roi} too small at {angles}"
        got = roi_radiance(GEOMETRY, pose, DIFFUSE, POINT, CAMERA, variant=variant, seed=k)
        want = lambert_per_pixel(pose, CAMERA, roi).mean()
        # A delta light under emitter sampling is exact; only sub-pixel jitter and float32 remain.
        np.testing.assert_allclose(got, want, rtol=2e-3, err_msg=f"angles {angles}, ROI {roi}")
        # The model's prediction at the sample centre, L = f_r I cos(theta_i) / d^2, within the ROI's spread.
        directions = forward(GEOMETRY, require(inverse(GEOMETRY, *angles)))
        light = PointLight(intensity=INTENSITY, distance=GEOMETRY.light_radius_m)
        centre = predict_radiance(Lambert(rho_d=ALBEDO), directions.wi, directions.wo, light)
        np.testing.assert_allclose(got, np.broadcast_to(centre, (3,)), rtol=5e-3, err_msg=f"angles {angles}")


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


# ----------------------------------------------------------------------------------------------------------
# (b) the sample's frame: local x -> tangent, y -> bitangent, z -> normal


def test_sample_to_world_maps_local_axes() -> None:
    pose = pose_at(30.0, 40.0, 70.0, 250.0)
    m = sample_to_world(GEOMETRY, pose)
    np.testing.assert_allclose(m[:3, 0], 0.5 * GEOMETRY.sample_width_m * pose.sample_tangent)
    np.testing.assert_allclose(m[:3, 1], 0.5 * GEOMETRY.sample_height_m * pose.sample_bitangent)
    np.testing.assert_allclose(m[:3, 2], pose.sample_normal)
    np.testing.assert_allclose(m[:3, 3], pose.sample_centre_m)
    assert np.linalg.det(m[:3, :3]) > 0  # right-handed, as Mitsuba's rectangle frame


def half_space_texture(axis: int) -> dict[str, Any]:
    """Diffuse reflectance whose checkerboard colour depends on the sign of local x (axis 0) or y (axis 1) only.

    Scaling the other uv coordinate by 1/2 keeps its frac() below 1/2, so the board splits at u (or v) = 1/2,
    i.e. at local x (or y) = 0 on Mitsuba's rectangle.
    """
    scale = [0.5, 1.0, 1.0] if axis == 1 else [1.0, 0.5, 1.0]
    return {
        "type": "diffuse",
        "reflectance": {
            "type": "checkerboard",
            "color0": rgb([0.9, 0.05, 0.05]),
            "color1": rgb([0.05, 0.05, 0.9]),
            "to_uv": mis.ScalarTransform4f().scale(scale),
        },
    }


def texture_at_local(spec: dict[str, Any], x: float, y: float) -> np.ndarray:
    """The reflectance texture's colour at local (x, y) in [-1, 1]^2, via the rectangle's uv = (x + 1, y + 1) / 2."""
    with mv.use_variant("scalar_rgb"):
        texture = mi.load_dict(spec["reflectance"])
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.uv = mi.Point2f(0.5 * x + 0.5, 0.5 * y + 0.5)
        return np.array(texture.eval(si), dtype=np.float64)


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


# ----------------------------------------------------------------------------------------------------------
# (c) crop, (f) where the camera looks


@pytest.mark.parametrize("variant", ORACLE_VARIANTS)
def test_crop_equals_the_same_pixels_of_the_full_frame(variant: str) -> None:
    require_variant(variant)
    pose = pose_at(30.0, 40.0, 45.0, 250.0)
    roi = default_roi(GEOMETRY, pose, POINT, CAMERA)
    full = render_radiance(build_scene(GEOMETRY, pose, DIFFUSE, POINT, CAMERA), variant)
    crop = render_radiance(build_scene(GEOMETRY, pose, DIFFUSE, POINT, CAMERA, crop=roi), variant)
    x0, y0, x1, y1 = roi
    assert crop.shape == (y1 - y0, x1 - x0, 3)
    same = full[y0:y1, x0:x1]
    # Different random streams jitter sample positions differently: per pixel within the radiance gradient.
    np.testing.assert_allclose(crop, same, rtol=5e-3)
    np.testing.assert_allclose(crop.mean(axis=(0, 1)), same.mean(axis=(0, 1)), rtol=5e-4)
    np.testing.assert_allclose(roi_mean(full, roi), same.mean(axis=(0, 1)))
    np.testing.assert_allclose(roi_mean(crop, roi, (x0, y0)), crop.mean(axis=(0, 1)))


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


def mirrored_through_sample(pose: RigPose, point: np.ndarray) -> np.ndarray:
    n = pose.sample_normal
    return point - 2.0 * ((point - pose.sample_centre_m) @ n) * n


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


# ----------------------------------------------------------------------------------------------------------
# (d) the cache, (e) variants


def test_renderer_cache_hits_and_misses() -> None:
    renderer = RadianceRenderer(GEOMETRY, POINT, CAMERA, variant="scalar_rgb", maxsize=2)
    pose = pose_at(30.0, 0.0, 45.0, 180.0)
    first = renderer.render(pose, DIFFUSE)
    again = renderer.render(RigPose(*(v + 1e-9 for v in astuple(pose))), dict(DIFFUSE))
    assert again is first and not first.flags.writeable
    assert (renderer.stats.hits, renderer.stats.misses) == (1, 1)
    other_material = {"type": "diffuse", "reflectance": rgb([0.2, 0.2, 0.2])}
    renderer.render(pose, other_material)
    renderer.render(pose_at(30.0, 0.0, 45.0, 170.0), DIFFUSE)  # third entry: evicts the least recent
    assert (renderer.stats.hits, renderer.stats.misses, renderer.stats.size) == (1, 3, 2)
    renderer.render(pose, other_material)  # still cached
    renderer.render(pose, DIFFUSE)  # evicted
    assert (renderer.stats.hits, renderer.stats.misses) == (2, 4)
    value = renderer.roi_radiance(pose, DIFFUSE, key="lambert 0.5")
    assert renderer.roi_radiance(pose, DIFFUSE, key="lambert 0.5") is not value  # a fresh mean of a cached crop
    assert renderer.stats.hits == 3
    np.testing.assert_allclose(value, roi_radiance(GEOMETRY, pose, DIFFUSE, POINT, CAMERA, variant="scalar_rgb"))
    renderer.clear()
    assert renderer.stats == type(renderer.stats)(0, 0, 0, 2, 0)


def test_renderer_cache_is_bounded_in_bytes() -> None:
    frame_bytes = 64 * 64 * 3 * 8
    renderer = RadianceRenderer(GEOMETRY, POINT, CameraSpec(resolution=(64, 64), spp=1), variant="scalar_rgb",
                                max_bytes=2 * frame_bytes + 1)
    poses = [pose_at(30.0, 0.0, 45.0, phi) for phi in (180.0, 170.0, 160.0)]
    for pose in poses:
        renderer.render(pose, DIFFUSE)
    assert (renderer.stats.size, renderer.stats.nbytes) == (2, 2 * frame_bytes)
    renderer.render(poses[0], DIFFUSE)  # the oldest went first
    assert renderer.stats.misses == 4


def test_renderer_asks_for_evaluated_calls_when_the_material_does(monkeypatch: pytest.MonkeyPatch) -> None:
    """A material object (``to_dict()``) flagged ``needs_evaluated_calls`` is rendered with symbolic calls off."""

    class PythonPluginLike:
        needs_evaluated_calls = True

        def to_dict(self) -> dict[str, Any]:
            return dict(DIFFUSE)

    seen: list[bool] = []
    original = render_module.render_radiance

    def spy(scene: Any, variant: Any = None, seed: int = 0, *, evaluated_calls: bool = False) -> np.ndarray:
        seen.append(evaluated_calls)
        return original(scene, variant, seed, evaluated_calls=evaluated_calls)

    monkeypatch.setattr(render_module, "render_radiance", spy)
    renderer = RadianceRenderer(GEOMETRY, POINT, CAMERA)
    pose = pose_at(30.0, 0.0, 45.0, 180.0)
    flagged = renderer.roi_radiance(pose, PythonPluginLike())
    plain = renderer.roi_radiance(pose, DIFFUSE, seed=1)
    assert seen == [True, False]
    np.testing.assert_allclose(flagged, plain, rtol=1e-3)


def test_variant_is_forced_and_the_previous_one_restored() -> None:
    require_variant("llvm_ad_rgb")
    scene = build_scene(GEOMETRY, pose_at(30.0, 0.0, 45.0, 180.0), DIFFUSE, POINT, CAMERA)
    with mv.use_variant("scalar_rgb"):
        llvm = render_radiance(scene, variant="llvm_ad_rgb")
        assert mi.variant() == "scalar_rgb"
        picked = render_radiance(scene)  # picks llvm (the fastest) and restores scalar again
        assert mi.variant() == "scalar_rgb"
        forced = render_radiance(scene, variant="scalar_rgb")
    np.testing.assert_allclose(llvm[24:40, 24:40], forced[24:40, 24:40], rtol=5e-3)
    np.testing.assert_allclose(picked, llvm)  # same variant, seed and scene: the same image
    with pytest.raises(mv.VariantUnavailable, match="no_such_variant"):
        render_radiance(scene, variant="no_such_variant")


def test_environment_variable_forces_the_variant(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(mv.ENV_VAR, "scalar_rgb")
    renderer = RadianceRenderer(GEOMETRY, POINT, CameraSpec(resolution=(8, 8), spp=1, variant="llvm_ad_rgb"))
    pose = pose_at(30.0, 0.0, 45.0, 180.0)
    renderer.render(pose, DIFFUSE)
    monkeypatch.delenv(mv.ENV_VAR)
    renderer.render(pose, DIFFUSE)
    # Different variants are different cache entries (where llvm loads; else both resolve to scalar).
    assert renderer.stats.misses == (2 if mv.unavailable_reason("llvm_ad_rgb") is None else 1)


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
