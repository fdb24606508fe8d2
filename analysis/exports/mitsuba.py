"""A fitted material for Mitsuba 3: stock plugins by default, gonio's exact plugin on request.

Stock form (what ``mitsuba_bsdf.xml`` / ``mitsuba_bsdf.json`` / ``mitsuba_scene.xml`` hold): the BSDF of
:func:`model.mitsuba.projection.native_projection`, built from Mitsuba's own plugins only (``diffuse``,
``roughconductor``, ``blendbsdf`` of those), so the files render in a Mitsuba 3 without gonio. Models that
map exactly keep that mapping; the others are projected onto the nearest diffuse + GGX roughconductor,
and the relative RMS difference (Mitsuba evaluating the native BSDF, gonio the model, over a fixed grid
of directions) is written into the XML's comments and the export's README.

Tabulated form (``material.bsdf`` with ``mitsuba_measured.xml`` / ``mitsuba_measured.json``): the model
tabulated in the RGL ``.bsdf`` format (:mod:`model.mitsuba.tabulated`) for stock Mitsuba's ``measured``
plugin, its error measured the same way (Mitsuba reading the file, on the same grid). For a model without a
native plugin, ``mitsuba_bsdf.*`` hold the projection where it is within 5 % RMS of the model (it needs no
side file), else whichever of the two is closer (analysis/exports/stock.py; the projection also stays under
``mitsuba_projection.*``).

Plugin form (``mitsuba_gonio_plugin.xml``, ``plugin=True``): the ``gonio_model`` plugin with the model's
JSON in ``model_json``: exact, but it renders only in a Python process that imported
``model.mitsuba.plugin`` under an rgb variant; stock Mitsuba says "Plugin gonio_model not found".
"""

from __future__ import annotations

from typing import Any
from xml.sax.saxutils import quoteattr

from model.base import BRDF
from model.merl import MerlTable
from model.mitsuba import plugin as gonio_plugin
from model.mitsuba.materials import to_mitsuba
from model.mitsuba.projection import NativeProjection, native_projection
from model.mitsuba.tabulated import Tabulated, measured_bsdf
from model.plain import jsonable

#: Mitsuba scene-format version written into standalone XML.
XML_VERSION = "3.0.0"
#: Plugins a nested dict may name to become a nested ``<bsdf>`` element.
BSDF_PLUGINS = frozenset({"diffuse", "roughconductor", "conductor", "blendbsdf", "measured", gonio_plugin.PLUGIN})
#: File the scene of :func:`scene_xml` includes (``analysis.exports.write.FILES["mitsuba_xml"]``).
BSDF_FILE = "mitsuba_bsdf.xml"
#: The RGL table the ``measured`` forms name, relative to the export directory (``FILES["tabulated"]``).
TABULATED_FILE = "material.bsdf"
#: Pixels on a side and samples per pixel of the preview scene.
SCENE_PIXELS = 128
SCENE_SPP = 16


def merl_refusal(model: BRDF) -> None:
    """Raise for a MERL table: it has no JSON form, and exports go through write_merl."""
    if isinstance(model, MerlTable):
        raise ValueError(
            f"MerlTable ({model.source or 'no source'}): Mitsuba has no MERL reader and a table has no JSON form; "
            "write it with model.write_merl, or render it inside gonio through model.mitsuba.materials.to_mitsuba"
        )


def mitsuba_dict(model: BRDF, *, plugin: bool = False, projection: NativeProjection | None = None) -> dict[str, Any]:
    """JSON-serialisable Mitsuba scene-dict entry of ``model``: stock plugins, or with ``plugin`` gonio's exact one.

    ``projection`` reuses a :func:`native_projection` already computed for ``model``. Native models give
    their exact native entry either way.
    """
    merl_refusal(model)
    mat = to_mitsuba(model)
    if mat.native:
        return jsonable(mat.bsdf, "bsdf")  # a copy of plain JSON values only
    if plugin:
        return jsonable(gonio_plugin.json_plugin_dict(model), "bsdf")
    return jsonable((projection or native_projection(model)).bsdf, "bsdf")


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


def error_words(e: dict[str, Any]) -> str:
    """How far a stock form is, in words: relative RMS, cosine weighted, worst, over how many pairs."""
    return (
        f"relative RMS BRDF difference {e['rms_rel']:.3%} (cosine weighted {e['rms_rel_cosine_weighted']:.3%}, "
        f"worst {e['worst_rel']:.2%}) over {e['pairs']} pairs"
    )


def tabulated_note(model: BRDF, table: Tabulated, error: dict[str, Any]) -> str:
    """One sentence: what the tabulated form is and how far it is from ``model`` (Mitsuba reading the file)."""
    return (
        f"{type(model).__name__} tabulated for stock Mitsuba's measured plugin in {TABULATED_FILE} "
        f"({table.summary()}): "
        f"{error_words(error)}, Mitsuba reading the file against gonio on a grid to 80 deg"
    )


def measured_xml(model: BRDF, name: str, table: Tabulated, error: dict[str, Any]) -> str:
    """Mitsuba 3 XML ``<bsdf id=name>`` of Mitsuba's ``measured`` plugin reading the table (beside the XML)."""
    notes = [
        f"gonio export: {tabulated_note(model, table, error)}",
        f"Mitsuba finds {TABULATED_FILE} through its file resolver: for a scene file in this directory (such as "
        "mitsuba_scene.xml) it does; from elsewhere, add this directory (mi.file_resolver().prepend(...)) or "
        "copy the table beside the scene. RGB table: Mitsuba's rgb variants only. The exact model: "
        "material.json (gonio), or mitsuba_gonio_plugin.xml where gonio is installed",
    ]
    lines = _xml_lines(measured_bsdf(TABULATED_FILE), "bsdf", f" id={quoteattr(name)}", "")
    lines[1:1] = ["    " + _comment(n) for n in notes]
    return "\n".join(lines) + "\n"


def stock_note(model: BRDF, projection: NativeProjection) -> str:
    """One sentence: how the stock-Mitsuba BSDF relates to ``model`` and how far it is (Mitsuba-evaluated)."""
    e = projection.error
    size = error_words(e)
    if projection.exact:
        return f"{type(model).__name__} maps exactly to stock Mitsuba ({projection.material.note}); measured {size}"
    # The projected model's own note ends in how exactly *it* maps (": exact"), which is not the point here.
    form = projection.material.note.rsplit(": ", 1)[0].removeprefix("native ")
    return (
        f"{type(model).__name__} has no stock Mitsuba plugin ({to_mitsuba(model).note}); this is the nearest "
        f"stock BSDF, a {form}, fitted to it: {size}, Mitsuba against gonio on a grid to 80 deg"
    )


def mitsuba_xml(
    model: BRDF,
    name: str = "material",
    *,
    version: str | None = None,
    plugin: bool = False,
    projection: NativeProjection | None = None,
) -> str:
    """Mitsuba 3 XML ``<bsdf id=name>`` of ``model``: stock plugins unless ``plugin``; ``version``: standalone."""
    merl_refusal(model)
    native = to_mitsuba(model).native
    attrs = f" id={quoteattr(name)}" + ("" if version is None else f" version={quoteattr(version)}")
    if plugin and not native:
        entry = mitsuba_dict(model, plugin=True)
        notes = [
            f"gonio export of {type(model).__name__}, exact: {to_mitsuba(model).note}",
            f"{gonio_plugin.PLUGIN} is gonio's Python plugin: this BSDF loads only in a Python process that "
            "imported model.mitsuba.plugin under an rgb variant; stock Mitsuba cannot render it. "
            f"{BSDF_FILE} holds the stock-Mitsuba form and its error.",
        ]
    else:
        projection = projection or native_projection(model)
        entry = mitsuba_dict(model, projection=projection)
        notes = [f"gonio export: {stock_note(model, projection)}"]
        if not projection.exact:
            notes.append("the exact model: material.json (gonio), or mitsuba_gonio_plugin.xml where gonio is installed")
    lines = _xml_lines(entry, "bsdf", attrs, "")
    lines[1:1] = ["    " + _comment(n) for n in notes]
    return "\n".join(lines) + "\n"


def scene_file(fragment: str, name: str) -> str:
    """The XML file: the element inside a versioned scene, so other scenes can include it."""
    body = "".join("    " + line + "\n" if line else "\n" for line in fragment.splitlines())
    use = f'include it in a <scene version="{XML_VERSION}"> with <include filename="{BSDF_FILE}"/>'
    return (
        '<?xml version="1.0" encoding="utf-8"?>\n'
        + _comment(f"{use}, then refer to the BSDF as <ref id=\"{name}\"/>") + "\n"
        + f'<scene version="{XML_VERSION}">\n{body}</scene>\n'
    )  # fmt: skip


def scene_xml(name: str, bsdf_file: str = BSDF_FILE) -> str:
    """A whole scene that renders the material in stock Mitsuba: a 5 cm patch under a point light, seen at 45 deg."""
    # Lengths in metres; the light at 30 deg incidence on the other side, so a glossy lobe shows.
    return f"""<?xml version="1.0" encoding="utf-8"?>
{_comment(f"preview of the exported material: mitsuba {bsdf_file.replace('bsdf.xml', 'scene.xml')} renders it")}
<scene version="{XML_VERSION}">
    <include filename={quoteattr(bsdf_file)}/>
    <integrator type="direct"/>
    <sensor type="perspective">
        <float name="fov" value="8"/>
        <transform name="to_world">
            <lookat origin="0, -0.5, 0.5" target="0, 0, 0" up="0, 0, 1"/>
        </transform>
        <sampler type="independent">
            <integer name="sample_count" value="{SCENE_SPP}"/>
        </sampler>
        <film type="hdrfilm">
            <integer name="width" value="{SCENE_PIXELS}"/>
            <integer name="height" value="{SCENE_PIXELS}"/>
            <rfilter type="box"/>
        </film>
    </sensor>
    <emitter type="point">
        <point name="position" x="0" y="0.35" z="0.606"/>
        <rgb name="intensity" value="1.0"/>
    </emitter>
    <shape type="rectangle">
        <transform name="to_world">
            <scale value="0.025"/>
        </transform>
        <ref id={quoteattr(name)}/>
    </shape>
</scene>
"""
