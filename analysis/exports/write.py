"""Exports of a fitted material: its parameters, Mitsuba 3 (stock and gonio's plugin), glTF, MERL, and a README.

A fit is useful beyond gonio only if other tools can take it. Each export says how faithful it is:

- ``material.json``: the model's class and parameters (:mod:`model.serialize`; exact, reads back with
  ``from_json_dict``) plus facts that do not depend on how it was fitted: channels, reciprocity, the
  energy promise and its exemption, directional albedo at a few incidence angles, the Mitsuba paths and
  the stock-Mitsuba error.
- ``mitsuba_bsdf.xml`` / ``mitsuba_bsdf.json``: a BSDF stock Mitsuba 3 renders without gonio
  (:mod:`analysis.exports.mitsuba`): the exact native mapping where one exists (``diffuse``,
  ``roughconductor``, ``blendbsdf`` of those; tolerances NATIVE_REL_TOL, BECKMANN_REL_TOL), else the
  nearest diffuse + GGX roughconductor (:func:`model.mitsuba.projection.native_projection`), with the
  relative RMS BRDF difference Mitsuba measures against the model. The XML file wraps the
  ``<bsdf id="...">`` in ``<scene version="3.0.0">`` so a scene can ``<include filename="mitsuba_bsdf.xml"/>``
  it and ``<ref id="material"/>``; :func:`mitsuba_xml` returns the bare element to paste.
- ``material.bsdf``, ``mitsuba_measured.xml`` / ``mitsuba_measured.json`` (models without a native plugin):
  the model tabulated in the RGL ``.bsdf`` format for stock Mitsuba's ``measured`` plugin
  (:mod:`model.mitsuba.tabulated`), its error measured like the projection's (Mitsuba reading the file);
  ``mitsuba_projection.xml`` / ``mitsuba_projection.json``: the projection under its own name. Which of the
  two ``mitsuba_bsdf.*`` hold is ``stock``: ``"auto"`` (the default) takes the one with the lower relative
  RMS difference (the table for every model measured so far: Phong n = 30 1.8 % against the projection's
  124 %, anisotropic Ward 2.2 % against 79 %, Oren-Nayar 1.7 % against 12 %, Lambert + GGX with Schlick
  Fresnel 2.0 % against 2.7 %: bench/tabulated.py), ``"projection"`` or ``"tabulated"`` force one.
- ``mitsuba_scene.xml``: a whole scene (a 5 cm patch of the material, a point light, a camera) that
  ``mitsuba mitsuba_scene.xml`` renders as it is.
- ``mitsuba_gonio_plugin.xml`` (opt-in, ``gonio_plugin=True``, models without an exact native mapping):
  the exact model through the ``gonio_model`` plugin, for renders in a process that has gonio.
- ``gltf_material.json``: the glTF 2.0 material closest to the model (:mod:`model.fit.metal_roughness`),
  with the projection's error in its extras; ``material.gltf``: a whole glTF asset, a sample patch
  wearing it (:mod:`analysis.exports.gltf`), which glTF viewers open.
- ``material.binary`` (opt-in, 35 MB): the model tabulated at MERL's bin centres, for tools that read
  MERL files (nearest-bin lookup: exact at the bin centres only).
- ``README.md``: what each file is, and each projection's error in words.

MERL tables have no JSON form: they export through ``write_merl`` and are refused here.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.files.atomic import atomic_path
from analysis.exports.gltf import gltf_asset
from analysis.exports.mitsuba import (
    TABULATED_FILE,
    XML_VERSION,
    measured_xml,
    merl_refusal,
    mitsuba_dict,
    mitsuba_xml,
    scene_file,
    scene_xml,
    stock_note,
    tabulated_note,
)
from analysis.exports.stock import SELF_CONTAINED_RMS, STOCK_FORMS, StockForms, stock_forms, tabulated_facts
from model.base import BRDF
from model.fit import metal_roughness
from model.fit.metal_roughness import GRAZING_DEG, MetalRoughnessFit, gltf_material, to_metal_roughness
from model.geometry import spherical_to_vector
from model.integrate import directional_albedo, prepare_albedo
from model.merl import MerlTable, write_merl
from model.mitsuba.materials import to_mitsuba
from model.mitsuba.projection import GRID_PHI_I_DEG, NativeProjection, fit_pairs, grid_pairs, native_projection
from model.mitsuba.tabulated import TabulationGrid, measured_bsdf, prepare_tabulation
from model.mitsuba.warm import warm_up
from model.serialize import to_json_dict
from model.version import gonio_version

__all__ = [
    "FILES", "STOCK_FORMS", "XML_VERSION", "StockForms", "export_material", "export_notes", "material_facts",
    "mitsuba_dict", "mitsuba_xml", "prepare_exports", "stock_forms",
]  # fmt: skip

#: File name of each export, by the kind :func:`export_material` returns it under.
FILES: dict[str, str] = {
    "material": "material.json",
    "mitsuba_xml": "mitsuba_bsdf.xml",
    "mitsuba_json": "mitsuba_bsdf.json",
    "mitsuba_scene": "mitsuba_scene.xml",
    "mitsuba_plugin_xml": "mitsuba_gonio_plugin.xml",
    "tabulated": TABULATED_FILE,
    "mitsuba_measured_xml": "mitsuba_measured.xml",
    "mitsuba_measured_json": "mitsuba_measured.json",
    "mitsuba_projection_xml": "mitsuba_projection.xml",
    "mitsuba_projection_json": "mitsuba_projection.json",
    "gltf": "gltf_material.json",
    "gltf_asset": "material.gltf",
    "merl": "material.binary",
    "readme": "README.md",
}
#: Incidence angles (degrees) at which material.json states the directional albedo.
ALBEDO_THETA_DEG: tuple[float, ...] = (0.0, 30.0, 60.0, 75.0, 85.0)
#: Evaluations per albedo (quadrature points, or importance samples for models with a microfacet lobe).
ALBEDO_EVALS = 65_536
CONVENTIONS = (
    "f_r in 1/sr, cosine excluded; local frame with z the sample normal and both directions pointing away; "
    "angle-valued parameters (sigma, phi_t) in radians"
)


def material_facts(
    model: BRDF, projection: NativeProjection | None = None, forms: StockForms | None = None
) -> dict[str, Any]:
    """What holds for the model whatever it was fitted to: channels, physics promises, albedo, Mitsuba paths.

    ``mitsuba_stock`` describes what mitsuba_bsdf.* hold (with ``forms``: the default form, ``form`` naming
    it); for a model without a native plugin ``mitsuba_projection`` and ``mitsuba_tabulated`` describe both forms.
    """
    mat = to_mitsuba(model)
    projection = forms.projection if forms is not None else projection or native_projection(model)
    # Quadrature cannot resolve a narrow lobe; models that declare one get importance-sampled Monte Carlo.
    method = "mc" if callable(getattr(model, "lobe", None)) else "quadrature"
    albedo, stderr = [], []
    for theta in ALBEDO_THETA_DEG:
        est = directional_albedo(model, spherical_to_vector(np.radians(theta), 0.0), n=ALBEDO_EVALS, method=method)
        albedo.append(np.atleast_1d(est.value).tolist())
        stderr.append(np.atleast_1d(est.stderr).tolist())
    conserves = getattr(model, "conserves_energy", None)
    facts: dict[str, Any] = {
        "channels": getattr(model, "channels", None) or 1,
        "reciprocal": bool(getattr(model, "reciprocal", True)),
        "conserves_energy": bool(conserves()) if callable(conserves) else None,
        "exemption": str(getattr(model, "exemption", "")),
        "directional_albedo": {
            "theta_i_deg": list(ALBEDO_THETA_DEG), "value": albedo, "stderr": stderr, "method": method,
            "evaluations": ALBEDO_EVALS,
        },
        "mitsuba": {"plugin": mat.plugin, "native": mat.native, "note": mat.note},
    }  # fmt: skip
    proj = {
        "plugin": projection.material.plugin, "exact": projection.exact, "note": projection.material.note,
        "native_model": to_json_dict(projection.native_model), "error": projection.error,
    }  # fmt: skip
    if forms is None or forms.chosen in ("native", "projection"):
        facts["mitsuba_stock"] = {**proj, "form": "native" if projection.exact else "projection"}
    else:
        tab = tabulated_facts(forms)
        # The table samples the model itself: the "native model" of this stock form is the model.
        facts["mitsuba_stock"] = {
            "plugin": "measured", "exact": False, "note": tab["note"], "native_model": to_json_dict(model),
            "error": tab["error"], "form": "tabulated", "file": TABULATED_FILE,
        }  # fmt: skip
    if forms is not None and not projection.exact:
        facts["mitsuba_projection"] = proj
        facts["mitsuba_tabulated"] = tabulated_facts(forms)
    return facts


def prepare_exports() -> None:
    """Compute what :func:`export_material` needs that depends on no model: the seeded direction pairs of the
    projections and the albedo, the error grid, the tabulation's unit square, and Mitsuba's first-use costs
    (:func:`model.mitsuba.warm.warm_up`).

    ``gonio analyze``'s export standby calls it while the fit runs; the exports then take the same arrays (cached
    in their modules, read-only), so the files are the same bytes with or without it.
    """
    grid_pairs()
    grid_pairs(GRID_PHI_I_DEG[:1])
    fit_pairs()
    metal_roughness.seeded_pairs(metal_roughness.FIT_SAMPLES, 0)
    prepare_albedo(ALBEDO_EVALS, 0)
    prepare_tabulation()
    warm_up()


def _write_text(path: Path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _json_text(doc: dict[str, Any]) -> str:
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


def _error_paragraph(e: dict[str, Any]) -> str:
    """The README's statement of one stock form's error: the metric, the grid and every figure."""
    per_channel = ", ".join(f"{x:.3%}" for x in e["rms_rel_per_channel"])
    where = e["worst_at_deg"]
    return (
        f"Relative RMS difference sqrt(sum (f_mitsuba - f)^2 / sum f^2) over {e['pairs']} direction pairs "
        f"(both zenith angles 0-80 deg in 5 deg steps, phi_o - phi_i 0-180 deg in 10 deg steps, phi_i 0, 45, 90 "
        f"deg): **{e['rms_rel']:.3%}** (per channel {per_channel}); weighted by cos^2 theta_i cos^2 theta_o "
        f"sin theta_i sin theta_o (what a camera sees) {e['rms_rel_cosine_weighted']:.3%}; worst relative "
        f"difference {e['worst_rel']:.2%} at theta_i {where['theta_i']:.0f}, theta_o {where['theta_o']:.0f}, "
        f"phi_o - phi_i {where['phi_o_minus_phi_i']:.0f} deg. Evaluated by {e['evaluated_by']}."
    )


def _readme(model: BRDF, name: str, forms: StockForms, mr: MetalRoughnessFit, files: list[str]) -> str:
    """The export's README: each file, how faithful it is, and how to use it."""
    projection = forms.projection
    lines = [
        f"# {name}: exports of a fitted {type(model).__name__}", "",
        f"Written by gonio {gonio_version()}. BRDF values f_r in 1/sr (cosine excluded), angles in degrees.", "",
        "| file | what it is |", "| --- | --- |",
    ]
    default = {"native": "exact native plugins", "projection": "the projection", "tabulated": "the tabulated form"}
    about = {
        "material.json": "the fitted gonio model, exact (`model.serialize.from_json_dict` reads it back), with facts",
        "mitsuba_bsdf.xml": f"Mitsuba 3 BSDF for stock Mitsuba (no gonio needed; {default[forms.chosen]}): "
                            f"`<include filename=\"mitsuba_bsdf.xml\"/>` then `<ref id=\"{name}\"/>`",
        "mitsuba_bsdf.json": "the same BSDF as a Mitsuba scene-dict entry: `mi.load_dict(json.load(f))`"
                             + (" (`filename` is relative: load from this directory)" if forms.chosen == "tabulated"
                                else ""),
        "mitsuba_scene.xml": "a whole scene (a 5 cm patch under a point light): `mitsuba mitsuba_scene.xml`",
        "mitsuba_gonio_plugin.xml": "the exact model through gonio's `gonio_model` plugin: renders only in a "
                                    "Python process that imported `model.mitsuba.plugin` (stock Mitsuba refuses it)",
        TABULATED_FILE: "the model tabulated in the RGL `.bsdf` format (Dupuy & Jakob 2018) that stock Mitsuba's "
                        "`measured` plugin reads (rgb variants)",
        "mitsuba_measured.xml": f"the `measured` BSDF reading `{TABULATED_FILE}` (XML; Mitsuba finds the table "
                                "for scenes in this directory, else add it: `mi.file_resolver().prepend(dir)`)",
        "mitsuba_measured.json": f"the same as a scene-dict entry (`filename` `{TABULATED_FILE}` is relative: load "
                                 "from this directory, add it to Mitsuba's file resolver, or give the full path)",
        "mitsuba_projection.xml": "the nearest diffuse + GGX roughconductor, fitted to the model (XML)",
        "mitsuba_projection.json": "the same projection as a scene-dict entry",
        "gltf_material.json": "glTF 2.0 metal-roughness material object (a projection, error below)",
        "material.gltf": "a glTF 2.0 asset, a 5 cm sample patch wearing that material; glTF viewers open it",
        "material.binary": "the model tabulated at MERL's bin centres (MERL .binary)",
        "README.md": "this file",
    }  # fmt: skip
    lines += [f"| `{f}` | {about[f]} |" for f in files]
    lines += ["", "## Mitsuba", ""]
    if projection.exact:
        lines += [stock_note(model, projection) + ".", "", _error_paragraph(projection.error), ""]
    else:
        native = json.dumps(to_json_dict(projection.native_model))
        lines += [
            f"`mitsuba_bsdf.xml` and `mitsuba_bsdf.json` hold {default[forms.chosen]}"
            + {"refused": " (the only stock form: the model could not be tabulated, see below).",
               "self-contained": f" (within {SELF_CONTAINED_RMS:.0%} RMS of the model and self-contained: no side "
                                 "file to find).",
               "closer": " (the stock form with the lower relative RMS difference).",
               "requested": f" (as asked: `--mitsuba-stock {forms.requested}`)."}[forms.why], "",
            "### Projection (`mitsuba_projection.xml`)", "", stock_note(model, projection) + ".", "",
            _error_paragraph(projection.error), "",
            f"The projection is the Mitsuba form of the gonio model `{native}`, fitted to the exported model's values.",
            "", f"### Tabulated (`{TABULATED_FILE}`, `mitsuba_measured.xml`)", "",
        ]  # fmt: skip
        if forms.table is None or forms.table_error is None:
            lines += [f"Not written: {forms.refusal}", ""]
        else:
            lines += [tabulated_note(model, forms.table, forms.table_error) + ".", "",
                      _error_paragraph(forms.table_error), ""]  # fmt: skip
        lines += ["For renders that must be exact, use `mitsuba_gonio_plugin.xml` (`gonio analyze --mitsuba-plugin`) "
                  "in a process with gonio.", ""]  # fmt: skip
    m = mr.material
    lines += [
        "## glTF", "",
        f"Metal-roughness projection: metallic {m.metallic:.4f}, roughness {m.roughness:.4f}; relative RMS "
        f"difference of f cos(theta_i) cos(theta_o) over both hemispheres {mr.rms_rel:.2%}, worst {mr.worst_rel:.1%} "
        f"within {GRAZING_DEG:g} deg (full numbers in the material's extras.projection_error).", "",
    ]  # fmt: skip
    return "\n".join(lines)


def export_material(
    model: BRDF,
    out_dir: str | os.PathLike[str],
    *,
    name: str = "material",
    merl: bool = False,
    gonio_plugin: bool = False,
    stock: str = "auto",
    tabulation: TabulationGrid | None = None,
) -> dict[str, Path]:
    """Write the exports of ``model`` into ``out_dir`` (see the module docstring); returns the paths by kind.

    ``gonio_plugin`` adds mitsuba_gonio_plugin.xml (the exact model, for processes with gonio) where the
    stock form is not exact. ``stock`` (one of STOCK_FORMS) picks what mitsuba_bsdf.* hold for a model
    without a native plugin; ``tabulation`` is the resolution of material.bsdf (default TabulationGrid()).
    Everything is computed before the first file is written, and each file is written atomically, so a
    model that cannot be exported leaves ``out_dir`` as it was.
    """
    if not isinstance(name, str) or not name.strip():
        raise ValueError(f"export_material: name = {name!r}; expected a non-empty string (the XML id and glTF name)")
    merl_refusal(model)
    out = Path(out_dir)
    forms = stock_forms(model, stock, tabulation)
    projection = forms.projection
    mr = to_metal_roughness(model)
    material = {
        **to_json_dict(model),
        "conventions": CONVENTIONS,
        "facts": material_facts(model, forms=forms),
        "generator": f"gonio {gonio_version()}",
    }
    gltf = gltf_material(mr, name)
    projection_xml = scene_file(mitsuba_xml(model, name, projection=projection), name)
    projection_json = _json_text(mitsuba_dict(model, projection=projection))
    texts: dict[str, str] = {"material": _json_text(material)}
    if forms.chosen == "tabulated" and forms.table is not None and forms.table_error is not None:
        texts["mitsuba_xml"] = scene_file(measured_xml(model, name, forms.table, forms.table_error), name)
        texts["mitsuba_json"] = _json_text(measured_bsdf(TABULATED_FILE))
    else:
        texts["mitsuba_xml"], texts["mitsuba_json"] = projection_xml, projection_json
    texts |= {
        "mitsuba_scene": scene_xml(name, FILES["mitsuba_xml"]),
        "gltf": _json_text(gltf),
        "gltf_asset": _json_text(gltf_asset(gltf)),
    }
    if gonio_plugin and not projection.exact:
        texts["mitsuba_plugin_xml"] = scene_file(mitsuba_xml(model, name, plugin=True), name)
    if not projection.exact:
        texts["mitsuba_projection_xml"], texts["mitsuba_projection_json"] = projection_xml, projection_json
    table = forms.table.to_bytes() if forms.table is not None else None
    if forms.table is not None and forms.table_error is not None:
        texts["mitsuba_measured_xml"] = scene_file(measured_xml(model, name, forms.table, forms.table_error), name)
        texts["mitsuba_measured_json"] = _json_text(measured_bsdf(TABULATED_FILE))
    kinds = [*texts, *(["tabulated"] if table is not None else []), *(["merl"] if merl else []), "readme"]
    texts["readme"] = _readme(model, name, forms, mr, [FILES[k] for k in kinds])
    paths: dict[str, Path] = {}
    if table is not None:
        # First, so that no XML naming it exists without it.
        paths["tabulated"] = out / FILES["tabulated"]
        with atomic_path(paths["tabulated"]) as tmp:
            tmp.write_bytes(table)
    for kind, text in texts.items():
        paths[kind] = out / FILES[kind]
        _write_text(paths[kind], text)
    if merl:
        # write_merl writes beside the target and renames, like atomic_path.
        paths["merl"] = out / FILES["merl"]
        write_merl(MerlTable.from_model(model), paths["merl"])
    return paths


def export_notes(paths: dict[str, Path]) -> dict[str, str]:
    """What the report says beside each export: for the Mitsuba files, which form, and its error."""
    notes: dict[str, str] = {}
    material = paths.get("material")
    if material is None or not material.is_file():
        return notes
    facts = json.loads(material.read_text(encoding="utf-8")).get("facts", {})
    stock = facts.get("mitsuba_stock")
    if not stock:
        return notes

    def rms(error: dict[str, Any]) -> str:
        return (
            f"relative RMS BRDF difference {error['rms_rel']:.2%} (cosine weighted "
            f"{error['rms_rel_cosine_weighted']:.2%}, worst {error['worst_rel']:.1%}), evaluated by Mitsuba"
        )

    def old_rms(error: dict[str, Any]) -> str:
        return f"relative RMS BRDF difference {error['rms_rel']:.2%}, evaluated by Mitsuba"

    tabulated = f"the model tabulated for Mitsuba's measured plugin ({TABULATED_FILE})"
    if stock.get("form") == "tabulated":
        how = tabulated
        said = rms(stock["error"])
    else:
        how = "exact native mapping" if stock["exact"] else f"nearest stock BSDF ({stock['plugin']}), a projection"
        said = old_rms(stock["error"])
    for kind in ("mitsuba_xml", "mitsuba_json"):
        notes[kind] = f"stock Mitsuba 3, no gonio needed: {how}, {said}"
    projection, table = facts.get("mitsuba_projection"), facts.get("mitsuba_tabulated")
    if projection:
        for kind in ("mitsuba_projection_xml", "mitsuba_projection_json"):
            notes[kind] = f"stock Mitsuba 3: nearest stock BSDF ({projection['plugin']}), a projection, " + rms(
                projection["error"]
            )
    if table and table.get("error"):
        size = f"{table['size_bytes'] / 1e6:.2f} MB"
        notes["tabulated"] = f"RGL .bsdf table for stock Mitsuba's measured plugin ({size}), {rms(table['error'])}"
        for kind in ("mitsuba_measured_xml", "mitsuba_measured_json"):
            notes[kind] = f"stock Mitsuba 3: {tabulated}, {rms(table['error'])}"
    return notes
