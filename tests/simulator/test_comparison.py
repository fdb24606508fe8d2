"""The renderer comparison: rendered, merged ROI readings against the model's prediction, and why they differ."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest

import model as m
from acquisition.noise import SensorNoise
from rig.instrument.geometry import RigGeometry
from simulator.comparison import (
    ComparisonResult,
    Explanation,
    compare_sweep,
    expected_variance,
    explain,
    metered_bracket,
    subpixel_lattice,
)
from simulator.comparison_plot import plot_comparison
from simulator.render.spec import CameraSpec, LightSpec

pytestmark = pytest.mark.mitsuba

#: Gold (RGB complex index) at alpha 0.3: maps natively to Mitsuba's GGX roughconductor.
GOLD = m.CookTorrance(alpha=0.3, distribution="ggx", fresnel="conductor", eta=(0.18, 0.42, 1.37), k=(3.42, 2.35, 1.77))
LAMBERT = m.Lambert(0.5)
#: Away from grazing (theta <= 60 deg), in and out of the arm plane.
MODERATE = [(0.0, 0.0, 30.0, 180.0), (30.0, 0.0, 30.0, 180.0), (45.0, 0.0, 20.0, 180.0),
            (60.0, 0.0, 60.0, 180.0), (40.0, 90.0, 50.0, 200.0), (60.0, 0.0, 30.0, 180.0)]  # fmt: skip
#: Light and camera 0 deg apart (arms collide), and beyond the rig's 85 deg zenith.
UNREACHABLE = [(5.0, 0.0, 5.0, 0.0), (89.0, 0.0, 10.0, 180.0)]


@pytest.fixture(scope="module")
def default_roi_sweep() -> ComparisonResult:
    """GOLD with the default ROI (a quarter of the sample): specular peaks, grazing, unreachable points."""
    points = [(0.0, 0.0, 30.0, 180.0), (30.0, 0.0, 30.0, 180.0), (80.0, 0.0, 80.0, 180.0), *UNREACHABLE]
    return compare_sweep(GOLD, points, seed=5)


@pytest.mark.parametrize("material", [LAMBERT, GOLD], ids=["lambert", "ggx_roughconductor"])
def test_rendered_readings_agree_with_the_prediction_away_from_grazing(material: m.Model) -> None:
    # A small ROI (1 % of the sample, 8-16 px) keeps light distance and ROI extent below the noise.
    result = compare_sweep(material, MODERATE, camera=CameraSpec(roi_fraction=0.01), spp=16, seed=1)
    assert len(result.rows) == len(MODERATE)
    for row in result.rows:
        assert row.reachable and row.roi_pixels >= 4
        # The premise: the ROI's extent moves the prediction by less than the reading's stated uncertainty.
        assert abs(row.extended - row.predicted) < row.measured_se, row.detail
        assert abs(row.z) <= result.z_bound, row.detail
        assert abs(row.ratio - 1.0) <= result.z_bound * row.measured_rel_se
        assert row.explanation is Explanation.AGREES
        # The merge's stated error is what the sensor model expects for that bracket.
        assert row.measured_rel_se == pytest.approx(row.expected_rel_noise, rel=0.02)
        assert row.exposures_s[0] > row.exposures_s[-1] and len(row.exposures_s) == 3


def test_finite_light_distance_and_roi_extent_explain_a_specular_peak(default_roi_sweep: ComparisonResult) -> None:
    off_peak, peak = default_roi_sweep.rows[0], default_roi_sweep.rows[1]
    assert abs(off_peak.ratio - 1.0) < abs(peak.ratio - 1.0) / 10
    # At the mirror direction the lobe's peak curves across +-1.4 deg of ROI: the ROI mean reads low.
    assert peak.explanation is Explanation.EXTENT
    assert peak.ratio < 1.0 - 10 * peak.measured_rel_se
    assert abs(peak.z_extended) <= default_roi_sweep.z_bound
    assert peak.off_sample_fraction == 0.0


def test_a_grazing_point_that_differs_says_grazing(default_roi_sweep: ComparisonResult) -> None:
    row = default_roi_sweep.rows[2]
    assert (row.theta_i, row.theta_o) == (80.0, 80.0)
    assert abs(row.z) > default_roi_sweep.z_bound
    assert row.explanation is Explanation.GRAZING
    assert "theta 80 deg > 75 deg" in row.detail
    # The extended prediction, with each pixel's own geometry, accounts for the render.
    assert abs(row.z_extended) <= default_roi_sweep.z_bound


def test_a_sample_edge_inside_the_roi_is_named() -> None:
    # A fixed 48 x 48 px ROI holds the 50 mm sample whole only when it is seen face-on.
    result = compare_sweep(LAMBERT, [(30.0, 0.0, 60.0, 180.0)], camera=CameraSpec(roi=(8, 8, 56, 56)))
    (row,) = result.rows
    assert row.explanation is Explanation.SAMPLE_EDGE
    assert 0.3 < row.off_sample_fraction < 0.7
    assert row.ratio == pytest.approx(1.0 - row.off_sample_fraction, abs=0.02)
    assert abs(row.z_extended) <= result.z_bound


def test_a_spot_beam_edge_inside_the_roi_is_named() -> None:
    geometry = RigGeometry(beam_half_angle_deg=1.0)
    light = LightSpec(kind="spot")
    result = compare_sweep(LAMBERT, [(30.0, 0.0, 30.0, 180.0)], geometry, light, CameraSpec(roi=(16, 16, 48, 48)),
                           spp=16)  # fmt: skip
    (row,) = result.rows
    assert row.explanation is Explanation.BEAM_EDGE
    assert row.off_sample_fraction == 0.0 and row.off_beam_fraction > 0.5
    assert abs(row.z_extended) <= result.z_bound


def test_unreachable_points_are_listed_with_their_reasons(default_roi_sweep: ComparisonResult) -> None:
    rows = [r for r in default_roi_sweep.rows if not r.reachable]
    assert [(r.theta_i, r.theta_o) for r in rows] == [(5.0, 5.0), (89.0, 10.0)]
    assert rows[0].detail.startswith("min_separation:") and rows[1].detail.startswith("max_zenith:")
    assert all(r.explanation is Explanation.UNREACHABLE and math.isnan(r.measured) for r in rows)
    assert default_roi_sweep.counts()["unreachable"] == 2


def test_table_csv_and_plot_hold_every_point(default_roi_sweep: ComparisonResult, tmp_path: Path) -> None:
    result = default_roi_sweep
    table = result.to_table().splitlines()
    for row in result.rows:
        line = next(t for t in table if t.split()[:1] == [str(row.index)])
        assert line.rstrip().endswith(row.explanation.value)
        assert any(t.startswith(f"#{row.index} {row.explanation.value}: ") for t in table)
    with result.to_csv(tmp_path / "cmp.csv").open(newline="") as fh:
        records = list(csv.DictReader(fh))
    assert [int(r["index"]) for r in records] == [r.index for r in result.rows]
    assert [r["explanation"] for r in records] == [r.explanation.value for r in result.rows]
    assert float(records[1]["ratio"]) == pytest.approx(result.rows[1].ratio, rel=1e-12)
    assert records[1]["joints"] == "light=30;camera=-30;tilt=0;roll=0"
    png = plot_comparison(result, tmp_path / "plots" / "cmp.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    image = matplotlib.image.imread(png)
    assert image.shape[0] > 300 and image.shape[1] > 300 and image.std() > 0.01


def test_explain_rules() -> None:
    none = {Explanation.EXTENT: 0.0, Explanation.SAMPLE_EDGE: 0.0, Explanation.BEAM_EDGE: 0.0}
    extent = {**none, Explanation.EXTENT: -10.0}
    edge = {**extent, Explanation.SAMPLE_EDGE: -50.0}
    assert explain(100.0, 102.0, 100.0, none, 1.0, 0.0, grazing=True) is Explanation.AGREES
    assert explain(100.0, 90.0, 90.0, extent, 1.0, 0.1, grazing=False) is Explanation.EXTENT
    assert explain(100.0, 90.0, 90.0, extent, 1.0, 0.1, grazing=True) is Explanation.GRAZING
    assert explain(100.0, 40.0, 40.0, edge, 1.0, 0.1, grazing=True) is Explanation.SAMPLE_EDGE
    # The modelled effects move the prediction by under a sigma: the gap is noise, the render's or the sensor's.
    assert explain(100.0, 105.0, 100.0, none, 1.0, 2.0, grazing=False) is Explanation.RENDER_NOISE
    assert explain(100.0, 105.0, 100.0, none, 1.0, 2.0, grazing=True) is Explanation.GRAZING
    small = {**none, Explanation.EXTENT: 0.5}
    assert explain(100.0, 103.5, 100.5, small, 1.0, 0.1, grazing=False) is Explanation.SENSOR_NOISE
    assert explain(100.0, 103.5, 100.5, small, 1.0, 0.1, grazing=True) is Explanation.SENSOR_NOISE
    assert explain(100.0, 110.0, 100.0, none, 1.0, 2.0, grazing=False) is Explanation.UNEXPLAINED
    assert explain(100.0, 110.0, 100.0, none, 1.0, 2.0, grazing=True) is Explanation.GRAZING


def test_exposure_and_noise_helpers() -> None:
    noise = SensorNoise()
    bracket = metered_bracket(1e5, noise, frames=3, stops=2.0, fraction=0.8)
    assert bracket[0] * 1e5 == pytest.approx(0.8 * noise.saturation_dn())
    assert bracket[1] == pytest.approx(bracket[0] / 4) and bracket[2] == pytest.approx(bracket[0] / 16)
    # A pixel clipped in the long frame is measured by the short one alone.
    t = 0.1
    var = expected_variance(np.array([1e3, 1e6]), [t, t / 10], noise)
    long_and_short = (noise.variance_dn2(1e2, t) + noise.variance_dn2(1e1, t / 10)
                      + noise.variance_dn2(0.0, t) + noise.variance_dn2(0.0, t / 10)) / (1.1 * t) ** 2  # fmt: skip
    assert var[0] == pytest.approx(long_and_short)
    assert var[1] == pytest.approx((noise.variance_dn2(1e4, t / 10) + noise.variance_dn2(0.0, t / 10)) / (t / 10) ** 2)
    x, y = subpixel_lattice(64)
    assert len(set(x)) == len(set(y)) == 64 and 0 < x.min() and y.max() < 1
