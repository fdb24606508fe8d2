"""simulator.render.renderer: rendered radiance against the point-source law, crops, the cache, variants.

The radiance reference is independent of Mitsuba's scene code: the point-source law evaluated per pixel on
geometry computed here in numpy. A crop must hold the very pixels of the full frame; the cache's hits, misses
and byte bound, and the variant a render runs under, are checked on the renderer itself.
"""

from __future__ import annotations

from dataclasses import astuple
from typing import Any

import mitsuba as mi
import numpy as np
import pytest

from model.lambert import Lambert
from model.mitsuba import variant as mv
from model.predict import predict_radiance
from model.radiometry import PointLight
from rig.instrument.kinematics import RigPose, forward, inverse, require
from simulator.render import renderer as render_module
from simulator.render.renderer import RadianceRenderer, render_radiance, roi_mean, roi_radiance
from simulator.render.scene import build_scene
from simulator.render.spec import CameraSpec
from simulator.render.view import default_roi
from tests.mitsuba_helpers import ORACLE_VARIANTS, require_variant, rgb
from tests.simulator.render.render_helpers import (
    ALBEDO,
    ANGLES,
    CAMERA,
    DIFFUSE,
    GEOMETRY,
    INTENSITY,
    POINT,
    lambert_per_pixel,
    pose_at,
)

pytestmark = pytest.mark.mitsuba


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


def test_renderer_cache_hits_and_misses() -> None:
    renderer = RadianceRenderer(GEOMETRY, POINT, CAMERA, variant="scalar_rgb", maxsize=2)
    pose = pose_at(30.0, 0.0, 45.0, 180.0)
    first = renderer.render(pose, DIFFUSE)
    again = renderer.render(RigPose(*(v + 1e-9 for v in astuple(pose)[:6])), dict(DIFFUSE))
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
