"""The renderer comparison: the model's predicted reading against the rendered, HDR-merged ROI reading.

For each BRDF direction pair (degrees) :func:`compare_sweep` solves the nominal joints, renders the ROI
with Mitsuba (``RadianceRenderer``, cached), captures a bracket and its darks through the sensor model
(``SimulatedCamera``), merges it (``merge_linear``, sum weighting) and reduces the ROI (``reduce_roi``,
propagated error: the geometry shades the ROI, so pixel scatter is not noise). Readings are counts/s at
gain 1, of one channel or (``channel=None``) the mean of RGB.

``predicted`` is ``model.predict_radiance`` at the nominal (ROI-centre) directions with a point light at
the light arm's radius, times ``CameraOptics.counts_per_radiance``: what a runner assumes. ``extended``
evaluates the model at ``subsamples``^2 positions inside every ROI pixel (the pinhole model of
``simulator.render.view``), each with its own directions, light distance, spot falloff and sample
coverage, averaged as the box-filtered film does: what the render should give up to noise. Its parts
isolate the causes: light distance and ROI extent (``extended_unbounded - predicted``), then the
sample's edges, then the spot beam's edge.

Noise: ``measured_se`` is the reading's standard error, its stated uncertainty (``z`` is in its units,
``z_extended`` in those of it and the render noise combined); ``expected_rel_noise`` the sensor model's
for that bracket and the extended per-pixel rates; ``render_rel_noise`` the spp sampling noise of the ROI
mean, each pixel's sub-position variance over spp (exact for the ``independent`` sampler, an upper bound
for ``stratified``).

Explanations (:func:`explain`): ``agrees`` when |measured - predicted| <= z_bound sigma. Otherwise, if
``extended`` accounts for the reading (within z_bound times sensor and render noise combined), the larger
share names the cause: ``render noise`` when the gap to ``extended`` needs it (exceeds z_bound sigma) and
outweighs every modelled part, else the largest part (``finite light distance and ROI extent``, ``sample
edge in ROI``, ``spot beam edge in ROI``), or ``sensor noise`` when all parts together move the
prediction by under one sigma (a fluctuation just beyond the bound). Beyond ``grazing_deg`` extent and
render noise read ``grazing``: angles change fastest across the ROI and cos(theta) is smallest there. A
gap ``extended`` does not account for is ``grazing`` beyond ``grazing_deg``, else ``unexplained``.
``unreachable`` points carry the kinematics' reason and no numbers.

Exposure: ``exposures_s`` fixes the bracket, else each point is metered on its render (a camera's preview):
the longest of ``frames`` frames ``stops`` EV apart puts the ROI's brightest pixel at ``meter_fraction``
(80 %) of saturation; it sets the noise, the shorter ones guard against a misjudged peak.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

import numpy as np
import numpy.typing as npt

from acquisition.files.atomic import atomic_path
from acquisition.hdr.merge import merge_linear
from acquisition.noise import SensorNoise
from acquisition.roi import reduce_roi
from model.base import BRDF
from model.mitsuba.materials import to_mitsuba
from model.predict import predict_radiance
from model.radiometry import PointLight, SpotLight
from rig.instrument.geometry import RigGeometry
from rig.instrument.kinematics import Joints, Unreachable, forward, inverse, world_pose
from rig.instrument.kinematics_types import Branch, RigPose
from simulator.camera.simulated import CameraOptics, SimulatedCamera
from simulator.render.renderer import RadianceRenderer, resolve_variant
from simulator.render.spec import Box, CameraSpec, LightSpec
from simulator.render.view import camera_view, pixel_on_sample

FloatArray = npt.NDArray[np.float64]
Direction = tuple[float, float, float, float]


class Explanation(StrEnum):
    """Why a rendered reading differs from the point prediction (or that it does not)."""

    AGREES = "agrees"
    EXTENT = "finite light distance and ROI extent"
    SAMPLE_EDGE = "sample edge in ROI"
    BEAM_EDGE = "spot beam edge in ROI"
    GRAZING = "grazing"
    RENDER_NOISE = "render noise"
    SENSOR_NOISE = "sensor noise"
    UNEXPLAINED = "unexplained"
    UNREACHABLE = "unreachable"


@dataclass(frozen=True)
class ExtendedPrediction:
    """The model over an ROI's pixel footprints: ROI means per channel (3,) in counts/s, and what shaped them.

    ``mean`` models everything, ``unbounded`` neither edges nor spot falloff, ``sample_only`` the sample's
    edges; ``render_var`` is the spp variance of the rendered ROI mean in (counts/s)^2, ``pixel_rate`` the
    (H, W, 3) pixel means; the fractions count sub-pixel positions off the sample, and on it off the full beam.
    """

    mean: FloatArray
    unbounded: FloatArray
    sample_only: FloatArray
    render_var: FloatArray
    pixel_rate: FloatArray
    off_sample_fraction: float
    off_beam_fraction: float


@dataclass(frozen=True)
class ComparisonRow:
    """One point: directions in degrees, readings in counts/s, ``*_rel_noise`` as relative standard deviations."""

    index: int
    theta_i: float
    phi_i: float
    theta_o: float
    phi_o: float
    explanation: Explanation
    detail: str
    predicted: float = math.nan
    extended: float = math.nan
    extended_unbounded: float = math.nan
    measured: float = math.nan
    measured_se: float = math.nan
    expected_rel_noise: float = math.nan
    render_rel_noise: float = math.nan
    ratio: float = math.nan
    ratio_extended: float = math.nan
    z: float = math.nan
    z_extended: float = math.nan
    off_sample_fraction: float = math.nan
    off_beam_fraction: float = math.nan
    roi_pixels: int = 0
    saturated_pixels: int = 0
    exposures_s: tuple[float, ...] = ()
    joints: tuple[tuple[str, float], ...] = ()

    @property
    def reachable(self) -> bool:
        """Whether the point was measured (False: ``detail`` holds the kinematics' reason)."""
        return self.explanation is not Explanation.UNREACHABLE

    @property
    def measured_rel_se(self) -> float:
        """The reading's standard error over its value (dimensionless)."""
        return self.measured_se / abs(self.measured) if self.measured else math.inf


# (heading, width, attribute, format); a "%" format prints 100 times the value with that many decimals.
_COLUMNS = (
    ("#", 3, "index", "d"), ("th_i", 6, "theta_i", ".1f"), ("ph_i", 6, "phi_i", ".1f"), ("th_o", 6, "theta_o", ".1f"),
    ("ph_o", 6, "phi_o", ".1f"), ("predicted", 10, "predicted", ".4g"), ("extended", 10, "extended", ".4g"),
    ("measured", 10, "measured", ".4g"), ("se%", 6, "measured_rel_se", "%3"), ("exp%", 6, "expected_rel_noise", "%3"),
    ("rnd%", 6, "render_rel_noise", "%3"), ("ratio", 7, "ratio", ".4f"), ("r_ext", 7, "ratio_extended", ".4f"),
    ("z", 9, "z", "+.3g"), ("z_ext", 9, "z_extended", "+.3g"), ("off%", 5, "off_sample_fraction", "%1"),
    ("beam%", 5, "off_beam_fraction", "%1"),
)  # fmt: skip


def _cell(row: ComparisonRow, attribute: str, fmt: str) -> str:
    value = getattr(row, attribute)
    if isinstance(value, float) and not math.isfinite(value):
        return "-"
    return f"{100.0 * value:.{fmt[1:]}f}" if fmt.startswith("%") else format(value, fmt)


def _csv_value(value: object) -> object:
    if isinstance(value, Explanation):
        return value.value
    if isinstance(value, tuple):  # exposures in s, or (joint, degrees) pairs
        return ";".join(f"{v[0]}={v[1]:.6g}" if isinstance(v, tuple) else f"{v:.6g}" for v in value)
    return value


@dataclass(frozen=True)
class ComparisonResult:
    """A sweep's comparison: one row per requested point (unreachable ones included) and its settings."""

    rows: tuple[ComparisonRow, ...]
    material: str
    plugin_note: str
    variant: str
    spp: int
    z_bound: float
    grazing_deg: float
    channel: int | None

    def counts(self) -> dict[str, int]:
        """Number of points per explanation."""
        return dict(Counter(r.explanation.value for r in self.rows))

    def to_table(self) -> str:
        """Fixed-width text: a line per point (angles in deg, readings in counts/s, noise in %), then details."""
        head = " ".join(f"{name:>{w}}" for name, w, _, _ in _COLUMNS) + "  explanation"
        which = "mean of RGB" if self.channel is None else f"channel {self.channel}"
        settings = f"{self.variant}, {self.spp} spp, {which}; agrees when |z| <= {self.z_bound:g}"
        lines = [f"{self.material}: {self.plugin_note}", f"{settings}; grazing beyond {self.grazing_deg:g} deg", head]
        lines += ["-" * len(head)] + [" ".join(f"{_cell(r, a, f):>{w}}" for _, w, a, f in _COLUMNS) + "  "
                                      + r.explanation.value for r in self.rows] + [""]  # fmt: skip
        lines.extend(f"#{r.index} {r.explanation.value}: {r.detail}" for r in self.rows)
        return "\n".join(lines)

    def to_csv(self, path: str | Path) -> Path:
        """Write every row (angles in deg, readings in counts/s, exposures in s) as CSV, atomically; the path."""
        names = [f.name for f in dataclasses.fields(ComparisonRow)]
        with atomic_path(path) as tmp, open(tmp, "w", newline="") as fh:
            writer = csv.writer(fh)
            writer.writerow(names)
            for r in self.rows:
                writer.writerow([_csv_value(getattr(r, n)) for n in names])
        return Path(path)


def subpixel_lattice(n: int) -> tuple[FloatArray, FloatArray]:
    """Offsets (x, y) in pixels of n positions in [0, 1)^2: a Fibonacci lattice with n distinct x and y values."""
    golden = round(n * (math.sqrt(5.0) - 1.0) / 2.0)
    g = next(c for c in range(max(golden, 1), 0, -1) if math.gcd(c, n) == 1)
    k = np.arange(n)
    # Distinct x and y per position resolve pixel-aligned sample edges to 1/n pixel, not 1/sqrt(n).
    return (k + 0.5) / n, ((k * g) % n + 0.5) / n


def extended_prediction(
    material: BRDF, geometry: RigGeometry, pose: RigPose, light: LightSpec, camera: CameraSpec, box: Box,
    counts_per_radiance: float, subsamples: int = 8,
) -> ExtendedPrediction:  # fmt: skip
    """The model in counts/s over ``subsamples``^2 positions per pixel of the box, each with its own geometry."""
    x0, y0, x1, y1 = box
    n_sub = subsamples * subsamples
    sx, sy = subpixel_lattice(n_sub)
    py, px = np.broadcast_arrays(np.arange(y0, y1)[:, None, None] + sy, np.arange(x0, x1)[None, :, None] + sx)
    p, uv = pixel_on_sample(camera_view(geometry, pose, camera), pose, px.reshape(-1), py.reshape(-1))
    hit = np.all(np.isfinite(p), axis=-1)
    p = np.where(hit[:, None], p, 0.0)
    frame = np.stack([pose.sample_tangent, pose.sample_bitangent, pose.sample_normal])
    to_light, to_cam = pose.light_position_m - p, pose.camera_position_m - p
    dist = np.linalg.norm(to_light, axis=-1)
    wi = (to_light / dist[:, None]) @ frame.T
    wo = (to_cam / np.linalg.norm(to_cam, axis=-1, keepdims=True)) @ frame.T
    n = wi.shape[0]
    f = np.broadcast_to(np.asarray(material.eval(wi, wo), dtype=np.float64).reshape(n, -1), (n, 3))
    irradiance = np.asarray(light.rgb()) * (np.maximum(wi[:, 2], 0.0) / dist**2)[:, None]
    rate = np.where(hit[:, None], f * irradiance, 0.0) * counts_per_radiance
    half_w, half_h = 0.5 * geometry.sample_width_m, 0.5 * geometry.sample_height_m
    on = hit & (np.abs(uv[:, 0]) <= half_w) & (np.abs(uv[:, 1]) <= half_h)
    beam = np.ones(n)
    if light.kind == "spot":
        width, cutoff = light.cone_deg(geometry)
        axis = np.asarray(pose.sample_centre_m) - pose.light_position_m  # the spot aims at the sample centre
        off_axis = np.arccos(np.clip(-(to_light / dist[:, None]) @ (axis / np.linalg.norm(axis)), -1.0, 1.0))
        spot = SpotLight(1.0, 1.0, beam_width=math.radians(width), cutoff=math.radians(cutoff))
        beam = np.asarray(spot.intensity_at(off_axis), dtype=np.float64).reshape(n)
    full = (rate * (on * beam)[:, None]).reshape(y1 - y0, x1 - x0, n_sub, 3)
    # A pixel's render averages spp independent sub-pixel samples: its variance is the footprint's over spp.
    render_var = full.var(axis=2).sum(axis=(0, 1)) / camera.spp / ((y1 - y0) * (x1 - x0)) ** 2
    return ExtendedPrediction(
        full.mean(axis=(0, 1, 2)), rate.mean(axis=0), (rate * on[:, None]).mean(axis=0), render_var,
        full.mean(axis=2), float(1.0 - on.mean()), float(np.sum(on & (beam < 1.0)) / max(int(on.sum()), 1)),
    )  # fmt: skip


def metered_bracket(
    peak_rate: float, noise: SensorNoise, frames: int = 3, stops: float = 2.0, fraction: float = 0.8,
    min_s: float = 1e-5, max_s: float = 30.0,
) -> tuple[float, ...]:  # fmt: skip
    """Exposures in s, longest first: the peak rate (counts/s) at ``fraction`` of saturation, ``stops`` EV apart."""
    longest = max_s if peak_rate <= 0 else min(max(fraction * noise.saturation_dn() / peak_rate, min_s), max_s)
    return tuple(max(longest * 2.0 ** (-stops * k), min_s) for k in range(frames))


def expected_variance(rate: npt.ArrayLike, exposures_s: Sequence[float], noise: SensorNoise) -> FloatArray:
    """Per-pixel variance in (counts/s)^2 of the sum merge with a dark frame per exposure, for rates in counts/s."""
    x = np.asarray(rate, dtype=np.float64)
    num, den = np.zeros_like(x), np.zeros_like(x)
    level = noise.saturation_dn()
    for t in exposures_s:
        # The merge's clip threshold (saturation_sigma 4) decides which frames a pixel uses.
        used = x * t < level - 4.0 * math.sqrt(float(noise.variance_dn2(level, t)))
        num += np.where(used, noise.variance_dn2(x * t, t) + noise.variance_dn2(0.0, t), 0.0)
        den += np.where(used, t, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 0, num / den**2, np.inf)


def explain(
    predicted: float, measured: float, extended: float, parts: Mapping[Explanation, float], se: float,
    render_se: float, grazing: bool, z_bound: float = 3.0,
) -> Explanation:  # fmt: skip
    """The rule naming a point's cause (see the module); readings, parts and errors in one unit (counts/s).

    ``parts`` maps EXTENT, SAMPLE_EDGE and BEAM_EDGE to their shares of ``extended - predicted``; ``se``
    is the reading's standard error (sensor), ``render_se`` the render's sampling noise of the ROI mean.
    """
    if abs(measured - predicted) <= z_bound * se:
        return Explanation.AGREES
    gap = measured - extended
    if not abs(gap) <= z_bound * math.hypot(se, render_se):
        return Explanation.GRAZING if grazing else Explanation.UNEXPLAINED
    cause = max(parts, key=lambda k: abs(parts[k]))
    small = abs(extended - predicted) < se
    if abs(gap) > z_bound * se and (small or abs(gap) > abs(parts[cause])):
        cause = Explanation.RENDER_NOISE
    elif small:
        cause = Explanation.SENSOR_NOISE
    if grazing and cause in (Explanation.EXTENT, Explanation.RENDER_NOISE):
        cause = Explanation.GRAZING
    return cause


def _detail(
    row: ComparisonRow, parts: Mapping[Explanation, float], se: float, render_se: float, z: float, grazing_deg: float
) -> str:
    pred, meas, ext = row.predicted, row.measured, row.extended
    shares = ", ".join(f"{k.value} {v / pred:+.3%}" for k, v in parts.items() if abs(v) >= 5e-6 * abs(pred)) or "none"
    text = (
        f"measured/predicted - 1 = {meas / pred - 1:+.3%} ({row.z:+.1f} sigma); extended - predicted: {shares}; "
        f"measured/extended - 1 = {meas / ext - 1:+.3%}; noise: sensor {se / meas:.3%}, render {render_se / ext:.3%}"
    )
    if row.saturated_pixels:
        text += f"; {row.saturated_pixels} ROI pixels saturated in every frame, left out (a fixed bracket too long)"
    if abs(meas - ext) > z * math.hypot(se, render_se):
        text += "; the extended prediction does not account for it"
    theta = max(row.theta_i, row.theta_o)
    return text + (f"; theta {theta:g} deg > {grazing_deg:g} deg" if theta > grazing_deg else "")


def compare_sweep(
    material: BRDF, directions: Sequence[Direction], geometry: RigGeometry | None = None,
    light: LightSpec | None = None, camera: CameraSpec | None = None, noise: SensorNoise | None = None,
    optics: CameraOptics | None = None, *, exposures_s: Sequence[float] | None = None, frames: int = 3,
    stops: float = 2.0, meter_fraction: float = 0.8, seed: int = 0, variant: str | None = None,
    spp: int | None = None, channel: int | None = None, z_bound: float = 3.0, grazing_deg: float = 75.0,
    subsamples: int = 8, branch: Branch = "camera_cw",
) -> ComparisonResult:  # fmt: skip
    """Predicted against rendered, merged ROI readings in counts/s for (theta_i, phi_i, theta_o, phi_o) in deg."""
    geometry, light, noise = geometry or RigGeometry(), light or LightSpec(), noise or SensorNoise()
    optics, camera = optics or CameraOptics(), camera or CameraSpec()
    camera = dataclasses.replace(camera, spp=spp) if spp is not None else camera
    if subsamples < 1 or frames < 1 or not z_bound > 0 or channel not in (None, 0, 1, 2):
        raise ValueError(f"subsamples {subsamples!r}, frames {frames!r}, z_bound {z_bound!r}, channel {channel!r}: "
                         "expected >= 1, >= 1, > 0, and None (mean of RGB) or 0, 1, 2")  # fmt: skip
    mat, key = to_mitsuba(material), repr(material)
    renderer = RadianceRenderer(geometry, light, camera, variant=variant)
    gain = optics.counts_per_radiance(noise)
    point_light = PointLight(light.rgb(), geometry.light_radius_m)
    image: list[FloatArray] = [np.zeros((1, 1, 3))]
    cam = SimulatedCamera(lambda: image[0], noise=noise, optics=optics, seed=seed)

    def one(values: npt.ArrayLike, *, stds: bool = False) -> float:
        v = np.broadcast_to(np.asarray(values, dtype=np.float64), (3,))
        if channel is not None:
            return float(v[channel])
        # Channels carry independent sensor noise: standard errors of their mean add in quadrature.
        return float(math.sqrt(np.sum(v**2)) / 3.0) if stds else float(v.mean())

    rows: list[ComparisonRow] = []
    near: Joints | None = None
    for index, angles in enumerate(directions):
        ti, pi, to, po = (float(a) for a in angles)
        joints = inverse(geometry, ti, pi, to, po, branch=branch, near=near)
        if isinstance(joints, Unreachable):
            why = f"{joints.reason.value}: {joints.message}"
            rows.append(ComparisonRow(index, ti, pi, to, po, Explanation.UNREACHABLE, why))
            continue
        near = joints
        pose = world_pose(geometry, joints)
        box = renderer.roi(pose)
        image[0] = np.asarray(renderer.render(pose, mat, crop=box, key=key, seed=seed), dtype=np.float64)
        bracket = exposures_s or metered_bracket(float(image[0].max()) * gain, noise, frames, stops, meter_fraction)
        shots, darks = [], {}
        for t in bracket:
            cam.set_exposure(t)
            shots.append(cam.capture())
            darks[shots[-1].exposure_s] = cam.capture_dark()
        hdr = merge_linear(shots, noise, darks=darks, weighting="sum")
        crop = (0, 0, box[2] - box[0], box[3] - box[1])
        reading = reduce_roi(hdr.radiance, hdr.variance, crop, flags=hdr.saturated, error_model="propagated")
        d = forward(geometry, joints)
        pred = one(predict_radiance(material, d.wi, d.wo, point_light) * gain)
        ext = extended_prediction(material, geometry, pose, light, camera, box, gain, subsamples)
        expected = expected_variance(ext.pixel_rate, [s.exposure_s for s in shots], noise)
        expected_se = one(np.sqrt(expected.sum(axis=(0, 1))) / (expected.shape[0] * expected.shape[1]), stds=True)
        # Every channel renders from the same samples: their render noise is correlated and averages as stds.
        render_se = one(np.sqrt(ext.render_var))
        meas, se, extended = one(reading.mean), one(reading.std_error_propagated, stds=True), one(ext.mean)
        unbounded, on_sample = one(ext.unbounded), one(ext.sample_only)
        edges = {Explanation.SAMPLE_EDGE: on_sample - unbounded, Explanation.BEAM_EDGE: extended - on_sample}
        parts = {Explanation.EXTENT: unbounded - pred, **edges}
        with np.errstate(divide="ignore", invalid="ignore"):
            row = ComparisonRow(
                index, ti, pi, to, po,
                explain(pred, meas, extended, parts, se, render_se, max(ti, to) > grazing_deg, z_bound), "",
                predicted=pred, extended=extended, extended_unbounded=unbounded, measured=meas,
                measured_se=se, expected_rel_noise=expected_se / extended, render_rel_noise=render_se / extended,
                ratio=meas / pred, ratio_extended=meas / extended, z=(meas - pred) / se,
                z_extended=(meas - extended) / math.hypot(se, render_se), off_sample_fraction=ext.off_sample_fraction,
                off_beam_fraction=ext.off_beam_fraction, roi_pixels=int(reading.n_pixels),
                saturated_pixels=int(np.max(reading.n_flagged)),
                exposures_s=tuple(s.exposure_s for s in shots),
                joints=tuple((k, float(v)) for k, v in joints.as_dict().items()),
            )  # fmt: skip
            rows.append(dataclasses.replace(row, detail=_detail(row, parts, se, render_se, z_bound, grazing_deg)))
    used = resolve_variant(variant, camera.variant)
    return ComparisonResult(tuple(rows), key, mat.note, used, camera.spp, z_bound, grazing_deg, channel)
