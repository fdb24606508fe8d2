"""Exports of a fitted material: its parameters, Mitsuba 3 (stock and gonio's plugin), glTF, MERL, and a README.

A fit is useful beyond gonio only if other tools can take it. Each export says how faithful it is:

- ``material.json``: the model's class and parameters (:mod:`model.serialize`; exact, reads back with
  ``from_json_dict``) plus facts that do not depend on how it was fitted: channels, reciprocity, the
  energy promise and its exemption, directional albedo at a few incidence angles, the Mitsuba paths and
  the stock-Mitsuba error.
- ``mitsuba_bsdf.xml`` / ``mitsuba_bsdf.json``: a BSDF stock Mitsuba 3 renders without gonio
  (:mod:`analysis.export_mitsuba`): the exact native mapping where one exists (``diffuse``,
  ``roughconductor``, ``blendbsdf`` of those; tolerances NATIVE_REL_TOL, BECKMANN_REL_TOL), else the
  nearest diffuse + GGX roughconductor (:func:`model.mitsuba.projection.native_projection`), with the
  relative RMS BRDF difference Mitsuba measures against the model. The XML file wraps the
  ``<bsdf id="...">`` in ``<scene version="3.0.0">`` so a scene can ``<include filename="mitsuba_bsdf.xml"/>``
  it and ``<ref id="material"/>``; :func:`mitsuba_xml` returns the bare element to paste.
- ``mitsuba_scene.xml``: a whole scene (a 5 cm patch of the material, a point light, a camera) that
  ``mitsuba mitsuba_scene.xml`` renders as it is.
- ``mitsuba_gonio_plugin.xml`` (opt-in, ``gonio_plugin=True``, models without an exact native mapping):
  the exact model through the ``gonio_model`` plugin, for renders in a process that has gonio.
- ``gltf_material.json``: the glTF 2.0 material closest to the model (:mod:`model.fit.metal_roughness`),
  with the projection's error in its extras; ``material.gltf``: a whole glTF asset, a sample patch
  wearing it (:mod:`analysis.export_gltf`), which glTF viewers open.
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
from analysis.export_gltf import gltf_asset
from analysis.export_mitsuba import (
    XML_VERSION,
    merl_refusal,
    mitsuba_dict,
    mitsuba_xml,
    scene_file,
    scene_xml,
    stock_note,
)
from model.base import BRDF
from model.fit.metal_roughness import GRAZING_DEG, MetalRoughnessFit, gltf_material, to_metal_roughness
from model.geometry import spherical_to_vector
from model.integrate import directional_albedo
from model.merl import MerlTable, write_merl
from model.mitsuba.materials import to_mitsuba
from model.mitsuba.projection import NativeProjection, native_projection
from model.serialize import to_json_dict
from model.version import gonio_version

__all__ = ["FILES", "XML_VERSION", "export_material", "export_notes", "material_facts", "mitsuba_dict", "mitsuba_xml"]

#: File name of each export, by the kind :func:`export_material` returns it under.
FILES: dict[str, str] = {
    "material": "material.json",
    "mitsuba_xml": "mitsuba_bsdf.xml",
    "mitsuba_json": "mitsuba_bsdf.json",
    "mitsuba_scene": "mitsuba_scene.xml",
    "mitsuba_plugin_xml": "mitsuba_gonio_plugin.xml",
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


def material_facts(model: BRDF, projection: NativeProjection | None = None) -> dict[str, Any]:
    """What holds for the model whatever it was fitted to: channels, physics promises, albedo, Mitsuba paths."""
    mat = to_mitsuba(model)
    projection = projection or native_projection(model)
    # Quadrature cannot resolve a narrow lobe; models that declare one get importance-sampled Monte Carlo.
    method = "mc" if callable(getattr(model, "lobe", None)) else "quadrature"
    albedo, stderr = [], []
    for theta in ALBEDO_THETA_DEG:
        est = directional_albedo(model, spherical_to_vector(np.radians(theta), 0.0), n=ALBEDO_EVALS, method=method)
        albedo.append(np.atleast_1d(est.value).tolist())
        stderr.append(np.atleast_1d(est.stderr).tolist())
    conserves = getattr(model, "conserves_energy", None)
    return {
        "channels": getattr(model, "channels", None) or 1,
        "reciprocal": bool(getattr(model, "reciprocal", True)),
        "conserves_energy": bool(conserves()) if callable(conserves) else None,
        "exemption": str(getattr(model, "exemption", "")),
        "directional_albedo": {
            "theta_i_deg": list(ALBEDO_THETA_DEG), "value": albedo, "stderr": stderr, "method": method,
            "evaluations": ALBEDO_EVALS,
        },
        "mitsuba": {"plugin": mat.plugin, "native": mat.native, "note": mat.note},
        "mitsuba_stock": {
            "plugin": projection.material.plugin, "exact": projection.exact, "note": projection.material.note,
            "native_model": to_json_dict(projection.native_model), "error": projection.error,
        },
    }  # fmt: skip


def _write_text(path: Path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _json_text(doc: dict[str, Any]) -> str:
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


def _readme(model: BRDF, name: str, projection: NativeProjection, mr: MetalRoughnessFit, files: list[str]) -> str:
    """The export's README: each file, how faithful it is, and how to use it."""
    e = projection.error
    per_channel = ", ".join(f"{x:.3%}" for x in e["rms_rel_per_channel"])
    where = e["worst_at_deg"]
    lines = [
        f"# {name}: exports of a fitted {type(model).__name__}", "",
        f"Written by gonio {gonio_version()}. BRDF values f_r in 1/sr (cosine excluded), angles in degrees.", "",
        "| file | what it is |", "| --- | --- |",
    ]
    about = {
        "material.json": "the fitted gonio model, exact (`model.serialize.from_json_dict` reads it back), with facts",
        "mitsuba_bsdf.xml": "Mitsuba 3 BSDF for stock Mitsuba (no gonio needed): "
                            f"`<include filename=\"mitsuba_bsdf.xml\"/>` then `<ref id=\"{name}\"/>`",
        "mitsuba_bsdf.json": "the same BSDF as a Mitsuba scene-dict entry: `mi.load_dict(json.load(f))`",
        "mitsuba_scene.xml": "a whole scene (a 5 cm patch under a point light): `mitsuba mitsuba_scene.xml`",
        "mitsuba_gonio_plugin.xml": "the exact model through gonio's `gonio_model` plugin: renders only in a "
                                    "Python process that imported `model.mitsuba.plugin` (stock Mitsuba refuses it)",
        "gltf_material.json": "glTF 2.0 metal-roughness material object (a projection, error below)",
        "material.gltf": "a glTF 2.0 asset, a 5 cm sample patch wearing that material; glTF viewers open it",
        "material.binary": "the model tabulated at MERL's bin centres (MERL .binary)",
        "README.md": "this file",
    }  # fmt: skip
    lines += [f"| `{f}` | {about[f]} |" for f in files]
    lines += ["", "## Mitsuba", "", stock_note(model, projection) + ".", ""]
    lines += [
        f"Relative RMS difference sqrt(sum (f_mitsuba - f)^2 / sum f^2) over {e['pairs']} direction pairs "
        f"(both zenith angles 0-80 deg in 5 deg steps, phi_o - phi_i 0-180 deg in 10 deg steps, phi_i 0, 45, 90 "
        f"deg): **{e['rms_rel']:.3%}** (per channel {per_channel}); worst relative difference {e['worst_rel']:.2%} at "
        f"theta_i {where['theta_i']:.0f}, theta_o {where['theta_o']:.0f}, phi_o - phi_i "
        f"{where['phi_o_minus_phi_i']:.0f} deg. Evaluated by {e['evaluated_by']}.", "",
    ]  # fmt: skip
    if not projection.exact:
        native = json.dumps(to_json_dict(projection.native_model))
        lines += [f"The stock BSDF is the Mitsuba form of the gonio model `{native}`, fitted to the exported "
                  "model's values; for renders that must be exact, use `mitsuba_gonio_plugin.xml` "
                  "(`gonio analyze --mitsuba-plugin`) in a process with gonio.", ""]  # fmt: skip
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
) -> dict[str, Path]:
    """Write the exports of ``model`` into ``out_dir`` (see the module docstring); returns the paths by kind.

    ``gonio_plugin`` adds mitsuba_gonio_plugin.xml (the exact model, for processes with gonio) where the
    stock form is a projection. Everything is computed before the first file is written, and each file is
    written atomically, so a model that cannot be exported leaves ``out_dir`` as it was.
    """
    if not isinstance(name, str) or not name.strip():
        raise ValueError(f"export_material: name = {name!r}; expected a non-empty string (the XML id and glTF name)")
    merl_refusal(model)
    out = Path(out_dir)
    projection = native_projection(model)
    mr = to_metal_roughness(model)
    material = {
        **to_json_dict(model),
        "conventions": CONVENTIONS,
        "facts": material_facts(model, projection),
        "generator": f"gonio {gonio_version()}",
    }
    gltf = gltf_material(mr, name)
    texts = {
        "material": _json_text(material),
        "mitsuba_xml": scene_file(mitsuba_xml(model, name, projection=projection), name),
        "mitsuba_json": _json_text(mitsuba_dict(model, projection=projection)),
        "mitsuba_scene": scene_xml(name, FILES["mitsuba_xml"]),
        "gltf": _json_text(gltf),
        "gltf_asset": _json_text(gltf_asset(gltf)),
    }
    if gonio_plugin and not projection.exact:
        texts["mitsuba_plugin_xml"] = scene_file(mitsuba_xml(model, name, plugin=True), name)
    kinds = [*texts, *(["merl"] if merl else []), "readme"]
    texts["readme"] = _readme(model, name, projection, mr, [FILES[k] for k in kinds])
    paths: dict[str, Path] = {}
    for kind, text in texts.items():
        paths[kind] = out / FILES[kind]
        _write_text(paths[kind], text)
    if merl:
        # write_merl writes beside the target and renames, like atomic_path.
        paths["merl"] = out / FILES["merl"]
        write_merl(MerlTable.from_model(model), paths["merl"])
    return paths


def export_notes(paths: dict[str, Path]) -> dict[str, str]:
    """What the report says beside each export: for the Mitsuba files, exact or projected and the error."""
    notes: dict[str, str] = {}
    material = paths.get("material")
    if material is None or not material.is_file():
        return notes
    stock = json.loads(material.read_text(encoding="utf-8")).get("facts", {}).get("mitsuba_stock")
    if not stock:
        return notes
    rms = f"relative RMS BRDF difference {stock['error']['rms_rel']:.2%}, evaluated by Mitsuba"
    how = "exact native mapping" if stock["exact"] else f"nearest stock BSDF ({stock['plugin']}), a projection"
    for kind in ("mitsuba_xml", "mitsuba_json"):
        notes[kind] = f"stock Mitsuba 3, no gonio needed: {how}, {rms}"
    return notes
