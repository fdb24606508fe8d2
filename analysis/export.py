"""Exports of a fitted material: its parameters, a Mitsuba 3 BSDF (XML and JSON), glTF metal-roughness, MERL.

A fit is useful beyond gonio only if other tools can take it. Each export says how faithful it is:

- ``material.json``: the model's class and parameters (:mod:`model.serialize`; exact, reads back with
  ``from_json_dict``) plus facts that do not depend on how it was fitted: channels, reciprocity, the
  energy promise and its exemption, directional albedo at a few incidence angles, the Mitsuba path.
- ``mitsuba_bsdf.xml`` / ``mitsuba_bsdf.json``: the BSDF :func:`model.mitsuba.materials.to_mitsuba` builds.
  Where that is a native plugin (``diffuse``, ``roughconductor``, ``blendbsdf`` of those) the export is
  exact to the tolerances documented there (NATIVE_REL_TOL, BECKMANN_REL_TOL) and renders in stock
  Mitsuba. The XML file wraps the ``<bsdf id="...">`` in ``<scene version="3.0.0">`` so a scene can
  ``<include filename="mitsuba_bsdf.xml"/>`` it and ``<ref id="material"/>``; :func:`mitsuba_xml` returns
  the bare element to paste.
- ``gltf_material.json``: the glTF 2.0 material closest to the model (:mod:`model.fit.metal_roughness`),
  with the projection's error in its extras: game engines take nothing else, and it is approximate.
- ``material.binary`` (opt-in, 35 MB): the model tabulated at MERL's bin centres, for tools that read
  MERL files (nearest-bin lookup: exact at the bin centres only).

Models without a native Mitsuba plugin (Phong, Ward, the glTF and notes' metalness models, Cook-Torrance
variants, ...). Mitsuba cannot render them outside gonio, and a "nearest native" BSDF would be a second
projection with its own error, on top of the glTF one that already serves portability. So the XML
keeps the exact model: the ``gonio_model`` plugin with the model's JSON in the string property
``model_json`` (:func:`model.mitsuba.plugin.json_plugin_dict`), which the plugin rebuilds in any
process, and an XML comment saying that the file needs gonio's plugin (a Python process that imported
``model.mitsuba.plugin`` under an rgb variant) and that ``gltf_material.json`` is the portable
approximation. ``mitsuba_bsdf.json`` is written for native models only, as the export's contract with
stock Mitsuba; :func:`mitsuba_dict` gives the plugin form only when asked (``allow_plugin=True``). MERL
tables have no JSON form: they export through ``write_merl`` and are refused here.
"""

from __future__ import annotations

import copy
import json
import os
from pathlib import Path
from typing import Any
from xml.sax.saxutils import quoteattr

import numpy as np

from acquisition.files.atomic import atomic_path
from model.base import BRDF
from model.fit.metal_roughness import gltf_material, to_metal_roughness
from model.geometry import spherical_to_vector
from model.integrate import directional_albedo
from model.merl import MerlTable, write_merl
from model.mitsuba import plugin as gonio_plugin
from model.mitsuba.materials import to_mitsuba
from model.serialize import to_json_dict
from model.version import gonio_version

#: File name of each export, by the kind :func:`export_material` returns it under.
FILES: dict[str, str] = {
    "material": "material.json",
    "mitsuba_xml": "mitsuba_bsdf.xml",
    "mitsuba_json": "mitsuba_bsdf.json",
    "gltf": "gltf_material.json",
    "merl": "material.binary",
}
#: Mitsuba scene-format version written into standalone XML.
XML_VERSION = "3.0.0"
#: Plugins a nested dict may name to become a nested ``<bsdf>`` element.
BSDF_PLUGINS = frozenset({"diffuse", "roughconductor", "conductor", "blendbsdf", gonio_plugin.PLUGIN})
#: Incidence angles (degrees) at which material.json states the directional albedo.
ALBEDO_THETA_DEG: tuple[float, ...] = (0.0, 30.0, 60.0, 75.0, 85.0)
#: Evaluations per albedo (quadrature points, or importance samples for models with a microfacet lobe).
ALBEDO_EVALS = 65_536
CONVENTIONS = (
    "f_r in 1/sr, cosine excluded; local frame with z the sample normal and both directions pointing away; "
    "angle-valued parameters (sigma, phi_t) in radians"
)


def _merl_refusal(model: BRDF) -> None:
    if isinstance(model, MerlTable):
        raise ValueError(
            f"MerlTable ({model.source or 'no source'}): Mitsuba has no MERL reader and a table has no JSON form; "
            "write it with model.write_merl, or render it inside gonio through model.mitsuba.materials.to_mitsuba"
        )


def _plain(d: dict[str, Any]) -> dict[str, Any]:
    """A deep copy that is guaranteed to be plain JSON data (raises on anything else)."""
    out: dict[str, Any] = json.loads(json.dumps(d, allow_nan=False))
    return out


def mitsuba_dict(model: BRDF, *, allow_plugin: bool = False) -> dict[str, Any]:
    """JSON-serialisable Mitsuba scene-dict entry of ``model`` (native plugins; the gonio plugin if allowed)."""
    _merl_refusal(model)
    mat = to_mitsuba(model)
    if mat.native:
        return _plain(copy.deepcopy(mat.bsdf))
    if not allow_plugin:
        raise ValueError(
            f"{type(model).__name__} has no native Mitsuba plugin ({mat.note}); allow_plugin=True gives the "
            f"{gonio_plugin.PLUGIN} plugin with the model as JSON, which renders only where gonio registered it"
        )
    return _plain(gonio_plugin.json_plugin_dict(model))


def _comment(text: str) -> str:
    # "--" may not occur inside an XML comment.
    return "<!-- " + text.replace("--", "- -") + " -->"


def _xml_lines(entry: dict[str, Any], tag: str, attrs: str, indent: str) -> list[str]:
    """One Mitsuba object (``entry`` is a scene-dict entry) as XML lines."""
    inner = indent + "    "
    lines = [f"{indent}<{tag} type={quoteattr(str(entry['type']))}{attrs}>"]
    for key, v in entry.items():
        if key == "type":
            continue
        name = quoteattr(key)
        if isinstance(v, bool):
            lines.append(f'{inner}<boolean name={name} value="{str(v).lower()}"/>')
        elif isinstance(v, int):
            lines.append(f'{inner}<integer name={name} value="{v}"/>')
        elif isinstance(v, float):
            lines.append(f'{inner}<float name={name} value="{v!r}"/>')
        elif isinstance(v, str):
            lines.append(f"{inner}<string name={name} value={quoteattr(v)}/>")
        elif isinstance(v, dict) and v.get("type") == "rgb":
            lines.append(f'{inner}<rgb name={name} value="{", ".join(repr(float(x)) for x in v["value"])}"/>')
        elif isinstance(v, dict) and v.get("type") in BSDF_PLUGINS:
            lines += _xml_lines(v, "bsdf", f" name={name}", inner)
        else:
            raise ValueError(f"no Mitsuba XML form for property {key!r} = {v!r} of a {entry['type']!r} plugin")
    lines.append(f"{indent}</{tag}>")
    return lines


def mitsuba_xml(model: BRDF, name: str = "material", *, version: str | None = None) -> str:
    """Mitsuba 3 XML ``<bsdf id=name>`` element of ``model``; with ``version`` it loads on its own."""
    _merl_refusal(model)
    mat = to_mitsuba(model)
    entry = mitsuba_dict(model, allow_plugin=True)
    attrs = f" id={quoteattr(name)}" + ("" if version is None else f" version={quoteattr(version)}")
    lines = _xml_lines(entry, "bsdf", attrs, "")
    notes = [f"gonio export of {type(model).__name__}: {mat.note}"]
    if not mat.native:
        notes.append(
            f"{gonio_plugin.PLUGIN} is gonio's Python plugin: this BSDF loads only in a Python process that "
            "imported model.mitsuba.plugin under an rgb variant; stock Mitsuba cannot render it. "
            "gltf_material.json holds the portable metal-roughness approximation and its error."
        )
    lines[1:1] = ["    " + _comment(n) for n in notes]
    return "\n".join(lines) + "\n"


def _scene_file(fragment: str, name: str) -> str:
    """The XML file: the element inside a versioned scene, so other scenes can include it."""
    body = "".join("    " + line + "\n" if line else "\n" for line in fragment.splitlines())
    use = f'include it in a <scene version="{XML_VERSION}"> with <include filename="{FILES["mitsuba_xml"]}"/>'
    return (
        '<?xml version="1.0" encoding="utf-8"?>\n'
        + _comment(f"{use}, then refer to the BSDF as <ref id=\"{name}\"/>") + "\n"
        + f'<scene version="{XML_VERSION}">\n{body}</scene>\n'
    )  # fmt: skip


def material_facts(model: BRDF) -> dict[str, Any]:
    """What holds for the model whatever it was fitted to: channels, physics promises, albedo, Mitsuba path."""
    mat = to_mitsuba(model)
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
    }  # fmt: skip


def _write_text(path: Path, text: str) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")


def _json_text(doc: dict[str, Any]) -> str:
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


def export_material(
    model: BRDF, out_dir: str | os.PathLike[str], *, name: str = "material", merl: bool = False
) -> dict[str, Path]:
    """Write the exports of ``model`` into ``out_dir`` (see the module docstring); returns the paths by kind.

    Everything is computed before the first file is written, and each file is written atomically, so a
    model that cannot be exported leaves ``out_dir`` as it was.
    """
    if not isinstance(name, str) or not name.strip():
        raise ValueError(f"export_material: name = {name!r}; expected a non-empty string (the XML id and glTF name)")
    _merl_refusal(model)
    out = Path(out_dir)
    native = to_mitsuba(model).native
    material = {
        **to_json_dict(model),
        "conventions": CONVENTIONS,
        "facts": material_facts(model),
        "generator": f"gonio {gonio_version()}",
    }
    texts = {
        "material": _json_text(material),
        "mitsuba_xml": _scene_file(mitsuba_xml(model, name), name),
        "gltf": _json_text(gltf_material(to_metal_roughness(model), name)),
    }
    if native:
        texts["mitsuba_json"] = _json_text(mitsuba_dict(model))
    paths: dict[str, Path] = {}
    for kind, text in texts.items():
        paths[kind] = out / FILES[kind]
        _write_text(paths[kind], text)
    if merl:
        # write_merl writes beside the target and renames, like atomic_path.
        paths["merl"] = out / FILES["merl"]
        write_merl(MerlTable.from_model(model), paths["merl"])
    return paths
