import numpy as np
import pytest

import model as m
from model.checks import check_energy, check_reciprocity, check_sanity
from model.geometry import degrees_to_vector
from model.integrate import directional_albedo, hemisphere_quadrature


def test_quadrature_weights_cover_the_hemisphere():
    dirs, w = hemisphere_quadrature(16, 32)
    assert dirs.shape == (512, 3) and w.sum() == pytest.approx(2 * np.pi)
    assert np.allclose(np.linalg.norm(dirs, axis=-1), 1.0)


@pytest.mark.parametrize(
    "model",
    [m.CookTorrance(alpha=0.2, rho_d=0.3, eta=1.5), m.Ward(0.2, 0.3, 0.2, variant="balanced"), m.OrenNayar(0.7, 0.4)],
)
@pytest.mark.parametrize("theta", [0.0, 50.0, 80.0])
def test_monte_carlo_agrees_with_quadrature_within_its_error(model, theta):
    wi = degrees_to_vector(theta, 10.0)
    ref = directional_albedo(model, wi, n=1_000_000)
    mc = directional_albedo(model, wi, n=50_000, method="mc", rng=7)
    assert float(mc.stderr) > 0
    assert abs(float(mc.value) - float(ref.value)) < 4.5 * float(mc.stderr) + 1e-4


@pytest.mark.parametrize("theta", [0.0, 30.0, 60.0])
def test_importance_sampling_resolves_a_near_mirror(theta):
    """alpha = 0.01 with F = 1 reflects all but the masked share; MC with the lobe proposal is exact."""
    mirror = m.CookTorrance(alpha=0.01, fresnel="schlick", f0=1.0)
    mc = directional_albedo(mirror, degrees_to_vector(theta, 0.0), n=20_000, method="mc", rng=1)
    assert float(mc.stderr) < 0.003
    assert float(mc.value) == pytest.approx(1.0, abs=0.01)


def test_unknown_method():
    with pytest.raises(ValueError, match="'quadrature' or 'mc'"):
        directional_albedo(m.Lambert(), [0, 0, 1], method="simpson")


def test_checks_report_where_a_bad_model_fails():
    class Broken(m.Lambert):
        def _eval(self, p):
            f = super()._eval(p).copy()
            return np.where(p.cos_i > 0.99, np.nan, np.where(p.cos_o < 0.1, -1.0, f * (1 + p.wi[..., :1])))

    broken = Broken(0.5)
    sanity = check_sanity(broken)
    assert not sanity.passed and sanity.n_nonfinite > 0 and sanity.n_negative > 0
    recip = check_reciprocity(m.KajiyaKay())
    assert not recip.passed
    assert recip.worst_wi.shape == (3,)
    energy = check_energy(m.Lambert(0.9), n=4096)
    assert energy.passed and energy.max_albedo == pytest.approx(0.9)


def test_energy_check_is_not_fooled_by_a_narrow_grazing_lobe():
    """Plain quadrature over-counts this lobe tenfold; the automatic choice samples the lobe."""
    furnace = m.CookTorrance(alpha=0.05, fresnel="schlick", f0=1.0)
    grazing = [np.radians(85.0)]
    assert check_energy(furnace, theta_i=grazing, n=256, method="quadrature").max_albedo > 2.0
    report = check_energy(furnace, theta_i=grazing, n=65_536)
    assert report.passed
    assert report.max_albedo == pytest.approx(0.899034465, abs=4 * report.stderr[0] + 1e-4)
