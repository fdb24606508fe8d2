"""model.fit.metal_roughness: the projection onto glTF metal-roughness recovers what it can represent and
reports, honestly, how far it is from what it cannot.

Honesty is checked against an independent estimate: the same error integral by Gauss-Legendre quadrature
over both hemispheres (isotropic sources, so phi_i = 0 suffices), not by the module's importance sampling.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from model import CookTorrance, Lambert, MerlTable, MetalRoughness
from model.base import BRDF
from model.fit.metal_roughness import GRAZING_DEG, MetalRoughnessFit, gltf_material, sample_pairs, to_metal_roughness
from model.fresnel import f0_from_ior
from model.integrate import hemisphere_quadrature
from model.merl import SHAPE
from model.serialize import to_json_dict

GOLD = CookTorrance(alpha=0.3, eta=(0.18, 0.42, 1.37), k=(3.42, 2.35, 1.77))
LAMBERT = Lambert(rho_d=(0.8, 0.5, 0.2))


def quadrature_error(source: BRDF, material: BRDF, n: int = 48) -> float:
    """E = ||(f_mr - f) cos_i cos_o|| / ||f cos_i cos_o|| over both hemispheres, by product quadrature."""
    x, w = np.polynomial.legendre.leggauss(n)
    mu, w_mu = 0.5 * (x + 1.0), 0.5 * w
    wi = np.stack([np.sqrt(1.0 - mu**2), np.zeros(n), mu], axis=-1)
    wo, w_o = hemisphere_quadrature(n, 2 * n)
    a, b = np.repeat(wi, len(wo), axis=0), np.tile(wo, (n, 1))
    weight = (np.repeat(w_mu, len(wo)) * np.tile(w_o, n) * (a[:, 2] * b[:, 2]) ** 2)[:, None]
    f = np.asarray(source.eval(a, b)).reshape(len(a), -1)
    g = np.broadcast_to(np.asarray(material.eval(a, b)).reshape(len(a), -1), f.shape)
    return float(np.sqrt(np.sum(weight * (g - f) ** 2) / np.sum(weight * f**2)))


@pytest.fixture(scope="module")
def gold() -> MetalRoughnessFit:
    return to_metal_roughness(GOLD)


@pytest.fixture(scope="module")
def lambert() -> MetalRoughnessFit:
    return to_metal_roughness(LAMBERT)


@pytest.mark.parametrize(
    "source",
    [
        MetalRoughness(base_color=(0.8, 0.5, 0.2), metallic=0.3, roughness=0.6),
        MetalRoughness(base_color=(0.95, 0.64, 0.54), metallic=1.0, roughness=0.25),
        MetalRoughness(base_color=(0.1, 0.6, 0.3), metallic=0.0, roughness=0.9),
    ],
)
def test_a_metal_roughness_source_is_recovered(source: MetalRoughness) -> None:
    r = to_metal_roughness(source)
    np.testing.assert_allclose(r.material.base_color, source.base_color, atol=1e-3)
    assert abs(r.material.metallic - source.metallic) < 1e-3
    assert abs(r.material.roughness - source.roughness) < 1e-3
    assert r.rms_rel < 1e-3 and r.worst_rel < 1e-3


def test_gold_projects_to_a_metal_with_the_same_roughness(gold: MetalRoughnessFit) -> None:
    m = gold.material
    assert m.metallic > 0.95
    assert abs(m.roughness - np.sqrt(0.3)) < 0.01  # glTF alpha = roughness^2
    # Schlick's F0 is the conductor's normal-incidence reflectance, up to what the fit trades at grazing.
    np.testing.assert_allclose(m.base_color, f0_from_ior(GOLD.eta, GOLD.k), atol=0.02)
    # Schlick against exact Fresnel and height-correlated against separable Smith: small, not zero.
    assert 1e-3 < gold.rms_rel < 0.05
    assert 0.0 < gold.worst_rel < 0.5
    assert len(gold.rms_rel_per_channel) == 3 and max(gold.rms_rel_per_channel) < 0.05


def test_lambert_projects_to_a_dielectric_and_reports_what_fresnel_mix_costs(lambert: MetalRoughnessFit) -> None:
    m = lambert.material
    assert m.metallic < 0.05
    # glTF adds an F(0.04) specular lobe and dims the diffuse by (1 - F): the projection cannot be exact.
    assert lambert.rms_rel > 1e-3
    assert lambert.worst_rel > 0.05
    # The diffuse colour survives with the channels in order.
    rgb = np.asarray(m.base_color)
    assert rgb[0] > rgb[1] > rgb[2]
    np.testing.assert_allclose(rgb, LAMBERT.rho_d, atol=0.05)


@pytest.mark.parametrize("name", ["gold", "lambert"])
def test_reported_error_agrees_with_quadrature(name: str, request: pytest.FixtureRequest) -> None:
    r: MetalRoughnessFit = request.getfixturevalue(name)
    reference = quadrature_error(r.source, r.material)
    assert r.rms_rel == pytest.approx(reference, rel=0.05)  # measured within 3.5 % (gold) and 0.6 % (Lambert)


def test_worst_difference_is_away_from_grazing(gold: MetalRoughnessFit) -> None:
    theta_i, theta_o, dphi = gold.worst_at_deg
    assert 0.0 <= theta_i <= GRAZING_DEG and 0.0 <= theta_o <= GRAZING_DEG and 0.0 <= dphi <= 180.0
    wi = np.array([np.sin(np.radians(theta_i)), 0.0, np.cos(np.radians(theta_i))])
    wo = np.array(
        [
            np.sin(np.radians(theta_o)) * np.cos(np.radians(dphi)),
            np.sin(np.radians(theta_o)) * np.sin(np.radians(dphi)),
            np.cos(np.radians(theta_o)),
        ]
    )
    f, g = GOLD.eval(wi, wo), gold.material.eval(wi, wo)
    assert np.max(np.abs(g - f) / f) == pytest.approx(gold.worst_rel, rel=1e-6)


def test_importance_weights_estimate_the_cosine_weighted_measure() -> None:
    # The weights turn any sample into an estimate of int int cos_i^2 cos_o^2 dw_i dw_o = (2 pi / 3)^2.
    wi, wo, w = sample_pairs(200_000, np.random.default_rng(5))
    assert np.all(wi[:, 2] > 0) and np.all(wo[:, 2] > 0) and len(wi) > 190_000
    estimate = w.sum() / 200_000
    assert estimate == pytest.approx((2.0 * np.pi / 3.0) ** 2, rel=0.01)


def test_seeded_and_deterministic() -> None:
    a, b = to_metal_roughness(LAMBERT, seed=3), to_metal_roughness(LAMBERT, seed=3)
    assert a.material == b.material and a.rms_rel == b.rms_rel
    c = to_metal_roughness(LAMBERT, seed=4)
    assert c.rms_rel != a.rms_rel and c.rms_rel == pytest.approx(a.rms_rel, rel=0.05)


def test_gltf_material_object(gold: MetalRoughnessFit) -> None:
    doc = json.loads(json.dumps(gltf_material(gold, "gold")))
    assert doc["name"] == "gold"
    pbr = doc["pbrMetallicRoughness"]
    assert pbr["baseColorFactor"][3] == 1.0 and len(pbr["baseColorFactor"]) == 4
    np.testing.assert_allclose(pbr["baseColorFactor"][:3], gold.material.base_color)
    assert pbr["metallicFactor"] == gold.material.metallic and pbr["roughnessFactor"] == gold.material.roughness
    assert doc["extras"]["source_model"] == to_json_dict(GOLD)
    err = doc["extras"]["projection_error"]
    assert err["rms_rel"] == gold.rms_rel and err["worst_rel"] == gold.worst_rel
    assert err["grazing_limit_deg"] == GRAZING_DEG


def test_grey_source_gives_a_grey_rgb_factor() -> None:
    r = to_metal_roughness(Lambert(rho_d=0.5), samples=1000)
    factor = gltf_material(r, "grey")["pbrMetallicRoughness"]["baseColorFactor"]
    assert factor[0] == factor[1] == factor[2] and 0.4 < factor[0] < 0.6
    assert len(r.rms_rel_per_channel) == 1


def test_a_merl_table_projects_where_it_has_data() -> None:
    th = ((np.arange(SHAPE[0]) + 0.5) / SHAPE[0]) ** 2 * (np.pi / 2)
    lobe = 0.05 + 3.0 * np.exp(-((th / 0.2) ** 2))
    values = np.broadcast_to(lobe[None, :, None, None] * np.array([1.0, 0.7, 0.4])[:, None, None, None], (3, *SHAPE))
    values = values.copy()
    values[:, :, 80:, :] = np.nan  # theta_d beyond 80 deg: no data, must not count as zeros
    r = to_metal_roughness(MerlTable(values, source="synthetic"), samples=1000)
    assert np.isfinite(r.rms_rel) and r.rms_rel < 1.0
    assert r.n_error < 50_000
    extras = gltf_material(r, "merl")["extras"]
    assert extras["source_model"] == {"model": "MerlTable", "source": "synthetic"}


def test_bad_sources_are_refused() -> None:
    with pytest.raises(ValueError, match="zero at every sampled pair"):
        to_metal_roughness(Lambert(rho_d=0.0), samples=200)
    with pytest.raises(ValueError, match="2 channels"):
        to_metal_roughness(Lambert(rho_d=(0.2, 0.3)), samples=200)
    with pytest.raises(ValueError, match="samples = 10"):
        to_metal_roughness(LAMBERT, samples=10)
