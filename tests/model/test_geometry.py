import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from model import geometry as g

angles = st.tuples(st.floats(0.0, np.pi / 2), st.floats(-np.pi + 1e-9, np.pi))


@given(angles)
def test_spherical_round_trip(ang):
    theta, phi = ang
    v = g.spherical_to_vector(theta, phi)
    assert np.linalg.norm(v) == pytest.approx(1.0, abs=1e-15)
    t2, p2 = g.vector_to_spherical(v)
    assert t2 == pytest.approx(theta, abs=1e-12)
    if 1e-9 < theta:
        assert np.angle(np.exp(1j * (p2 - phi))) == pytest.approx(0.0, abs=1e-9)


def test_degrees_boundary_matches_radians():
    assert np.allclose(g.degrees_to_vector(30.0, 90.0), g.spherical_to_vector(np.pi / 6, np.pi / 2))


@settings(max_examples=200)
@given(angles, angles)
def test_half_diff_round_trip(a, b):
    wi = g.spherical_to_vector(*a)
    wo = g.spherical_to_vector(*b)
    th, ph, td, pd = g.to_half_diff(wi, wo)
    wi2, wo2 = g.from_half_diff(th, ph, td, pd)
    assert np.allclose(wi2, wi, atol=1e-9)
    assert np.allclose(wo2, wo, atol=1e-9)


def test_half_diff_of_mirror_pair_is_normal_half_vector():
    wi = g.spherical_to_vector(0.7, 0.3)
    th, _, td, _ = g.to_half_diff(wi, g.reflect(wi))
    assert th == pytest.approx(0.0, abs=1e-12)
    assert td == pytest.approx(0.7, abs=1e-12)


def test_reflect_keeps_zenith_and_flips_azimuth():
    v = g.spherical_to_vector(0.4, 1.0)
    r = g.reflect(v)
    assert np.allclose(r, [-v[0], -v[1], v[2]])


def test_refract_obeys_snell_and_reports_tir():
    theta = np.radians(40.0)
    v = g.spherical_to_vector(theta, 0.0)
    t, tir = g.refract(v, 1.5)
    assert not tir
    theta_t = np.arccos(-t[2])
    assert np.sin(theta) == pytest.approx(1.5 * np.sin(theta_t), rel=1e-12)
    # Leaving glass (eta = 1/1.5) beyond the critical angle of 41.8 degrees.
    crit = g.critical_angle(1 / 1.5)
    assert np.degrees(crit) == pytest.approx(41.81, abs=0.01)
    t2, tir2 = g.refract(g.spherical_to_vector(crit + 0.01, 0.0), 1 / 1.5)
    assert tir2
    assert np.all(np.isfinite(t2))
    assert g.critical_angle(1.5) == pytest.approx(np.pi / 2)


def test_frame_is_orthonormal_even_near_minus_z():
    normals = np.array([[0, 0, 1], [0, 0, -1], [1e-9, 0, -1], [0.3, -0.5, 0.8], [1, 0, 0]], dtype=float)
    s, t, n = g.build_frame(normals)
    for a, b in ((s, t), (s, n), (t, n)):
        assert np.allclose(np.sum(a * b, axis=-1), 0.0, atol=1e-12)
    for a in (s, t, n):
        assert np.allclose(np.linalg.norm(a, axis=-1), 1.0)
    local = g.to_local(g.normalize(normals), normals)
    assert np.allclose(local, [0, 0, 1], atol=1e-12)


def test_normalize_zero_stays_zero_and_float32_is_kept():
    v = g.normalize(np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0]], dtype=np.float32))
    assert v.dtype == np.float32
    assert np.all(v[0] == 0)
    assert np.allclose(v[1], [0.6, 0.8, 0.0])
