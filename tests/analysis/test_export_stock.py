"""The stock-Mitsuba exports load and render in a Python that has Mitsuba but no gonio, and their stated error is
the error that Mitsuba shows there.

The child process runs with ``-I -S`` (no site, no user site, no PYTHONPATH, no cwd on sys.path) and only the
directory that holds mitsuba and drjit put on its path, in the export directory as its cwd; it checks that none of
gonio's packages can be imported, then loads ``mitsuba_scene.xml`` (which includes ``mitsuba_bsdf.xml``) and
``mitsuba_bsdf.json``, renders the scene and evaluates both BSDFs on the error grid.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import mitsuba as mi
import numpy as np
import pytest

from analysis.export import export_material
from model import CookTorrance, Lambert
from model.base import BRDF
from model.mitsuba.projection import grid_pairs
from model.serialize import from_json_dict

pytestmark = pytest.mark.mitsuba

CHILD = r"""
import importlib.util, json, sys
import numpy as np
for pkg in ("model", "analysis", "rig", "acquisition", "simulator", "gonio"):
    assert importlib.util.find_spec(pkg) is None, f"{pkg} is importable: the process is not clean"
import drjit as dr
import mitsuba as mi
mi.set_variant("scalar_rgb")
scene = mi.load_file("mitsuba_scene.xml")
image = np.array(mi.render(scene), dtype=np.float64)
from_xml = scene.shapes()[0].bsdf()
from_json = mi.load_dict(json.load(open("mitsuba_bsdf.json")))
wi, wo = np.load(sys.argv[1]), np.load(sys.argv[2])
ctx, out = mi.BSDFContext(), {"xml": [], "json": []}
for a, b in zip(wo, wi):  # radiance mode: si.wi is the camera (the model's wo), wo the light
    si = dr.zeros(mi.SurfaceInteraction3f)
    si.wi = mi.Vector3f(*(float(x) for x in a))
    for key, bsdf in (("xml", from_xml), ("json", from_json)):
        value = bsdf.eval(ctx, si, mi.Vector3f(*(float(x) for x in b)))
        out[key].append([float(x) / max(float(b[2]), 1e-12) for x in value])
try:
    mi.load_file("mitsuba_gonio_plugin.xml")
    refusal = None
except Exception as exc:
    refusal = str(exc)
np.save("child_xml.npy", np.array(out["xml"]))
np.save("child_json.npy", np.array(out["json"]))
print(json.dumps({"image_mean": float(image.mean()), "image_finite": bool(np.isfinite(image).all()),
                  "image_lit": float((image.max(axis=-1) > 0).mean()), "refusal": refusal}))
"""

#: The usual choice of the ladder (Lambert plus GGX, Schlick Fresnel: no stock plugin) and a native one.
CASES: dict[str, BRDF] = {
    "lambert_ggx_schlick": CookTorrance(alpha=0.2, fresnel="schlick", f0=0.04, rho_d=(0.5, 0.4, 0.2)),
    "lambert": Lambert(rho_d=(0.8, 0.5, 0.2)),
}


def run_clean(directory: Path) -> dict[str, object]:
    wi, wo = grid_pairs((0.0,))
    np.save(directory / "wi.npy", wi)
    np.save(directory / "wo.npy", wo)
    site = str(Path(mi.__file__).resolve().parent.parent)
    code = f"import sys; sys.path.insert(0, {site!r})\n" + CHILD
    done = subprocess.run([sys.executable, "-I", "-S", "-c", code, "wi.npy", "wo.npy"], cwd=directory,
                          capture_output=True, text=True, timeout=600, env={"PATH": "/usr/bin:/bin"})  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    result: dict[str, object] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


@pytest.mark.parametrize("case", sorted(CASES))
def test_stock_export_renders_without_gonio_and_its_stated_error_holds(case: str, tmp_path: Path) -> None:
    m = CASES[case]
    paths = export_material(m, tmp_path, name="sample", gonio_plugin=True)
    child = run_clean(tmp_path)
    assert child["image_finite"] and float(child["image_mean"]) > 0 and float(child["image_lit"]) > 0.05  # type: ignore[arg-type]
    xml, js = np.load(tmp_path / "child_xml.npy"), np.load(tmp_path / "child_json.npy")
    np.testing.assert_array_equal(xml, js)
    stock = json.loads(paths["material"].read_text())["facts"]["mitsuba_stock"]
    wi, wo = grid_pairs((0.0,))
    # What stock Mitsuba evaluates is the Mitsuba form of the stated native model, to float32 rounding ...
    native = from_json_dict(stock["native_model"])
    np.testing.assert_allclose(xml, np.broadcast_to(native.eval(wi, wo), xml.shape), rtol=2e-4, atol=1e-7)
    # ... and its difference from the exported model on this slice of the grid is the one stated for the grid
    # (isotropic models: every phi_i slice is the same), to the rounding of float32 in another variant.
    f = np.broadcast_to(np.asarray(m.eval(wi, wo)).reshape(len(wi), -1), xml.shape)
    rms = float(np.sqrt(np.sum((xml - f) ** 2) / np.sum(f**2)))
    assert rms == pytest.approx(stock["error"]["rms_rel"], rel=1e-3, abs=1e-6)
    if stock["exact"]:
        assert rms < 1e-5 and "mitsuba_plugin_xml" not in paths
        assert child["refusal"] is not None  # no plugin file was written: nothing to load
    else:
        assert 0.005 < rms < 0.1  # a real projection, and a close one for the usual Lambert + GGX choice
        assert "gonio_model" in str(child["refusal"])  # the plugin form is refused by stock Mitsuba, as documented
