"""The Mitsuba 3 scene of the rig at one pose: the sample, one light and the camera, nothing else.

World frame and units are those of ``rig.instrument.kinematics`` (metres, sample centre at the origin, z up along
the arm axis). What is modelled, and what is not ("model only what the scene requires"):

- The sample is a ``rectangle`` of the rig's sample size. Its ``to_world`` maps local x to
  ``pose.sample_tangent``, y to ``pose.sample_bitangent`` and z to ``pose.sample_normal``, centred at
  ``pose.sample_centre_m``. Mitsuba builds the BSDF's shading frame from the same axes (s along local x),
  so the BSDF local frame is the kinematics' local frame: phi angles and anisotropic materials agree.
  The rectangle is one-sided for ordinary BSDFs: seen or lit from behind it renders black.
- A curved sample (``rig.instrument.sample_surface``) is Mitsuba's ``sphere``, its pole on the bitangent, or
  its open ``cylinder``, its axis along the bitangent, placed as that module places them (the top touching
  the sample centre). Mitsuba's shading frame on both has its s axis along pole/axis x normal, which is the
  module's tangent: the BRDF's local frame is the one the angles are measured in there too.
- One light at ``pose.light_position_m``: an isotropic ``point`` emitter, or a ``spot`` aimed at the
  aim point (``pose.aim()``, the arms' axis); both are delta lights. A point light of ``LightSpec.size_m``
  > 0 is a Lambertian disk of that diameter facing the aim point, with the same on-axis intensity.
- A ``perspective`` camera at ``pose.camera_position_m`` looking at the aim point (image up is the
  world +z, the arm axis, unless the view is nearly vertical). The rig's ``camera_fov_deg`` is a cone;
  by default it spans the image's smaller side (``fov_axis="smaller"``), so the circle of
  ``RigGeometry.view_radius_m`` lies inside the image.
- No environment light, no sample holder, no arms, no back side of the sample, no interreflection: a flat
  sample under one light needs direct lighting only, so the integrator is ``direct``. Light from a delta
  emitter can only be reached by emitter sampling (a BSDF-sampled ray never hits a point), so
  ``bsdf_samples`` is 0 and one ``emitter_samples`` is exact; spp then only antialiases (sub-pixel
  positions), which matters at the sample's edges and for textured materials. A smooth (delta) BSDF, such
  as ``conductor``, renders black: a mirror shows a point light at a single point only.

The specs (light, camera, pixel boxes) are in ``simulator.render.spec``; the numpy model of the camera
and the ROI it picks in ``simulator.render.view``.
"""

from __future__ import annotations

import math
from typing import Any

import mitsuba.scalar_rgb as mis  # variant-free scalar types; the transforms load under any variant
import numpy as np
import numpy.typing as npt

from rig.instrument.camera_model import up_for
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics_types import RigPose
from rig.instrument.sample_surface import FLAT, SampleShape
from simulator.render.spec import Box, BSDFLike, CameraSpec, LightSpec, bsdf_dict, check_box
from simulator.render.view import _unit, _vec3, camera_view

FloatArray = npt.NDArray[np.float64]


def _transform(matrix: FloatArray) -> Any:
    return mis.ScalarTransform4f(np.asarray(matrix, dtype=np.float64))


def _look_at(origin: FloatArray, forward: FloatArray, left: FloatArray, up: FloatArray) -> Any:
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, up, forward, origin
    return _transform(m)


def _look_at_matrix(origin: FloatArray, forward: FloatArray, left: FloatArray) -> FloatArray:
    """A 4x4 frame at ``origin`` whose z axis is ``forward`` (a disk's normal faces along its z)."""
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, np.cross(forward, left), forward, origin
    return m


def _emitter(geometry: RigGeometry, pose: RigPose, light: LightSpec) -> dict[str, Any]:
    position = _vec3("light_position_m", pose.light_position_m)
    intensity = {"type": "rgb", "value": list(light.rgb())}
    forward = _unit(_vec3("aim_m", pose.aim()) - position)
    left = _unit(np.cross(up_for(forward), forward))
    if light.kind == "point" and light.size_m > 0:
        # A Lambertian disk facing the aim point with the point light's on-axis intensity: I = L pi r^2.
        r = 0.5 * light.size_m
        scale = np.diag([r, r, 1.0, 1.0])
        radiance = {"type": "rgb", "value": [v / (math.pi * r * r) for v in light.rgb()]}
        return {"type": "disk", "to_world": _transform(_look_at_matrix(position, forward, left) @ scale),
                "emitter": {"type": "area", "radiance": radiance}}  # fmt: skip
    if light.kind == "point":
        return {"type": "point", "position": position.tolist(), "intensity": intensity}
    beam, cutoff = light.cone_deg(geometry)
    return {
        "type": "spot",
        "to_world": _look_at(position, forward, left, np.cross(forward, left)),
        "intensity": intensity,
        "cutoff_angle": cutoff,
        "beam_width": beam,
    }


def sample_to_world(geometry: RigGeometry, pose: RigPose) -> FloatArray:
    """4x4 matrix taking Mitsuba's [-1, 1]^2 rectangle to the sample: x -> tangent, y -> bitangent, z -> normal."""
    m = np.eye(4)
    m[:3, 0] = 0.5 * geometry.sample_width_m * _vec3("sample_tangent", pose.sample_tangent)
    m[:3, 1] = 0.5 * geometry.sample_height_m * _vec3("sample_bitangent", pose.sample_bitangent)
    m[:3, 2] = _vec3("sample_normal", pose.sample_normal)
    m[:3, 3] = _vec3("sample_centre_m", pose.sample_centre_m)
    return m


def sample_shape_dict(geometry: RigGeometry, pose: RigPose, shape: SampleShape) -> dict[str, Any]:
    """The sample's Mitsuba shape (no BSDF): a rectangle, or the sphere or open cylinder of ``shape``."""
    if shape.kind == "flat":
        return {"type": "rectangle", "to_world": _transform(sample_to_world(geometry, pose))}
    r = shape.radius_m
    normal, bitangent = _vec3("sample_normal", pose.sample_normal), _vec3("sample_bitangent", pose.sample_bitangent)
    centre = _vec3("sample_centre_m", pose.sample_centre_m) - r * normal
    if shape.kind == "sphere":
        # Local z (Mitsuba's pole, whose longitude gives the s axis) on the bitangent; (n, t, b) is right-handed.
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2] = r * normal, r * _vec3("sample_tangent", pose.sample_tangent), r * bitangent
        m[:3, 3] = centre
        return {"type": "sphere", "to_world": _transform(m)}
    half = 0.5 * geometry.sample_height_m
    return {"type": "cylinder", "p0": (centre - half * bitangent).tolist(), "p1": (centre + half * bitangent).tolist(),
            "radius": r}  # fmt: skip


def _extent(geometry: RigGeometry, shape: SampleShape) -> float:
    """How far (m) the sample reaches from its centre: the square's half-diagonal, or the curved body's far side."""
    half_diagonal = 0.5 * math.hypot(geometry.sample_width_m, geometry.sample_height_m)
    if shape.kind == "flat":
        return half_diagonal
    return max(half_diagonal, math.hypot(2.0 * shape.radius_m, 0.5 * geometry.sample_height_m))


def build_scene(
    geometry: RigGeometry,
    pose: RigPose,
    bsdf: BSDFLike,
    light: LightSpec,
    camera: CameraSpec,
    crop: Box | None = None,
    shape: SampleShape = FLAT,
) -> dict[str, Any]:
    """The Mitsuba scene dict of the rig at one pose (metres, W/sr); ``crop`` renders only that pixel box."""
    view = camera_view(geometry, pose, camera)
    distance = float(np.linalg.norm(view.origin - _vec3("sample_centre_m", pose.sample_centre_m)))
    half_diagonal = _extent(geometry, shape)
    w, h = camera.resolution
    film: dict[str, Any] = {
        "type": "hdrfilm",
        "width": w,
        "height": h,
        "pixel_format": "rgb",
        "component_format": "float32",
        "rfilter": {"type": "box"},  # each pixel averages its own footprint only, so crops match the full frame
    }
    if crop is not None:
        x0, y0, x1, y1 = check_box(crop, camera.resolution, "crop")
        film.update(crop_offset_x=x0, crop_offset_y=y0, crop_width=x1 - x0, crop_height=y1 - y0)
    return {
        "type": "scene",
        # A delta light is reached by emitter sampling alone; a disk also by BSDF sampling (MIS), which a
        # near-mirror needs to see it.
        "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 1 if light.size_m > 0 else 0},
        "sensor": {
            "type": "perspective",
            "fov": camera.fov(geometry),
            "fov_axis": camera.fov_axis,
            # Clip planes bracket the sample with margin whatever the arm radius.
            "near_clip": 0.5 * (distance - half_diagonal),
            "far_clip": 2.0 * (distance + half_diagonal),
            "to_world": _look_at(view.origin, view.forward, view.left, view.up),
            "film": film,
            "sampler": {"type": camera.sampler, "sample_count": camera.spp, "seed": camera.seed},
        },
        "sample": {**sample_shape_dict(geometry, pose, shape), "bsdf": bsdf_dict(bsdf)},
        "light": _emitter(geometry, pose, light),
    }
