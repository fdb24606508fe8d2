"""A whole glTF 2.0 asset of a fitted material: a square sample patch wearing it, which any glTF viewer opens.

A material object alone (``gltf_material.json``) is something to paste into an asset; ``material.gltf`` is an
asset: one scene, one node, one mesh (two triangles, a patch :data:`PATCH_SIZE_M` on a side in the x-z
plane, facing +y, glTF's up), its positions, normals and texture coordinates in one buffer embedded as a
base64 data URI (so the file travels alone), and the metal-roughness material with the projection's error
in its extras. Lengths in metres, as glTF defines them.
"""

from __future__ import annotations

import base64
import struct
from collections.abc import Sequence
from typing import Any

from model.version import gonio_version

#: Side of the sample patch (m): the rig's default sample size.
PATCH_SIZE_M = 0.05
#: glTF constants (glTF 2.0 specification, accessor component types, buffer view targets, primitive modes).
FLOAT, UNSIGNED_SHORT = 5126, 5123
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
TRIANGLES = 4
DATA_URI_PREFIX = "data:application/octet-stream;base64,"


def _pack(fmt: str, rows: Sequence[Sequence[float]]) -> bytes:
    return b"".join(struct.pack("<" + fmt, *r) for r in rows)


def gltf_asset(material: dict[str, Any], *, size_m: float = PATCH_SIZE_M) -> dict[str, Any]:
    """A glTF 2.0 asset (JSON document) of a ``size_m`` square patch with ``material`` (a glTF material object)."""
    if not size_m > 0:
        raise ValueError(f"gltf_asset: size_m = {size_m!r}; expected a positive length in metres")
    h = size_m / 2.0
    positions = [(-h, 0.0, h), (h, 0.0, h), (h, 0.0, -h), (-h, 0.0, -h)]
    normals = [(0.0, 1.0, 0.0)] * 4
    uvs = [(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)]
    indices = [(0, 1, 2), (0, 2, 3)]  # counter-clockwise seen from +y: the front face
    chunks = [_pack("3f", positions), _pack("3f", normals), _pack("2f", uvs), _pack("3H", indices)]
    views, offset = [], 0
    for i, chunk in enumerate(chunks):
        target = ELEMENT_ARRAY_BUFFER if i == 3 else ARRAY_BUFFER
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(chunk), "target": target})
        offset += len(chunk)  # every chunk is a multiple of 4 bytes but the last, so alignment holds
    data = b"".join(chunks)
    accessors = [
        {"bufferView": 0, "componentType": FLOAT, "count": 4, "type": "VEC3",
         "min": [-h, 0.0, -h], "max": [h, 0.0, h]},
        {"bufferView": 1, "componentType": FLOAT, "count": 4, "type": "VEC3"},
        {"bufferView": 2, "componentType": FLOAT, "count": 4, "type": "VEC2"},
        {"bufferView": 3, "componentType": UNSIGNED_SHORT, "count": 6, "type": "SCALAR"},
    ]  # fmt: skip
    name = str(material.get("name", "material"))
    return {
        "asset": {"version": "2.0", "generator": f"gonio {gonio_version()}"},
        "scene": 0,
        "scenes": [{"name": name, "nodes": [0]}],
        "nodes": [{"name": f"{name} sample", "mesh": 0}],
        "meshes": [{"name": f"{name} patch", "primitives": [{
            "attributes": {"POSITION": 0, "NORMAL": 1, "TEXCOORD_0": 2}, "indices": 3, "material": 0,
            "mode": TRIANGLES,
        }]}],
        "materials": [material],
        "accessors": accessors,
        "bufferViews": views,
        "buffers": [{"byteLength": len(data), "uri": DATA_URI_PREFIX + base64.b64encode(data).decode("ascii")}],
    }  # fmt: skip
