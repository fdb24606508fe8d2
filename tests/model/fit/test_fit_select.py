import numpy as np
import pytest

from model import CookTorrance, Lambert
from model.fit.select import default_ladder, select
from model.fit.solve import LAMBERT, FitError, lambert_ggx
from tests.model.fit.test_fit import PLASTIC, noisy, noisy_in_plane


def test_lambertian_data_choose_lambert_and_say_why() -> None:
    samples, _ = noisy(Lambert(rho_d=(0.2, 0.3, 0.4)), n=300, seed=0)
    sel = select(samples)
    assert sel.chosen_name == "lambert"
    assert sel.chosen.noise_reached
    assert "chi2/dof" in sel.reason and "BIC" in sel.reason and "was not needed" in sel.reason
    assert np.allclose(sel.chosen.values, [0.2, 0.3, 0.4], atol=4 * sel.chosen.std_errors.max())


def test_glossy_data_choose_lambert_plus_ggx() -> None:
    samples, _ = noisy(PLASTIC, n=300, seed=1)
    sel = select(samples)
    assert sel.chosen_name == "lambert+ggx_dielectric"
    assert "The simpler lambert was not enough" in sel.reason and "above the noise" in sel.reason
    table = sel.table()
    assert table.count("\n") == len(default_ladder()) and "*lambert+ggx_dielectric" in table


def test_aic_also_works_and_unknown_criteria_are_refused() -> None:
    samples, _ = noisy(PLASTIC, n=200, seed=2)
    assert select(samples, criterion="aic").chosen_name == "lambert+ggx_dielectric"
    with pytest.raises(FitError, match="criterion"):
        select(samples, criterion="dic")


def test_when_no_candidate_reaches_the_noise_the_reason_says_so() -> None:
    samples, _ = noisy(PLASTIC, n=300, seed=3)
    sel = select(samples, [LAMBERT])
    assert not sel.chosen.noise_reached
    assert "No fitted candidate brings the residuals down to the noise" in sel.reason


def test_a_candidate_the_data_cannot_support_is_listed_with_its_error() -> None:
    samples, _ = noisy_in_plane(PLASTIC, n=200, seed=4)
    sel = select(samples)
    assert sel.chosen_name == "lambert+ggx_dielectric"
    assert "not fitted" in sel.table() and "could not be fitted" in sel.reason


def test_no_candidate_fittable_is_an_error() -> None:
    samples, _ = noisy(CookTorrance(), n=2, seed=5)
    with pytest.raises(FitError, match="no candidate could be fitted"):
        select(samples, [lambert_ggx()])
