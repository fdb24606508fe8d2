"""The thread pools' policy (model/threads.py) is in effect in a fresh interpreter, whatever came first.

Each case runs in its own interpreter, because the policy has to be in place before the OpenMP runtime
and OpenBLAS start, which happens once per process. libgomp itself reports the wait policy it took
(OMP_DISPLAY_ENV), so the check is the runtime's own word, not only our environment.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from model import threads

ROOT = Path(__file__).resolve().parents[2]
# Generous: a cold interpreter imports numpy, scipy and numba and may compile the kernel on a loaded host.
TIMEOUT_S = 600

REPORT = """
import json, numba, numpy as np
from model import threads
from model.cook_torrance import CookTorrance, KERNEL_MIN_PAIRS
z = np.tile([0.0, 0.6, 0.8], (KERNEL_MIN_PAIRS, 1))
CookTorrance(alpha=0.3).eval(z, z)  # a parallel launch: loads the threading layer's runtime
info = threads.thread_policy_info()
info["layer"] = numba.threading_layer()
from threadpoolctl import threadpool_info
info["openmp"] = [lib["filepath"] for lib in threadpool_info() if lib["user_api"] == "openmp"]
print("REPORT " + json.dumps(info))
"""


def _run(code: str, **env: str) -> tuple[dict, str]:
    own = {*threads.POLICY_ENV, "NUMBA_THREADING_LAYER", "OMP_NUM_THREADS", "NUMBA_NUM_THREADS"}
    base = {k: v for k, v in os.environ.items() if k not in own}
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env={**base, "OMP_DISPLAY_ENV": "TRUE", **env},
        capture_output=True, text=True, timeout=TIMEOUT_S, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    line = next(x for x in proc.stdout.splitlines() if x.startswith("REPORT "))
    return json.loads(line.removeprefix("REPORT ")), proc.stderr


def _check_policy(info: dict, stderr: str) -> None:
    assert info["env"] == threads.POLICY_ENV
    assert info["blas"], "numpy's BLAS was not found"
    assert all(lib["num_threads"] == 1 for lib in info["blas"]), info["blas"]
    assert info["openmp_loaded_before"] == []
    assert info["layer"] in ("omp", "workqueue", "tbb")
    if info["layer"] == "omp":
        assert info["openmp"], "numba's omp layer ran but no OpenMP runtime is loaded"
        # libgomp's own account of the settings it started with (printed at its initialisation).
        assert "OMP_WAIT_POLICY = 'PASSIVE'" in stderr, stderr


@pytest.mark.slow
def test_importing_model_sets_the_policy_before_the_pools_start():
    info, stderr = _run("import model\n" + REPORT)
    _check_policy(info, stderr)
    assert info["user_set"] == []


@pytest.mark.slow
def test_numpy_and_scipy_imported_first_still_run_blas_on_one_thread():
    # numpy's OpenBLAS is running before the policy (threadpoolctl limits it); scipy's loads after.
    info, stderr = _run("import numpy, scipy.linalg\nimport gonio\n" + REPORT)
    _check_policy(info, stderr)
    assert len({lib["filepath"] for lib in info["blas"]}) >= 2, info["blas"]  # numpy's and scipy's own


@pytest.mark.slow
def test_the_users_environment_wins():
    info, stderr = _run("import acquisition\n" + REPORT, OMP_WAIT_POLICY="ACTIVE", OPENBLAS_NUM_THREADS="2")
    assert info["env"]["OMP_WAIT_POLICY"] == "ACTIVE" and info["env"]["OPENBLAS_NUM_THREADS"] == "2"
    assert info["user_set"] == ["OMP_WAIT_POLICY", "OPENBLAS_NUM_THREADS"]
    assert all(lib["num_threads"] == 2 for lib in info["blas"]), info["blas"]
    if info["layer"] == "omp":
        assert "OMP_WAIT_POLICY = 'ACTIVE'" in stderr, stderr


def test_this_process_runs_under_the_policy():
    # The test session itself: tests/conftest.py imports model.threads before any test runs.
    info = threads.thread_policy_info()
    for key, value in threads.POLICY_ENV.items():
        assert info["env"][key] == os.environ.get(key, value)
    if "OPENBLAS_NUM_THREADS" not in info["user_set"]:
        assert all(lib["num_threads"] == 1 for lib in info["blas"]), info["blas"]


POOLS = """
import json
import model, numba
import drjit as dr
import model.mitsuba.variant
print("REPORT " + json.dumps({"numba": numba.config.NUMBA_NUM_THREADS, "drjit": dr.thread_count()}))
"""


@pytest.mark.slow
@pytest.mark.mitsuba
def test_omp_num_threads_caps_numbas_and_drjits_pools_too():
    # What Dask's nanny sets in every worker; numba and Dr.Jit would size their pools by the cores.
    info, _ = _run(POOLS, OMP_NUM_THREADS="1")
    assert info["numba"] == 1 and info["drjit"] == 1, info
    info, _ = _run(POOLS, OMP_NUM_THREADS="1", NUMBA_NUM_THREADS="2")  # the user's own setting wins
    assert info["numba"] == 2, info
    info, _ = _run(POOLS)  # without it, both pools are as wide as the machine
    assert info["numba"] == os.cpu_count() and info["drjit"] == os.cpu_count(), info
