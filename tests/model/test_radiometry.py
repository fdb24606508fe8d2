import numpy as np
import pytest

import model as m
from model import radiometry as r
from model.integrate import integrate_hemisphere


def test_small_disk_solid_angle_is_area_over_distance_squared():
    assert r.solid_angle_disk(1e-3, 1.0) == pytest.approx(np.pi * 1e-6, rel=1e-6)
    assert r.solid_angle_disk(1e-9, 1.0) == pytest.approx(np.pi * 1e-18, rel=1e-9)  # no cancellation
    assert r.solid_angle_disk(1e9, 1.0) == pytest.approx(2 * np.pi, rel=1e-6)


def test_rectangle_solid_angle_against_numerical_integration():
    w, h, d = 0.4, 0.2, 0.5
    x = np.linspace(-w / 2, w / 2, 801)
    y = np.linspace(-h / 2, h / 2, 401)
    xx, yy = np.meshgrid(x, y)
    integrand = d / (xx**2 + yy**2 + d**2) ** 1.5
    numeric = np.trapezoid(np.trapezoid(integrand, x, axis=1), y)
    assert r.solid_angle_rectangle(w, h, d) == pytest.approx(numeric, rel=1e-5)


def test_point_light_inverse_square_and_cosine():
    light = m.PointLight(intensity=(2.0, 4.0, 8.0), distance=0.5)
    e = light.irradiance(np.cos(np.radians(60.0)))
    assert np.allclose(e, np.array([2.0, 4.0, 8.0]) * 0.5 / 0.25)
    assert np.all(light.irradiance(-0.2) == 0)
    assert r.irradiance_point(3.0, 2.0, 1.0) == pytest.approx(0.75)


def test_spot_light_profile():
    spot = m.SpotLight(intensity=10.0, distance=1.0, beam_width=np.radians(10), cutoff=np.radians(20))
    i = spot.intensity_at(np.radians([0.0, 10.0, 12.5, 15.0, 20.0, 30.0]))
    assert i[0] == i[1] == 10.0
    assert i[2] == pytest.approx(7.5)  # linear in angle, as Mitsuba 3's spot emitter
    assert i[3] == pytest.approx(5.0)
    assert i[4] == i[5] == 0.0


def test_predicted_radiance_of_lambert_is_rho_over_pi_times_irradiance():
    light = m.PointLight(intensity=100.0, distance=2.0)
    lam = m.Lambert(0.5)
    L = m.predict_radiance_deg(lam, 30.0, 0.0, 45.0, 180.0, light)
    assert float(L) == pytest.approx(0.5 / np.pi * 100.0 * np.cos(np.radians(30.0)) / 4.0)
    per_channel = m.predict_radiance(m.Lambert((0.2, 0.4, 0.6)), [0, 0, 1], [0, 0, 1], light)
    assert per_channel.shape == (3,)


def test_lambertian_exitance_balances_irradiance():
    """Energy balance of the prediction chain: radiant exitance of a Lambertian = rho * E."""
    light = m.PointLight(intensity=1.0, distance=1.0)
    wi = np.array([0.0, 0.0, 1.0])
    est = integrate_hemisphere(
        lambda d: m.predict_radiance(m.Lambert(0.7), wi, d, light) * d[:, 2], n=4096
    )
    assert float(est.value) == pytest.approx(0.7 * light.irradiance(1.0), rel=1e-10)
