"""analysis.exports.write: the Mitsuba XML and JSON exports load in Mitsuba 3 and evaluate to the model, the MERL
export reads back bin by bin, and export_material writes what it promises (and nothing when it refuses).

Mitsuba runs under scalar_rgb (always available; one call per pair). Its ``eval`` includes cos(theta_o)
of its ``wo``, the light direction in radiance mode: compared with model.eval(wi=wo, wo=si.wi) * cos.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from analysis.exports.write import FILES, export_material, export_notes, mitsuba_dict, mitsuba_xml
from model import CookTorrance, Lambert, MerlTable, MetalRoughness, Phong, read_merl
from model.base import BRDF
from model.fit.metal_roughness import to_metal_roughness
from model.mitsuba import plugin as mitsuba_bsdf
from model.mitsuba.materials import NATIVE_REL_TOL
from model.mitsuba.variant import use_variant
from model.serialize import ModelFormatError, from_json_dict, to_json_dict
from tests.mitsuba_helpers import f32, require_variant

pytestmark = pytest.mark.mitsuba

VARIANT = "scalar_rgb"
#: One float32 rounding of the plugin's output, with a little margin (as tests/simulator/test_materials.py).
PLUGIN_REL_TOL = 1.5 * 2.0**-24
F32_TINY = float(np.finfo(np.float32).tiny)

NATIVE: dict[str, tuple[BRDF, str]] = {
    "lambert": (Lambert(rho_d=(0.8, 0.5, 0.2)), "diffuse"),
    "ggx_conductor": (CookTorrance(alpha=0.3, eta=(0.18, 0.42, 1.37), k=(3.42, 2.35, 1.77)), "roughconductor"),
    "lambert_ggx_dielectric": (CookTorrance(alpha=0.2, fresnel="dielectric", eta=1.5, rho_d=(0.5, 0.4, 0.2)),
                               "blendbsdf"),
}  # fmt: skip
PLUGIN: dict[str, BRDF] = {
    "phong": Phong(rho_d=(0.3, 0.2, 0.1), rho_s=(0.4, 0.5, 0.6), n=30.0),
    "metal_roughness": MetalRoughness(base_color=(0.9, 0.6, 0.3), metallic=1.0, roughness=0.4),
}


@pytest.fixture(autouse=True)
def scalar_rgb() -> Iterator[None]:
    require_variant(VARIANT)
    with use_variant(VARIANT):
        yield


def sph(theta_deg: float, phi_deg: float) -> np.ndarray:
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.array([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)])


def pairs() -> tuple[np.ndarray, np.ndarray]:
    """float32-rounded (si.wi, wo): a grid to 85 deg, the mirror directions (lobe peaks)."""
    wis = [sph(t, p) for t in (0.0, 30.0, 60.0, 85.0) for p in (0.0, 135.0)]
    wos = [sph(t, p) for t in (10.0, 45.0, 75.0) for p in (0.0, 100.0, 180.0)]
    both = [(a, b) for a in wis for b in wos] + [(a, np.array([-a[0], -a[1], a[2]])) for a in wis]
    wi, wo = (f32(np.array(x)) for x in zip(*both, strict=True))
    return wi, wo


def mitsuba_eval_cos(bsdf: Any, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    """Scalar-variant bsdf.eval (f_r cos(theta_o)) at each pair, (N, 3)."""
    ctx, out = mi.BSDFContext(), []
    for a, b in zip(wi, wo, strict=True):
        si = dr.zeros(mi.SurfaceInteraction3f)
        si.wi = mi.Vector3f(*(float(x) for x in a))
        out.append(list(bsdf.eval(ctx, si, mi.Vector3f(*(float(x) for x in b)))))
    return np.array(out, dtype=np.float64)


def model_eval_cos(m: BRDF, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
    f = np.asarray(m.eval(wo, wi), dtype=np.float64).reshape(len(wi), -1)
    return np.broadcast_to(f, (len(wi), 3)) * wo[:, 2:3]


def assert_matches(bsdf: Any, m: BRDF, rtol: float) -> None:
    wi, wo = pairs()
    theirs, ours = mitsuba_eval_cos(bsdf, wi, wo), model_eval_cos(m, wi, wo)
    assert np.all(ours > 0)
    np.testing.assert_allclose(theirs, ours, rtol=rtol, atol=F32_TINY)


@pytest.mark.parametrize("case", sorted(NATIVE))
def test_xml_fragment_loads_and_evaluates_to_the_model(case: str) -> None:
    m, plugin = NATIVE[case]
    fragment = mitsuba_xml(m, name="sample_bsdf")
    assert fragment.startswith(f'<bsdf type="{plugin}" id="sample_bsdf">') and "version" not in fragment
    bsdf = mi.load_string(fragment.replace("<bsdf ", '<bsdf version="3.0.0" ', 1))
    assert_matches(bsdf, m, NATIVE_REL_TOL)
    # The keyword does the same.
    assert mitsuba_xml(m, name="sample_bsdf", version="3.0.0").startswith(f'<bsdf type="{plugin}" id="sample_bsdf" ')


@pytest.mark.parametrize("case", sorted(NATIVE))
def test_json_dict_loads_and_evaluates_to_the_model(case: str) -> None:
    m, plugin = NATIVE[case]
    d = mitsuba_dict(m)
    assert d["type"] == plugin and json.loads(json.dumps(d)) == d
    assert_matches(mi.load_dict(d), m, NATIVE_REL_TOL)


@pytest.mark.parametrize("case", sorted(PLUGIN))
def test_non_native_models_export_exactly_through_the_gonio_plugin_on_request(case: str) -> None:
    m = PLUGIN[case]
    d = mitsuba_dict(m, plugin=True)
    assert d["type"] == mitsuba_bsdf.PLUGIN and set(d) == {"type", mitsuba_bsdf.MODEL_JSON_KEY}
    assert from_json_dict(json.loads(d[mitsuba_bsdf.MODEL_JSON_KEY])) == m  # plain data, no registry key
    fragment = mitsuba_xml(m, "plugin_bsdf", version="3.0.0", plugin=True)
    assert "stock Mitsuba cannot render it" in fragment and "mitsuba_bsdf.xml" in fragment
    assert_matches(mi.load_string(fragment), m, PLUGIN_REL_TOL)
    assert_matches(mi.load_dict(d), m, PLUGIN_REL_TOL)


def test_plugin_reports_a_bad_model_json_by_property() -> None:
    mitsuba_bsdf.ensure_registered()
    with pytest.raises(Exception, match="gonio_model property 'model_json': not valid JSON"):
        mi.load_dict({"type": mitsuba_bsdf.PLUGIN, mitsuba_bsdf.MODEL_JSON_KEY: "{not json"})
    bad = json.dumps({"model": "Phong", "params": {"n": -3}})
    with pytest.raises(Exception, match=r"model_json': params: Phong\.n = -3\.0 is outside"):
        mi.load_dict({"type": mitsuba_bsdf.PLUGIN, mitsuba_bsdf.MODEL_JSON_KEY: bad})
    with pytest.raises(ModelFormatError, match="model_json': params: unknown field"):
        mitsuba_bsdf.model_from_json(json.dumps({"model": "Phong", "params": {"m": 3}}))
    with pytest.raises(Exception, match=r"needs a 'model' key .* or a 'model_json' string"):
        mi.load_dict({"type": mitsuba_bsdf.PLUGIN})


def test_xml_escapes_names() -> None:
    fragment = mitsuba_xml(Lambert(), name='a "quoted" & <odd> id', version="3.0.0")
    assert mi.load_string(fragment) is not None


def load_through_include(xml_file: Path, name: str) -> Any:
    """The BSDF of a rectangle in a scene that includes the exported file and refers to it by id."""
    scene = mi.load_string(
        f'<scene version="3.0.0"><include filename="{xml_file}"/>'
        f'<shape type="rectangle"><ref id="{name}"/></shape></scene>'
    )
    return scene.shapes()[0].bsdf()


def test_export_material_writes_every_file_for_a_native_model(tmp_path: Path) -> None:
    m = NATIVE["lambert_ggx_dielectric"][0]
    paths = export_material(m, tmp_path / "out", name="plastic")
    assert set(paths) == {"material", "mitsuba_xml", "mitsuba_json", "mitsuba_scene", "gltf", "gltf_asset", "readme"}
    assert {p.name for p in paths.values()} == {FILES[k] for k in paths}  # an exact mapping: no table, no projection
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == sorted(FILES[k] for k in paths)  # no temp files
    doc = json.loads(paths["material"].read_text())
    assert from_json_dict(doc, source=str(paths["material"])) == m
    assert {k: doc[k] for k in ("model", "params")} == to_json_dict(m)
    facts = doc["facts"]
    assert facts["mitsuba"]["native"] and facts["mitsuba"]["plugin"] == "blendbsdf" and facts["channels"] == 3
    albedo = np.array(facts["directional_albedo"]["value"])
    assert albedo.shape == (len(facts["directional_albedo"]["theta_i_deg"]), 3) and np.all((albedo > 0) & (albedo < 1))
    assert mitsuba_dict(m) == json.loads(paths["mitsuba_json"].read_text())
    assert_matches(load_through_include(paths["mitsuba_xml"], "plastic"), m, NATIVE_REL_TOL)
    gltf = json.loads(paths["gltf"].read_text())
    assert gltf["name"] == "plastic" and gltf["extras"]["source_model"] == to_json_dict(m)
    projection = to_metal_roughness(m)  # seeded: the export's projection is reproducible
    assert gltf["pbrMetallicRoughness"]["roughnessFactor"] == projection.material.roughness
    assert gltf["extras"]["projection_error"]["rms_rel"] == projection.rms_rel > 0


#: What a model without a native plugin adds to the native set: the table and both stock forms by name.
NON_NATIVE_EXTRA = {"tabulated", "mitsuba_measured_xml", "mitsuba_measured_json", "mitsuba_projection_xml",
                    "mitsuba_projection_json"}  # fmt: skip
NATIVE_SET = {"material", "mitsuba_xml", "mitsuba_json", "mitsuba_scene", "gltf", "gltf_asset", "readme"}


def test_export_material_for_a_non_native_model_writes_the_table_and_the_projection(tmp_path: Path) -> None:
    m = PLUGIN["phong"]
    paths = export_material(m, tmp_path, name="phong")
    assert set(paths) == NATIVE_SET | NON_NATIVE_EXTRA
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(FILES[k] for k in paths)  # no temp files
    doc = json.loads(paths["material"].read_text())
    facts = doc["facts"]
    assert facts["mitsuba"] == {"plugin": "gonio_model", "native": False,
                                "note": "Python plugin: Mitsuba has no Phong plugin"}  # fmt: skip
    projection, table, stock = facts["mitsuba_projection"], facts["mitsuba_tabulated"], facts["mitsuba_stock"]
    assert projection["plugin"] == "blendbsdf" and not projection["exact"]
    native = from_json_dict(projection["native_model"])
    # The projection is exactly the Mitsuba form of the fitted native model; nothing names gonio's plugin.
    assert json.loads(paths["mitsuba_projection_json"].read_text()) == mitsuba_dict(native)
    assert_matches(load_through_include(paths["mitsuba_projection_xml"], "phong"), native, NATIVE_REL_TOL)
    # The default (auto) is the closer form: Phong's table, stated as Mitsuba measures it, against 124 %.
    assert table["error"]["rms_rel"] < 0.05 < 1.0 < projection["error"]["rms_rel"]
    assert stock["form"] == "tabulated" and stock["plugin"] == "measured" and stock["error"] == table["error"]
    assert json.loads(paths["mitsuba_json"].read_text()) == {"type": "measured", "filename": "material.bsdf"}
    assert paths["mitsuba_measured_json"].read_text() == paths["mitsuba_json"].read_text()
    assert table["size_bytes"] == paths["tabulated"].stat().st_size and table["isotropic"]
    for kind in ("mitsuba_xml", "mitsuba_measured_xml", "mitsuba_projection_xml"):
        assert "gonio_model" not in paths[kind].read_text().split("-->")[-1]
    xml = paths["mitsuba_xml"].read_text()
    e = table["error"]
    # Mitsuba's measured plugin gives these numbers' last bits differently from one process to the next: they are
    # written to 4 significant digits (as the files' texts show them), so material.json is the same bytes each time.
    for value in (e["rms_rel"], e["rms_rel_cosine_weighted"], e["worst_rel"], *e["rms_rel_per_channel"]):
        assert value == float(f"{value:.4g}"), value
    for figure in (f"{e['rms_rel']:.3%}", f"{e['rms_rel_cosine_weighted']:.3%}", f"{e['worst_rel']:.2%}"):
        assert figure in xml and figure in paths["readme"].read_text()
    assert f"{projection['error']['rms_rel']:.3%}" in paths["readme"].read_text()
    assert f"{table['size_bytes'] / 1e6:.2f} MB" in xml
    # Mitsuba finds the table through its file resolver, as the XML says: not from a scene elsewhere until the
    # export directory is added; then its values are the model's, as stated.
    with pytest.raises(RuntimeError, match=r'"material\.bsdf" does not exist'):
        load_through_include(paths["mitsuba_xml"], "phong")
    resolver = mi.FileResolver(mi.file_resolver())
    try:
        mi.file_resolver().prepend(str(tmp_path))
        g = load_through_include(paths["mitsuba_xml"], "phong")
    finally:
        mi.set_file_resolver(resolver)
    rng = np.random.default_rng(2)
    wi = np.array([sph(t, p) for t, p in zip(rng.uniform(0, 80, 200), rng.uniform(-180, 180, 200), strict=True)])
    wo = np.array([sph(t, p) for t, p in zip(rng.uniform(0, 80, 200), rng.uniform(-180, 180, 200), strict=True)])
    got, want = mitsuba_eval_cos(g, f32(wi), f32(wo)), model_eval_cos(m, f32(wi), f32(wo))
    assert float(np.sqrt(np.sum((got - want) ** 2) / np.sum(want**2))) < 0.05
    # What the report page says beside each file: which form, and how far it is.
    notes = export_notes(paths)
    assert notes["mitsuba_xml"].startswith("stock Mitsuba 3, no gonio needed: the model tabulated for Mitsuba's")
    assert f"{e['rms_rel']:.2%}" in notes["mitsuba_xml"] and f"{e['rms_rel']:.2%}" in notes["tabulated"]
    assert f"{projection['error']['rms_rel']:.2%}" in notes["mitsuba_projection_xml"]
    with_plugin = export_material(m, tmp_path / "with_plugin", name="phong", gonio_plugin=True)
    assert_matches(load_through_include(with_plugin["mitsuba_plugin_xml"], "phong"), m, PLUGIN_REL_TOL)


def test_the_projection_stays_the_default_on_request_and_a_bad_choice_is_refused(tmp_path: Path) -> None:
    m = PLUGIN["phong"]
    paths = export_material(m, tmp_path / "projected", name="phong", stock="projection")
    stock = json.loads(paths["material"].read_text())["facts"]["mitsuba_stock"]
    native = from_json_dict(stock["native_model"])
    assert stock["form"] == "projection" and stock["plugin"] == "blendbsdf"
    assert json.loads(paths["mitsuba_json"].read_text()) == mitsuba_dict(native)
    assert paths["mitsuba_xml"].read_text() == paths["mitsuba_projection_xml"].read_text()
    assert "tabulated" in paths  # the table is there all the same, under its own name
    assert "hold the projection (as asked: `--mitsuba-stock projection`)" in paths["readme"].read_text()
    assert export_notes(paths)["mitsuba_xml"] == (
        "stock Mitsuba 3, no gonio needed: nearest stock BSDF (blendbsdf), a projection, relative RMS BRDF "
        f"difference {stock['error']['rms_rel']:.2%}, evaluated by Mitsuba")
    with pytest.raises(ValueError, match="stock = 'tabular'; expected one of auto, tabulated, projection"):
        export_material(m, tmp_path / "bad", stock="tabular")
    assert not (tmp_path / "bad").exists()


def test_a_model_that_cannot_be_tabulated_falls_back_to_the_projection_and_says_why(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import analysis.exports.stock

    def refuse(model: BRDF, *args: object, **kwargs: object) -> None:
        raise ValueError(f"{type(model).__name__}: f_r is negative at some tabulated directions")

    monkeypatch.setattr(analysis.exports.stock, "tabulate", refuse)
    m = PLUGIN["phong"]
    paths = export_material(m, tmp_path / "auto", name="phong")
    facts = json.loads(paths["material"].read_text())["facts"]
    assert facts["mitsuba_stock"]["form"] == "projection" and "tabulated" not in paths
    refusal = "Phong: f_r is negative at some tabulated directions"
    assert facts["mitsuba_tabulated"] == {"file": None, "refusal": refusal}
    readme = paths["readme"].read_text()
    assert "Not written: Phong: f_r is negative" in readme and "the model could not be tabulated" in readme
    with pytest.raises(ValueError, match="Phong: f_r is negative"):
        export_material(m, tmp_path / "forced", stock="tabulated")
    assert not (tmp_path / "forced").exists()


def test_merl_export_reads_back_bin_by_bin(tmp_path: Path) -> None:
    # Phong varies with theta_h, theta_d and phi_d alike, so a misplaced bin would show.
    m = Phong(rho_d=(0.3, 0.2, 0.1), rho_s=(0.4, 0.5, 0.6), n=10.0)
    start = time.perf_counter()
    paths = export_material(m, tmp_path, merl=True)
    elapsed = time.perf_counter() - start
    back = read_merl(paths["merl"])
    expected = MerlTable.from_model(m)
    assert np.all(np.isfinite(back.values))
    np.testing.assert_allclose(back.values, expected.values, rtol=1e-15, atol=0.0)
    assert len({float(v) for v in back.values[0, ::9, ::9, ::9].ravel()}) > 100  # not a constant table
    print(f"export_material with merl=True: {elapsed:.2f} s")  # shown with -s


def test_refusals_leave_nothing_behind(tmp_path: Path) -> None:
    table = MerlTable(np.full((3, 90, 90, 180), 0.1))
    with pytest.raises(ValueError, match="write_merl"):
        export_material(table, tmp_path / "merl")
    with pytest.raises(ValueError, match="no JSON form"):
        mitsuba_xml(table)
    with pytest.raises(ValueError, match="name = ''"):
        export_material(Lambert(), tmp_path / "unnamed", name="")
    assert not (tmp_path / "merl").exists() and not (tmp_path / "unnamed").exists()


def test_gltf_asset_is_a_whole_valid_gltf_2_document(tmp_path: Path) -> None:
    import base64
    import struct

    m = NATIVE["ggx_conductor"][0]
    paths = export_material(m, tmp_path, name="gold")
    doc = json.loads(paths["gltf_asset"].read_text())
    assert doc["asset"]["version"] == "2.0" and doc["scene"] == 0
    # Every index points at something that exists (glTF 2.0 section 3.7 onwards).
    scene = doc["scenes"][doc["scene"]]
    node = doc["nodes"][scene["nodes"][0]]
    prim = doc["meshes"][node["mesh"]]["primitives"][0]
    assert doc["materials"][prim["material"]] == json.loads(paths["gltf"].read_text())
    (buffer,) = doc["buffers"]
    prefix = "data:application/octet-stream;base64,"
    assert buffer["uri"].startswith(prefix)
    data = base64.b64decode(buffer["uri"][len(prefix):])
    assert len(data) == buffer["byteLength"]
    sizes = {5126: 4, 5123: 2}
    widths = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}
    decoded = {}
    for i, acc in enumerate(doc["accessors"]):
        view = doc["bufferViews"][acc["bufferView"]]
        assert view["buffer"] == 0 and view["byteOffset"] % sizes[acc["componentType"]] == 0
        assert view["byteOffset"] + view["byteLength"] <= len(data)
        n = acc["count"] * widths[acc["type"]]
        assert n * sizes[acc["componentType"]] == view["byteLength"]
        fmt = "<" + ("f" if acc["componentType"] == 5126 else "H") * n
        decoded[i] = np.array(struct.unpack_from(fmt, data, view["byteOffset"])).reshape(acc["count"], -1)
    pos = decoded[prim["attributes"]["POSITION"]]
    np.testing.assert_allclose(pos.min(axis=0), doc["accessors"][prim["attributes"]["POSITION"]]["min"], atol=1e-7)
    np.testing.assert_allclose(pos.max(axis=0), doc["accessors"][prim["attributes"]["POSITION"]]["max"], atol=1e-7)
    assert np.ptp(pos[:, 0]) == pytest.approx(0.05) and np.all(pos[:, 1] == 0)  # a 5 cm patch in the x-z plane
    idx = decoded[prim["indices"]].ravel().astype(int)
    assert sorted(set(idx)) == [0, 1, 2, 3] and prim.get("mode", 4) == 4
    normals = decoded[prim["attributes"]["NORMAL"]]
    np.testing.assert_allclose(normals, [[0.0, 1.0, 0.0]] * 4)
    # Triangles wind counter-clockwise seen along their normal (front faces, glTF 2.0 section 3.7.2.1).
    for t in idx.reshape(-1, 3):
        a, b, c = pos[t]
        assert np.dot(np.cross(b - a, c - a), normals[t[0]]) > 0


def test_the_usual_models_scene_dictionary_loads_from_any_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Lambert + GGX with Schlick Fresnel projects within 5 %: mitsuba_bsdf.json needs no side file to be found.
    m = CookTorrance(alpha=0.2, fresnel="schlick", f0=0.04, rho_d=(0.5, 0.4, 0.2))
    paths = export_material(m, tmp_path / "export")
    facts = json.loads(paths["material"].read_text())["facts"]
    assert facts["mitsuba_stock"]["form"] == "projection" and facts["mitsuba_projection"]["error"]["rms_rel"] <= 0.05
    assert "tabulated" in paths  # the table is written all the same, under its own name
    assert "self-contained" in paths["readme"].read_text()
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    bsdf = mi.load_dict(json.loads(paths["mitsuba_json"].read_text()))  # under the autouse fixture's variant
    assert bsdf is not None
