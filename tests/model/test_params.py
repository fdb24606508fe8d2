"""Invalid parameters raise one clear error naming the parameter, its value and its range."""

import numpy as np
import pytest

import model as m
from model import ParameterError


@pytest.mark.parametrize(
    "build,fragment",
    [
        (lambda: m.Lambert(1.2), "Lambert.rho_d = 1.2 is outside its valid range [0, 1]"),
        (lambda: m.Lambert(-0.1), "Lambert.rho_d"),
        (lambda: m.Lambert(np.nan), "Lambert.rho_d"),
        (lambda: m.Lambert([[0.1]]), "1-D sequence"),
        (lambda: m.CookTorrance(alpha=0.0), "CookTorrance.alpha = 0.0 is outside its valid range (0, 10]"),
        (lambda: m.CookTorrance(alpha=-1), "CookTorrance.alpha"),
        (lambda: m.CookTorrance(alpha=(0.1, 0.2)), "expected a single number"),
        (lambda: m.CookTorrance(distribution="gauss"), "'ggx', 'beckmann', 'blinn_phong'"),
        (lambda: m.CookTorrance(alpha=1.5, distribution="blinn_phong"), "outside (0, 1] for distribution"),
        (lambda: m.CookTorrance(masking="smyth"), "CookTorrance.masking = 'smyth'"),
        (lambda: m.CookTorrance(eta=0.0), "CookTorrance.eta"),
        (lambda: m.CookTorrance(k=-1.0), "CookTorrance.k"),
        (lambda: m.CookTorrance(eta=(1, 2, 3), k=(1, 2)), "disagree on the number of channels"),
        (lambda: m.Phong(0.6, 0.6, 10), "rho_d + rho_s"),
        (lambda: m.Phong(0.1, 0.1, -1), "Phong.n"),
        (lambda: m.Ward(alpha_x=0.0), "Ward.alpha_x"),
        (lambda: m.Ward(variant="wardd"), "Ward.variant"),
        (lambda: m.OrenNayar(sigma=2.0), "OrenNayar.sigma = 2.0 is outside its valid range [0, 1.5708]"),
        (lambda: m.Lafortune(lobes=()), "Lafortune.lobes"),
        (lambda: m.LafortuneLobe(5.0, 5.0, 5.0, 100.0), "exceeds 1e30"),
        (lambda: m.MetalRoughness(roughness=0.0), "MetalRoughness.roughness"),
        (lambda: m.PointLight(distance=0.0), "PointLight.distance"),
        (lambda: m.SpotLight(beam_width=0.5, cutoff=0.3), "SpotLight.beam_width"),
    ],
)
def test_invalid_parameters_are_named(build, fragment):
    with pytest.raises(ParameterError) as err:
        build()
    assert fragment in str(err.value)


def test_parameter_error_is_a_value_error():
    assert issubclass(ParameterError, ValueError)


def test_per_channel_count_mismatch_is_caught_at_construction():
    with pytest.raises(ParameterError):
        m.Lafortune((0.1, 0.2), (m.LafortuneLobe(c_x=(1.0, 1.0, 1.0)),)).channels  # noqa: B018


def test_models_are_hashable_and_comparable():
    a = m.CookTorrance(alpha=0.2, eta=[0.2, 0.9, 1.1], k=[3.9, 2.4, 2.2])
    b = m.CookTorrance(alpha=0.2, eta=(0.2, 0.9, 1.1), k=(3.9, 2.4, 2.2))
    assert a == b and hash(a) == hash(b)
    assert a.with_params(alpha=0.3) != a


def test_bad_direction_shapes():
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3\)"):
        m.Lambert().eval(np.zeros((4, 2)), np.zeros((4, 2)))
