"""What ``gonio run`` on the simulated servo rig imports before its first reading: only what a run needs.

Every import is paid before the first reading (``bench/first_reading.py``), so what serves something else (DNG
files, saved images, the GRBL simulator, the analysis, plots, Parquet) is imported where it is used. Checked
in a fresh interpreter, by the modules present, not by a time.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# Everything the run's command, session, runner and simulated rig import, and the simulated rig's spec built
# from the example rig file (what `gonio run` does before it opens the rig).
PROBE = f"""
import json, sys
import gonio.cli, gonio.cli_run, rig.run.session, rig.run.measuring.runner, simulator.backend, simulator.rig
from rig.run.config.files import load_rig
from simulator.from_config import rig_from
rig = load_rig({str(ROOT / "examples" / "rig_simulated.toml")!r})
rig_from(rig)  # the unstarted rig: what opening it imports, without starting a bus or a render
print(json.dumps(sorted(sys.modules)))
"""

NOT_BEFORE_THE_FIRST_READING = {
    "tifffile": "DNG files (a camera that writes them)",
    "rawpy": "DNG files",
    "OpenEXR": "saved images (--save-images)",
    "simulator.grbl_rig": "the GRBL simulator (a rig file with [simulation] link = 'grbl')",
    "simulator.grbl": "the GRBL simulator",
    "rig.instrument.links.grbl": "a GRBL link",
    "pyarrow": "samples.parquet, written at the end",
    "matplotlib": "plots",
    "analysis": "gonio analyze",
    "dask": "gonio batch",
    "cv2": "the calibration board's detection",
    "numba": "the HDR merge's compiled passes (images larger than an ROI crop)",
    "scipy": "numba's array functions (and analysis)",
}


def test_a_simulated_servo_run_imports_nothing_it_does_not_need_before_its_first_reading() -> None:
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    loaded = set(json.loads(out.stdout.strip().splitlines()[-1]))
    assert "rig.run.measuring.runner" in loaded and "simulator.rig" in loaded  # the probe did import the run
    early = {m: why for m, why in NOT_BEFORE_THE_FIRST_READING.items() if m in loaded}
    assert not early, f"imported before the first reading, though only needed for: {early}"


# A short simulated run on ROI crops, through the command: its merges run in numpy, so numba never loads (its
# import and start-up would come before the first reading). An empty numba cache: nothing compiles.
RUN = f"""
import json, sys
from gonio.cli import main
sweep, out = sys.argv[1], sys.argv[2]
code = main(["run", sweep, "--rig", {str(ROOT / "examples" / "rig_simulated.toml")!r}, "--out", out, "--quiet"])
print(json.dumps([code, sorted(m for m in sys.modules if m.split(".")[0] in ("numba", "llvmlite", "scipy"))]))
"""


def test_a_short_simulated_run_on_roi_crops_never_imports_numba(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep.toml"
    sweep.write_text('name = "short"\n[sweep]\nkind = "grid"\ntheta_i_deg = [30.0]\ntheta_o_deg = [20.0, 40.0]\n'
                     'phi_o_deg = [180.0]\nisotropic = true\n[capture]\ntarget_snr = 100.0\n')  # fmt: skip
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba"), "HOME": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", RUN, str(sweep), str(tmp_path / "run")], capture_output=True,
                         text=True, cwd=ROOT, timeout=600, env=env)  # fmt: skip
    assert out.returncode == 0, out.stderr[-3000:]
    code, loaded = json.loads(out.stdout.strip().splitlines()[-1])
    assert code == 0 and (tmp_path / "run" / "journal.jsonl").exists()
    assert loaded == [], f"a run on ROI crops imported {loaded}"
    assert "compiling kernels" not in out.stderr
