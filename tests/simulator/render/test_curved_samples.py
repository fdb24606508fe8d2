"""Curved samples in the rendered scene: Mitsuba as an independent oracle of rig.instrument.sample_surface.

Mitsuba's own ray tracer finds where the camera's pixel rays meet its ``sphere`` and ``cylinder`` (points,
normals, the shading frame's s axis), and its renders of a Lambertian sphere and cylinder under the point light
must show rho/pi * I * cos(theta_i) / d^2 wherever ``surface_hits`` and ``local_angles`` say a pixel sees the
surface, and black wherever they say it sees nothing.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from model.mitsuba import variant as mv
from rig.instrument.kinematics import Joints, RigPose, world_pose
from rig.instrument.sample_surface import FLAT, SampleShape, local_angles
from simulator.render.renderer import RadianceRenderer, render_radiance
from simulator.render.scene import build_scene
from simulator.render.spec import CameraSpec
from simulator.render.view import camera_view, default_roi, pixel_hits
from tests.simulator.render.render_helpers import ALBEDO, DIFFUSE, GEOMETRY, INTENSITY, POINT

pytestmark = pytest.mark.mitsuba

SHAPES = [SampleShape("sphere", 0.02), SampleShape("cylinder", 0.012)]
#: Oblique light and camera and a turned stage: no symmetry of the pose hides a misplaced axis.
POSE = world_pose(GEOMETRY, Joints(light=50.0, camera=-25.0, tilt=20.0, roll=30.0))
CAMERA = CameraSpec(resolution=(64, 48), spp=256, sampler="stratified")
SUB = 16  # sub-pixel grid of the prediction: the stratified sampler's 16 x 16 strata


def _grazing(shape: SampleShape, pose: RigPose, origin: np.ndarray, d: np.ndarray) -> np.ndarray:
    """How far (m) each ray's closest approach to the centre (sphere) or axis (cylinder) is from the radius."""
    centre = pose.sample_centre_m - shape.radius_m * pose.sample_normal
    oc = np.broadcast_to(origin - centre, d.shape)
    if shape.kind == "cylinder":
        b = pose.sample_bitangent
        oc, d = oc - np.outer(oc @ b, b), d - np.outer(d @ b, b)
    t = -np.sum(oc * d, -1) / np.sum(d * d, -1)
    out: np.ndarray = np.abs(np.linalg.norm(oc + t[:, None] * d, axis=-1) - shape.radius_m)
    return out


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: s.kind)
def test_mitsuba_meets_each_pixel_ray_where_the_surface_module_does(shape: SampleShape) -> None:
    view = camera_view(GEOMETRY, POSE, CAMERA)
    py, px = np.mgrid[0:48, 0:64] + 0.5
    hits = pixel_hits(view, GEOMETRY, POSE, shape, px, py)
    rays = view.ray(px, py).reshape(-1, 3)
    with mv.use_variant("scalar_rgb"):
        scene = mi.load_dict({"type": "scene", "sample": build_scene(GEOMETRY, POSE, DIFFUSE, POINT, CAMERA,
                                                                     shape=shape)["sample"]})  # fmt: skip
        found = []
        for d in rays:
            si = scene.ray_intersect(mi.Ray3f(mi.Point3f(*view.origin), mi.Vector3f(*d)))
            ok = bool(si.is_valid()) and float(dr.dot(si.n, mi.Vector3f(*d))) < 0  # met from outside
            found.append((ok, np.array(si.p), np.array(si.sh_frame.n), np.array(si.sh_frame.s)))
    hit = hits.hit.reshape(-1)
    clear = _grazing(shape, POSE, view.origin, rays) > 1e-6  # float32 rays may split the silhouette otherwise
    theirs = np.array([f[0] for f in found])
    assert hit.sum() > 200 and (~hit).sum() > 200
    np.testing.assert_array_equal(theirs[clear], hit[clear])
    both = theirs & hit
    # Mitsuba intersects in float32 half a metre from the camera: micrometres, and normals to ~1e-3 on a 12 mm radius.
    for name, k, tol in (("point", 1, 2e-5), ("normal", 2, 2e-3), ("tangent", 3, 2e-3)):
        ours = {"point": hits.point_m, "normal": hits.normal, "tangent": hits.tangent}[name].reshape(-1, 3)[both]
        mitsuba = np.array([f[k] for f in found])[both]
        assert np.abs(ours - mitsuba).max() < tol, name


def _predicted(shape: SampleShape) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lambert's radiance per pixel (mean over a 4 x 4 sub-grid), and which pixels lie wholly on / off the surface."""
    view = camera_view(GEOMETRY, POSE, CAMERA)
    w, h = CAMERA.resolution
    offsets = (np.arange(SUB) + 0.5) / SUB
    # Row i * SUB + a, column j * SUB + b is sub-point (a, b) of pixel (j, i): reshaped to (h, SUB, w, SUB) below.
    py, px = np.meshgrid((np.arange(h)[:, None] + offsets).reshape(-1), (np.arange(w)[:, None] + offsets).reshape(-1),
                         indexing="ij")  # fmt: skip
    hits = pixel_hits(view, GEOMETRY, POSE, shape, px, py)
    flat = type(hits)(*(np.asarray(v).reshape(-1, 3) for v in (hits.point_m, hits.normal, hits.tangent)),
                      hits.hit.reshape(-1))  # fmt: skip
    ang = local_angles(flat, POSE.light_position_m, POSE.camera_position_m)
    cos_i = np.cos(np.radians(ang.theta_i_deg))
    radiance = np.where(flat.hit & (cos_i > 0), ALBEDO / np.pi * INTENSITY * cos_i / ang.light_distance_m**2, 0.0)
    per_sub = radiance.reshape(h, SUB, w, SUB)
    lit = (flat.hit & (cos_i > 0.05)).reshape(h, SUB, w, SUB)
    # Whole pixels (and their neighbours) on the lit surface, away from edges, silhouettes and the terminator,
    # where the radiance is smooth across a pixel; or wholly off it.
    inside = _eroded(lit.all(axis=(1, 3)))
    outside = _eroded((~flat.hit).reshape(h, SUB, w, SUB).all(axis=(1, 3)))
    return per_sub.mean(axis=(1, 3)), inside, outside


def _eroded(mask: np.ndarray) -> np.ndarray:
    """Pixels of the mask whose eight neighbours are in it too."""
    padded = np.pad(mask, 1, constant_values=False)
    h, w = mask.shape
    out = np.ones_like(mask)
    for dy in range(3):
        for dx in range(3):
            out &= padded[dy:dy + h, dx:dx + w]
    return out


@pytest.mark.parametrize("shape", [*SHAPES, FLAT], ids=lambda s: s.kind)
def test_a_lambertian_sample_renders_the_point_source_law_at_each_hit(shape: SampleShape) -> None:
    image = render_radiance(build_scene(GEOMETRY, POSE, DIFFUSE, POINT, CAMERA, shape=shape), "scalar_rgb")
    want, inside, outside = _predicted(shape)
    assert inside.sum() > 100 and outside.sum() > 100
    for channel in range(3):
        got = image[..., channel]
        # The radiance changes by up to a quarter across a pixel of the sphere: 256 jittered strata against the
        # strata's centres leave ~1e-4 typically, 1e-3 at the steepest pixels.
        np.testing.assert_allclose(got[inside], want[inside], rtol=3e-3)
        assert np.median(np.abs(got[inside] / want[inside] - 1.0)) < 3e-4
        assert np.all(got[outside] == 0.0)


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: s.kind)
def test_the_default_roi_of_a_curved_sample_sits_on_its_top(shape: SampleShape) -> None:
    camera = CameraSpec(resolution=(512, 512), spp=4)
    pose = world_pose(GEOMETRY, Joints(light=40.0, camera=-30.0, tilt=0.0, roll=0.0))
    x0, y0, x1, y1 = default_roi(GEOMETRY, pose, POINT, camera, shape)
    assert x0 < 256 < x1 and y0 < 256 < y1
    view = camera_view(GEOMETRY, pose, camera)
    py, px = np.mgrid[y0:y1, x0:x1] + 0.5
    hits = pixel_hits(view, GEOMETRY, pose, shape, px, py)
    assert hits.hit.all()
    # Its normals span no more than the flat sample's central region does seen from the camera (~1.4 deg).
    spread = np.degrees(np.arccos(np.clip(hits.normal @ pose.sample_normal, -1.0, 1.0)))
    assert spread.max() <= np.degrees(np.arctan2(0.0125, 0.5)) + 1e-9
    # ... and it is far smaller than a flat sample's, whose directions vary only with the view.
    flat = default_roi(GEOMETRY, pose, POINT, camera)
    assert (x1 - x0) * (y1 - y0) < 0.1 * (flat[2] - flat[0]) * (flat[3] - flat[1])
    renderer = RadianceRenderer(GEOMETRY, POINT, camera, shape=shape)
    assert renderer.roi(pose) == (x0, y0, x1, y1)
    radiance = renderer.roi_radiance(pose, DIFFUSE)
    assert np.all(radiance > 0)
    # A flat tile shown in its place renders as flat, with its own cache entry.
    tile = renderer.render(pose, DIFFUSE, crop=(x0, y0, x1, y1), shape=FLAT)
    assert renderer.stats.size == 2 and np.all(tile > 0)
