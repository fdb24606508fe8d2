import math

import numpy as np
import pytest

from acquisition.calibration import CalibrationError, ReferenceCalibration, detector_solid_angle
from acquisition.exposure.plan import plan_exposure
from acquisition.exposure.spec import RoiLevel
from acquisition.noise import SensorNoise
from acquisition.roi import reduce_roi

NOISE = SensorNoise()
ALBEDO_REF = 0.99
ALBEDO_SAMPLE = 0.5
K = 6e4  # counts/s per (1/sr of BRDF x unit irradiance at normal incidence): camera, light and distance


def capture(rate_dn_per_s, rng, shape=(20, 20), target_snr=2000.0):
    """Plan, simulate and merge frames of a uniform ROI; return the ROI reading (counts/s) with its error."""
    plan = plan_exposure(RoiLevel.uniform(rate_dn_per_s, shape[0] * shape[1]), NOISE, target_snr)
    g = NOISE.e_per_dn
    num = np.zeros(shape)
    var = np.zeros(shape)
    for t in plan.exposures_s:
        e = rng.poisson(rate_dn_per_s * t * g, shape) + rng.normal(0, NOISE.read_noise_e, shape)
        s = np.rint(e / g)
        num += s
        var += NOISE.variance_dn2(np.maximum(s, 0), t)
    total_t = sum(plan.exposures_s)
    return reduce_roi(num / total_t, var / total_t**2, (0, 0, shape[1], shape[0]))


def lambertian_rate(albedo, theta_i_deg, theta_o_deg, footprint="roi_in_spot"):
    """Reading of a Lambertian surface in counts/s per ROI pixel, from the physics of the module doc."""
    f = albedo / math.pi
    if footprint == "roi_in_spot":
        return K * f * math.cos(math.radians(theta_i_deg))  # E ~ cos(theta_i); no theta_o dependence
    return K * f * math.cos(math.radians(theta_o_deg))  # all beam power lands; projected spot ~ cos(theta_o)


GEOMETRIES = [(0.0, 30.0), (30.0, 0.0), (45.0, 60.0), (60.0, 10.0), (75.0, 45.0), (80.0, 80.0), (20.0, 84.0)]


@pytest.mark.parametrize("footprint", ["roi_in_spot", "spot_in_roi"])
def test_lambertian_sample_gives_albedo_over_pi_within_uncertainty(footprint):
    rng = np.random.default_rng(0)
    z = []
    for trial in range(160):  # a fresh reference reading each time, so the z-scores are independent
        ref_reading = capture(lambertian_rate(ALBEDO_REF, 0.0, 45.0, footprint), rng)
        cal = ReferenceCalibration.from_roi(ref_reading, ALBEDO_REF, 0.0, 45.0, albedo_std_error=0.005,
                                            footprint=footprint)
        ti, to = GEOMETRIES[trial % len(GEOMETRIES)]
        sample = cal.to_brdf(capture(lambertian_rate(ALBEDO_SAMPLE, ti, to, footprint), rng), ti, to)
        assert abs(float(sample.value) - ALBEDO_SAMPLE / math.pi) < 4 * float(sample.std_error)
        z.append((float(sample.value) - ALBEDO_SAMPLE / math.pi) / float(sample.std_error_readings))
        assert not sample.includes_cosine and sample.geometry.theta_i_deg == ti
        assert sample.metadata["footprint"] == footprint
    # Against the readings' error alone (the albedo is exact in this simulation) the z-scores are N(0, 1).
    assert np.std(z) == pytest.approx(1.0, abs=0.2)
    assert abs(np.mean(z)) < 0.3
    assert float(sample.std_error) > 2 * float(sample.std_error_readings)  # the albedo's 0.5 % dominates


def test_wrong_footprint_mode_is_biased_off_normal():
    rng = np.random.default_rng(1)
    cal = ReferenceCalibration.from_roi(capture(lambertian_rate(ALBEDO_REF, 0.0, 45.0), rng), ALBEDO_REF, 0.0, 45.0,
                                        footprint="spot_in_roi")
    sample = cal.to_brdf(capture(lambertian_rate(ALBEDO_SAMPLE, 60.0, 45.0), rng), 60.0, 45.0)
    assert float(sample.value) == pytest.approx(0.5 * ALBEDO_SAMPLE / math.pi, rel=0.01)  # cos 60 not undone


def test_exact_formula_cosine_and_light_distance():
    cal = ReferenceCalibration(reading=(800.0, 900.0, 1000.0), reading_std_error=0.0, albedo=(0.98, 0.99, 0.99),
                               albedo_std_error=0.0, theta_i_deg=0.0, theta_o_deg=45.0, light_distance_m=1.0,
                               detector_solid_angle_sr=detector_solid_angle(0.01, 0.5))
    s = cal.to_brdf([400.0, 450.0, 500.0], 60.0, 20.0, std_error=[4.0, 4.5, 5.0])
    expected = 0.5 * np.array([0.98, 0.99, 0.99]) / math.pi / 0.5
    np.testing.assert_allclose(s.value, expected)
    np.testing.assert_allclose(s.std_error, expected * 0.01)
    c = cal.to_brdf([400.0, 450.0, 500.0], 60.0, 20.0, include_cosine=True)
    assert c.includes_cosine
    np.testing.assert_allclose(c.value, expected * 0.5)
    far = cal.to_brdf([100.0, 112.5, 125.0], 60.0, 20.0, light_distance_m=2.0)  # inverse square undone
    np.testing.assert_allclose(far.value, expected)
    assert s.detector_solid_angle_sr == pytest.approx(math.pi * 0.005**2 / 0.25, rel=1e-3)
    zero = cal.to_brdf([0.0, 0.0, 0.0], 10.0, 10.0, std_error=[1.0, 1.0, 1.0])
    assert np.all(zero.value == 0) and np.all(zero.std_error > 0)


def test_uncertainty_propagation_against_monte_carlo():
    rng = np.random.default_rng(4)
    n = 40_000
    r_ref, se_ref, r, se, rho, se_rho = 1000.0, 20.0, 400.0, 10.0, 0.8, 0.016
    nominal = ReferenceCalibration(r_ref, se_ref, rho, se_rho, 10.0, 45.0).to_brdf(r, 40.0, 20.0, std_error=se)
    # One "channel" per Monte Carlo draw: the calibration is vectorised over channels.
    draws = ReferenceCalibration(rng.normal(r_ref, se_ref, n), 0.0, rng.normal(rho, se_rho, n), 0.0, 10.0, 45.0)
    values = draws.to_brdf(rng.normal(r, se, n), 40.0, 20.0).value
    assert values.mean() == pytest.approx(float(nominal.value), rel=2e-3)
    assert values.std(ddof=1) == pytest.approx(float(nominal.std_error), rel=0.03)
    rel = math.sqrt((se_ref / r_ref) ** 2 + (se / r) ** 2 + (se_rho / rho) ** 2)
    assert float(nominal.std_error) == pytest.approx(float(nominal.value) * rel)
    assert float(nominal.std_error_readings) == pytest.approx(
        float(nominal.value) * math.sqrt((se_ref / r_ref) ** 2 + (se / r) ** 2)
    )


def test_drift_is_interpolated_between_two_reference_readings():
    # The light dims linearly by 10 % over the run; the sample is read a quarter of the way through.
    cal = ReferenceCalibration(1000.0, 10.0, 0.99, 0.0, 0.0, 45.0, time_s=0.0)
    cal = cal.with_closing_reading(900.0, 10.0, time_s=100.0)
    light = 1.0 - 0.1 * 25.0 / 100.0
    reading = light * 1000.0 * (0.5 / 0.99)
    s = cal.to_brdf(reading, 0.0, 30.0, time_s=25.0)
    assert float(s.value) == pytest.approx(0.5 / math.pi)
    assert s.metadata["drift_corrected"] is True
    _, se = cal.reference_at(25.0)
    assert float(se) == pytest.approx(math.hypot(0.75 * 10.0, 0.25 * 10.0))
    uncorrected = cal.to_brdf(reading, 0.0, 30.0)
    assert float(uncorrected.value) == pytest.approx(light * 0.5 / math.pi)
    with pytest.raises(CalibrationError, match=r"time_s = 150.0 is outside .* \[0, 100\] s"):
        cal.to_brdf(reading, 0.0, 30.0, time_s=150.0)
    with pytest.raises(CalibrationError, match="closing_time_s"):
        ReferenceCalibration(1000.0, 10.0, 0.99, 0.0, 0.0, 45.0).with_closing_reading(900.0, time_s=10.0)


def test_grazing_geometry_is_refused_naming_the_angle():
    cal = ReferenceCalibration(1000.0, 10.0, 0.99, 0.0, 0.0, 45.0, max_theta_deg=80.0)
    with pytest.raises(CalibrationError, match=r"theta_i_deg = 86 deg is beyond max_theta_deg = 80 deg"):
        cal.to_brdf(10.0, 86.0, 10.0)
    with pytest.raises(CalibrationError, match=r"theta_o_deg = 81 deg is beyond max_theta_deg = 80"):
        cal.to_brdf(10.0, 10.0, 81.0)
    with pytest.raises(CalibrationError, match=r"theta_i_deg = 90.0 deg: expected a polar angle in \[0, 90\)"):
        cal.to_brdf(10.0, 90.0, 10.0)
    with pytest.raises(CalibrationError, match=r"theta_o_deg = -5.0"):
        cal.to_brdf(10.0, 10.0, -5.0)
    with pytest.raises(CalibrationError, match=r"ReferenceCalibration: theta_i_deg = 88"):
        ReferenceCalibration(1000.0, 10.0, 0.99, 0.0, 88.0, 45.0)


def test_bad_inputs_name_the_field():
    with pytest.raises(CalibrationError, match=r"reading = 0.0 counts/s: the reference must read > 0"):
        ReferenceCalibration(0.0, 1.0, 0.99, 0.0, 0.0, 45.0)
    with pytest.raises(CalibrationError, match=r"ReferenceCalibration.reading = \(5.0, -1.0\)"):
        ReferenceCalibration((5.0, -1.0), 1.0, 0.99, 0.0, 0.0, 45.0)
    with pytest.raises(CalibrationError, match=r"albedo = 1.2: expected a reflectance in \(0, 1\]"):
        ReferenceCalibration(5.0, 1.0, 1.2, 0.0, 0.0, 45.0)
    with pytest.raises(CalibrationError, match="albedo has 2 channels but reading has 3 channels"):
        ReferenceCalibration((5.0, 5.0, 5.0), 1.0, (0.9, 0.9), 0.0, 0.0, 45.0)
    with pytest.raises(CalibrationError, match="reading_std_error"):
        ReferenceCalibration(5.0, -1.0, 0.9, 0.0, 0.0, 45.0)
    cal = ReferenceCalibration((5.0, 5.0, 5.0), 0.1, 0.99, 0.0, 0.0, 45.0)
    with pytest.raises(CalibrationError, match="the reading has 4 channels but the reference reading has 3 channels"):
        cal.to_brdf([1.0, 1.0, 1.0, 1.0], 10.0, 10.0)
    with pytest.raises(CalibrationError, match="the reading has 1 value but the reference reading has 3 channels"):
        cal.to_brdf(1.0, 10.0, 10.0)
    with pytest.raises(CalibrationError, match="light distance"):
        cal.to_brdf([1.0, 1.0, 1.0], 10.0, 10.0, light_distance_m=1.0)
    with pytest.raises(CalibrationError, match="footprint"):
        ReferenceCalibration(5.0, 1.0, 0.9, 0.0, 0.0, 45.0, footprint="overfilled")


def test_lower_bound_readings_and_roi_size_in_spot_mode():
    rad = np.full((4, 4), 100.0)
    flags = np.zeros((4, 4), dtype=bool)
    flags[0, 0] = True
    lower = reduce_roi(rad, np.ones((4, 4)), (0, 0, 4, 4), flags, on_flagged="lower_bound")
    with pytest.raises(CalibrationError, match="lower bound"):
        ReferenceCalibration.from_roi(lower, 0.99, 0.0, 45.0)
    ok = reduce_roi(rad, np.ones((4, 4)), (0, 0, 4, 4))
    cal = ReferenceCalibration.from_roi(ok, 0.99, 0.0, 45.0, footprint="spot_in_roi")
    assert cal.to_brdf(lower, 10.0, 10.0).lower_bound
    small = reduce_roi(rad, np.ones((4, 4)), (0, 0, 2, 2))
    with pytest.raises(CalibrationError, match="4 pixels and the reference 16"):
        cal.to_brdf(small, 10.0, 10.0)
