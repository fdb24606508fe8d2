"""model.serialize: every analytic model survives JSON (through the text, not just the dict), and bad input
gets an error that names the source, the key and what was expected."""

from __future__ import annotations

import inspect
import json
from typing import Any

import numpy as np
import pytest

import model as model_pkg
from model import BlinnPhong, CookTorrance, KajiyaKay, Lambert, MerlTable, MetalnessMix, Model, Phong, Ward
from model.checks import random_hemisphere
from model.merl import SHAPE
from model.serialize import MODELS, ModelFormatError, from_json_dict, is_serialisable, to_json_dict
from tests.model import model_instances as shared

NON_DEFAULT: list[Model] = [
    shared.ASHIKHMIN_SHIRLEY,
    BlinnPhong(rho_d=0.2, rho_s=(0.5, 0.5, 0.4), n=80.0, normalization="approx"),
    CookTorrance(alpha=0.3, eta=(0.18, 0.42, 1.37), k=(3.42, 2.35, 1.77)),
    CookTorrance(
        alpha=0.2,
        distribution="beckmann",
        masking="smith_correlated",
        fresnel="dielectric",
        eta=1.45,
        rho_d=(0.5, 0.4, 0.2),
        form="cook_torrance_1982",
    ),
    shared.CT_SCHLICK,
    shared.KAJIYA_KAY,
    shared.LAFORTUNE,
    shared.LAMBERT,
    shared.METAL,
    MetalnessMix(base_color=(0.8, 0.5, 0.2), roughness=0.5, metalness=0.3, f0_dielectric=0.05),
    shared.OREN_NAYAR,
    shared.PHONG,
    shared.WARD,
    Lambert(rho_d=(1.0 / 3.0,)),  # a one-element channel list stays a tuple, and 1/3 survives exactly
]


def exported_model_classes() -> set[type]:
    return {
        obj
        for name in model_pkg.__all__
        if inspect.isclass(obj := getattr(model_pkg, name)) and issubclass(obj, Model) and not inspect.isabstract(obj)
    }


def through_text(m: Model) -> Model:
    return from_json_dict(json.loads(json.dumps(to_json_dict(m))), source="test.json")


def test_every_exported_model_class_is_registered() -> None:
    classes = exported_model_classes()
    assert classes == set(MODELS.values()), sorted(c.__name__ for c in classes ^ set(MODELS.values()))
    assert len(classes) >= 11


@pytest.mark.parametrize("name", sorted(MODELS))
def test_defaults_round_trip(name: str) -> None:
    cls = MODELS[name]
    m = cls()
    d = to_json_dict(m)
    assert d["model"] == cls.__name__ and set(d) == {"model", "params"}
    back = through_text(m)
    assert type(back) is cls and back == m
    # A minimal document (no params at all) means the defaults, as the constructor does.
    assert from_json_dict({"model": cls.__name__, "params": {}}) == m


@pytest.mark.parametrize("m", NON_DEFAULT, ids=lambda m: type(m).__name__)
def test_non_default_values_round_trip_and_evaluate_identically(m: Model) -> None:
    back = through_text(m)
    assert back == m and back != type(m)()
    rng = np.random.default_rng(3)
    wi, wo = random_hemisphere(64, rng), random_hemisphere(64, rng)
    np.testing.assert_array_equal(back.eval(wi, wo), m.eval(wi, wo))


def test_json_values_are_plain() -> None:
    d = to_json_dict(shared.LAFORTUNE)
    assert d["params"]["rho_d"] == [0.2, 0.1, 0.05]
    assert d["params"]["lobes"][1] == {"c_x": 0.5, "c_y": 0.5, "c_z": 0.6, "n": 5.0}
    assert json.loads(json.dumps(d)) == d
    # Integers are numbers too (hand-written files).
    assert from_json_dict({"model": "Phong", "params": {"n": 7, "rho_s": 0}}) == Phong(n=7.0, rho_s=0.0)


def test_ward_none_is_accepted_and_normalised() -> None:
    m = from_json_dict({"model": "Ward", "params": {"alpha_x": 0.2, "alpha_y": None}})
    assert m == Ward(alpha_x=0.2, alpha_y=0.2)


def test_merl_table_is_refused_both_ways() -> None:
    table = MerlTable(np.zeros((3, *SHAPE)))
    with pytest.raises(TypeError, match="write_merl"):
        to_json_dict(table)
    assert not is_serialisable(table)
    with pytest.raises(ModelFormatError, match=r"runs/x\.json.*MerlTable.*write_merl"):
        from_json_dict({"model": "MerlTable", "params": {}}, source="runs/x.json")


def test_unregistered_types_and_subclasses_are_refused() -> None:
    class Tinted(Lambert):
        pass

    with pytest.raises(TypeError, match="Tinted has no JSON form"):
        to_json_dict(Tinted())
    assert is_serialisable(Lambert()) and not is_serialisable(Tinted()) and not is_serialisable(object())


BAD: list[tuple[Any, str]] = [
    ([1, 2], r"m\.json: expected an object with 'model' and 'params'; got list"),
    ({"params": {}}, r"m\.json: missing key 'model'"),
    ({"model": "Lambert"}, r"m\.json: missing key 'params'"),
    ({"model": "Lamberd", "params": {}}, r"m\.json: model = 'Lamberd': expected one of .*Lambert"),
    ({"model": 3, "params": {}}, r"m\.json: model = 3: expected one of"),
    ({"model": "Lambert", "params": [0.5]}, r"m\.json: params = \[0\.5\]: expected an object of Lambert fields"),
    ({"model": "Lambert", "params": {"rho": 0.5}}, r"m\.json: params: unknown field\(s\) 'rho' for Lambert; expected"),
    ({"model": "Lambert", "params": {"rho_d": "0.5"}}, r"m\.json: params\.rho_d = '0\.5': expected a number or a non"),
    ({"model": "Lambert", "params": {"rho_d": True}}, r"m\.json: params\.rho_d = True: expected a number"),
    ({"model": "Lambert", "params": {"rho_d": []}}, r"params\.rho_d = \[\]: expected a number or a non-empty list"),
    ({"model": "Lambert", "params": {"rho_d": [0.1, "x"]}}, r"params\.rho_d = \[0\.1, 'x'\]"),
    ({"model": "CookTorrance", "params": {"alpha": [0.1, 0.2]}}, r"params\.alpha = \[0\.1, 0\.2\]: expected a number$"),
    ({"model": "CookTorrance", "params": {"distribution": 1}}, r"params\.distribution = 1: expected a string"),
    ({"model": "Ward", "params": {"alpha_y": "wide"}}, r"params\.alpha_y = 'wide': expected a number or null"),
    ({"model": "CookTorrance", "params": {"alpha": -1}}, r"m\.json: params: CookTorrance\.alpha = -1\.0 is outside"),
    ({"model": "CookTorrance", "params": {"distribution": "phong"}}, r"params: CookTorrance\.distribution = 'phong'"),
    ({"model": "Lambert", "params": {"rho_d": float("nan")}}, r"params: Lambert\.rho_d = nan is outside"),
    ({"model": "Lafortune", "params": {"lobes": {}}}, r"params\.lobes = \{\}: expected a non-empty list of Lafortune"),
    ({"model": "Lafortune", "params": {"lobes": [{}, {"c_w": 1}]}}, r"params\.lobes\[1\]: unknown field\(s\) 'c_w'"),
    ({"model": "Lafortune", "params": {"lobes": [{"n": "ten"}]}}, r"params\.lobes\[0\]\.n = 'ten': expected a number"),
    ({"model": "Lafortune", "params": {"lobes": [{"n": -1}]}}, r"params\.lobes\[0\]: LafortuneLobe\.n = -1\.0"),
]


@pytest.mark.parametrize(("doc", "message"), BAD, ids=[m[:40] for _, m in BAD])
def test_bad_input_names_source_key_and_expectation(doc: Any, message: str) -> None:
    with pytest.raises(ModelFormatError, match=message):
        from_json_dict(doc, source="m.json")


def test_error_without_source_still_says_what_it_read() -> None:
    with pytest.raises(ModelFormatError, match=r"^model JSON: params\.n = None"):
        from_json_dict({"model": "Phong", "params": {"n": None}})


def test_extra_top_level_keys_are_metadata() -> None:
    d = {**to_json_dict(KajiyaKay()), "facts": {"reciprocal": False}}
    assert from_json_dict(d) == KajiyaKay()
