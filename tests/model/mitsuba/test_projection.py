"""model.mitsuba.projection: the error grid, Mitsuba's values on it, and the warm start of the projection fit."""

from __future__ import annotations

import numpy as np
import pytest

from model import CookTorrance, Lambert, Phong
from model.fit.spec import LAMBERT, ggx_conductor
from model.mitsuba.materials import to_mitsuba
from model.mitsuba.projection import (
    GRID_DPHI_DEG,
    GRID_PHI_I_DEG,
    GRID_THETA_DEG,
    grid_error,
    grid_pairs,
    rounded_error,
    warm_start,
)
from tests.mitsuba_helpers import require_variant

pytestmark = pytest.mark.mitsuba


def test_the_grid_covers_both_hemispheres_to_80_degrees_and_every_azimuth_slice() -> None:
    wi, wo = grid_pairs()
    n = len(GRID_THETA_DEG) ** 2 * len(GRID_DPHI_DEG)
    assert wi.shape == wo.shape == (n * len(GRID_PHI_I_DEG), 3)
    np.testing.assert_allclose(np.linalg.norm(wi, axis=1), 1.0, atol=1e-6)
    theta = np.degrees(np.arccos(np.clip(np.concatenate([wi[:, 2], wo[:, 2]]), -1, 1)))
    assert theta.min() < 1e-3 and theta.max() == pytest.approx(80.0, abs=1e-3)
    # Each phi_i slice is the first turned about the normal: an isotropic BSDF has the same values on all.
    iso = CookTorrance(alpha=0.3, eta=(0.2, 0.4, 1.4), k=(3.4, 2.4, 1.8))
    f = iso.eval(wi, wo).reshape(len(GRID_PHI_I_DEG), n, -1)
    np.testing.assert_allclose(f[1:], np.broadcast_to(f[0], f[1:].shape), rtol=1e-5)


@pytest.mark.parametrize("variant", ["scalar_rgb"])
def test_a_native_mapping_measures_as_float32_rounding(variant: str) -> None:
    require_variant(variant)
    m = Lambert(rho_d=(0.8, 0.5, 0.2))
    e = grid_error(m, to_mitsuba(m).bsdf, variant)
    assert e["rms_rel"] < 1e-6 and e["pairs"] == len(grid_pairs()[0]) and variant in e["evaluated_by"]
    far = grid_error(m, {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.4, 0.25, 0.1]}}, variant)
    assert far["rms_rel"] == pytest.approx(0.5, rel=1e-5)  # half the albedo: half the BRDF everywhere


def test_a_rounded_error_keeps_four_significant_digits_of_each_metric_and_the_rest_as_it_is() -> None:
    # Two processes' readings of one table by Mitsuba's measured plugin (the README run's): one number once rounded.
    error = {"rms_rel": 0.01560573123485755, "rms_rel_per_channel": [0.0123456789, 1.23456789],
             "rms_rel_cosine_weighted": 0.00987654, "worst_rel": 12.3456, "pairs": 17, "worst_at_deg": {"theta_i": 5.0}}
    again = dict(error, rms_rel=0.015605731215887883)
    r = rounded_error(error)
    assert r == rounded_error(again) and list(r) == list(error)
    assert r == {**error, "rms_rel": 0.01561, "rms_rel_per_channel": [0.01235, 1.235],
                 "rms_rel_cosine_weighted": 0.009877, "worst_rel": 12.35}  # fmt: skip


def test_the_warm_start_is_the_source_itself_for_cook_torrance_only() -> None:
    spec = ggx_conductor(rho_d=True)
    src = CookTorrance(alpha=0.2, fresnel="schlick", f0=(0.04, 0.05, 0.06), rho_d=(0.5, 0.4, 0.2))
    warm = warm_start(spec, src)
    assert warm is not None and [p.name for p in warm.params] == [p.name for p in spec.params]
    init = {p.name: p.init(None) if callable(p.init) else p.init for p in warm.params}  # type: ignore[arg-type]
    eta = np.asarray(init["eta"])
    np.testing.assert_allclose(((eta - 1) / (eta + 1)) ** 2, src.f0, rtol=1e-12)  # the dielectric with that F0
    assert init["alpha"] == 0.2 and np.all(np.asarray(init["k"]) == 0.0)
    np.testing.assert_allclose(init["rho_d"], src.rho_d)
    assert warm_start(spec, Phong()) is None and warm_start(LAMBERT, src) is None
