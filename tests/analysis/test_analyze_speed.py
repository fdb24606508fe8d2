"""What keeps ``gonio analyze`` quick, checked by what it does rather than by timing it: which modules it loads
(in a fresh interpreter, through sys.modules), that numba is not loaded for a one-off evaluation, and that a standby
draws with the collector paused. The forked calls themselves are tested with model/runtime.py."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
#: Modules an analysis of an existing table has no use for before it draws or exports: the measuring side of a run
#: (its runner, planner, HDR merge and numba behind it), the image library, plots, Mitsuba, progress bars. (Reading a
#: run's rig file loads the backend it names, as every rig file does: that module is cheap by design.)
NOT_NEEDED = ("numba", "matplotlib", "mitsuba", "drjit", "OpenEXR", "tqdm", "asyncio", "cv2", "acquisition.hdr",
              "acquisition.flatfield", "rig.run.measuring.runner", "rig.run.measuring.measure", "rig.run.calibrate",
              "rig.run.planning.plan", "model.kernels")  # fmt: skip


def loaded_after(code: str) -> list[str]:
    """The NOT_NEEDED modules (or their submodules) loaded after ``code`` runs in a fresh interpreter."""
    probe = (f"{code}\nimport json, sys\nprint(json.dumps(sorted(m for m in sys.modules if any(m == n or "
             f"m.startswith(n + '.') for n in {NOT_NEEDED!r}))))")  # fmt: skip
    done = subprocess.run([sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return list(json.loads(done.stdout.splitlines()[-1]))


def test_the_analyze_command_imports_nothing_it_does_not_need() -> None:
    loaded = loaded_after("import gonio.cli, gonio.cli_analyze, analysis.analyze, analysis.ladder, "
                          "analysis.batch.records")  # fmt: skip
    assert loaded == [], f"imported before any analysis: {loaded}"


def test_a_one_off_evaluation_stays_in_numpy_and_a_long_one_loads_the_kernel() -> None:
    code = """
import sys
import numpy as np
from model import CookTorrance, cook_torrance
from model.base import Model
rng = np.random.default_rng(0)
v = rng.normal(size=(2, 65536, 3)); v[..., 2] = np.abs(v[..., 2]); v /= np.linalg.norm(v, axis=-1, keepdims=True)
m = CookTorrance(alpha=0.2, fresnel="conductor", eta=(0.2, 0.4, 1.4), k=(3.4, 2.4, 1.8))
f = m.eval(v[0], v[1])
assert "numba" not in sys.modules and "model.kernels" not in sys.modules
for _ in range(cook_torrance.KERNEL_LOAD_PAIRS // 65536 + 1):
    g = m.eval(v[0], v[1])
assert "model.kernels" in sys.modules
np.testing.assert_array_equal(g, f)  # the kernel agrees with numpy to the last bit (GGX)
np.testing.assert_array_equal(m.eval(v[0], v[1]), Model.eval(m, v[0], v[1]))
"""
    done = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr


DRAWS_IN_A_STANDBY = """
import gc
from model.runtime import Standby
from analysis.figure_pool import run_draws
with Standby(lambda: None) as standby:
    standby.run(lambda: (gc.isenabled(), run_draws([gc.isenabled, gc.isenabled], 2, lambda _: None)))
    assert standby.result() == (False, [False, False])
assert gc.isenabled()
print("ok")
"""


def test_a_standbys_call_and_the_draws_it_forks_run_with_the_collector_paused() -> None:
    # The standby's one call runs with the collector paused (its garbage ends with the process), and so does a draw
    # forked from it; the caller's collector is untouched.
    done = subprocess.run([sys.executable, "-c", DRAWS_IN_A_STANDBY], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)  # fmt: skip
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


FIT_AND_PICKLE = """
import sys, cloudpickle
from analysis.analyze import load_and_fit
from analysis.ladder import parse_models
from model import CookTorrance
from model.merl import MerlTable, write_merl
write_merl(MerlTable.from_model(CookTorrance(alpha=0.2, fresnel="dielectric", eta=1.5, rho_d=(0.2, 0.3, 0.4))),
           sys.argv[1] + "/plastic.binary")
a = load_and_fit(sys.argv[1] + "/plastic.binary", models=parse_models("lambert,lambert_ggx"), samples=400)
open(sys.argv[1] + "/analysis.pickle", "wb").write(cloudpickle.dumps(a))
"""
DRAW_WITHOUT_SCIPY = """
import pickle, sys
import analysis.report.html, analysis.report.plots
from analysis.report.plots import write_figures
assert not [m for m in sys.modules if m.split(".")[0] == "scipy"], "the figures' modules loaded scipy"
a = pickle.loads(open(sys.argv[1] + "/analysis.pickle", "rb").read())
figures = write_figures(a, sys.argv[1] + "/figures", jobs=1)
print(len(figures.files), sorted(m for m in sys.modules if m.split(".")[0] == "scipy"))
"""


def test_the_figures_are_drawn_without_scipy(tmp_path: Path) -> None:
    # gonio analyze forks its figures' process before loading scipy (a costly import), so that process loads matplotlib
    # while the main one loads scipy: that holds only while reading a fit's results and drawing them need no scipy.
    fitted = subprocess.run([sys.executable, "-c", FIT_AND_PICKLE, str(tmp_path)], cwd=ROOT, capture_output=True,
                            text=True, timeout=600)  # fmt: skip
    assert fitted.returncode == 0, fitted.stderr
    drawn = subprocess.run([sys.executable, "-c", DRAW_WITHOUT_SCIPY, str(tmp_path)], cwd=ROOT, capture_output=True,
                           text=True, timeout=600)  # fmt: skip
    assert drawn.returncode == 0, drawn.stderr
    count, loaded = drawn.stdout.split(maxsplit=1)
    assert int(count) >= 5 and loaded.strip() == "[]", drawn.stdout
    assert sorted(p.suffix for p in (tmp_path / "figures").iterdir()) == [".png"] * int(count)
