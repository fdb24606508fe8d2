"""The process's plumbing (model/runtime.py): the thread pools' policy is in effect in a fresh interpreter, whatever
came first; work handed to a forked child comes back (result, exception, or done here when the child dies); the
collector is paused where asked and a caller's pause is kept; a costly module loads once enough work was done.

Each thread-policy case runs in its own interpreter, because the policy has to be in place before the OpenMP runtime
and OpenBLAS start, which happens once per process. libgomp itself reports the wait policy it took
(OMP_DISPLAY_ENV), so the check is the runtime's own word, not only our environment.
"""

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from model import runtime
from model.runtime import CollectorPause, ForkedCall, Standby, load_due, without_gc

ROOT = Path(__file__).resolve().parents[2]
# Generous: a cold interpreter imports numpy, scipy and numba and may compile the kernel on a loaded host.
TIMEOUT_S = 600

REPORT = """
import json, numba, numpy as np
from model import runtime
from model.cook_torrance import CookTorrance, KERNEL_MIN_PAIRS
z = np.tile([0.0, 0.6, 0.8], (KERNEL_MIN_PAIRS, 1))
CookTorrance(alpha=0.3).eval(z, z)  # a parallel launch: loads the threading layer's runtime
info = runtime.thread_policy_info()
info["layer"] = numba.threading_layer()
from threadpoolctl import threadpool_info
info["openmp"] = [lib["filepath"] for lib in threadpool_info() if lib["user_api"] == "openmp"]
print("REPORT " + json.dumps(info))
"""


def _run(code: str, **env: str) -> tuple[dict, str]:
    own = {*runtime.POLICY_ENV, "NUMBA_THREADING_LAYER", "OMP_NUM_THREADS", "NUMBA_NUM_THREADS"}
    base = {k: v for k, v in os.environ.items() if k not in own}
    proc = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env={**base, "OMP_DISPLAY_ENV": "TRUE", **env},
        capture_output=True, text=True, timeout=TIMEOUT_S, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    line = next(x for x in proc.stdout.splitlines() if x.startswith("REPORT "))
    return json.loads(line.removeprefix("REPORT ")), proc.stderr


def _check_policy(info: dict, stderr: str) -> None:
    assert info["env"] == runtime.POLICY_ENV
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
    # The test session itself: tests/conftest.py imports model.runtime before any test runs.
    info = runtime.thread_policy_info()
    for key, value in runtime.POLICY_ENV.items():
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


FORKED = """
import os, sys
from model.runtime import ForkedCall, Standby
parent = os.getpid()
with ForkedCall(lambda: (os.getpid(), sorted(range(5))), fork=True) as call:
    assert call.forked
    pid, value = call.result()
assert pid != parent and value == [0, 1, 2, 3, 4]
def fail():
    raise ValueError("export: no such model")
with ForkedCall(fail, fork=True) as call:
    try:
        call.result()
    except ValueError as exc:
        assert "no such model" in str(exc)
    else:
        raise AssertionError("the child's exception was not raised here")
# A child that dies without answering: the call is made here instead.
with ForkedCall(lambda: os._exit(3) if os.getpid() != parent else "done here", fork=True) as call:
    assert call.result() == "done here"
# A standby loads first, then runs a call it is handed later: a closure plain pickle refuses (cloudpickle does not).
with Standby(lambda: os.environ.__setitem__("PREPARED_IN", str(os.getpid()))) as standby:
    assert standby.forked
    scale = 3
    standby.run(lambda: (os.environ.get("PREPARED_IN"), os.getpid(), [scale * i for i in range(3)]))
    prepared_in, ran_in, value = standby.result()
assert prepared_in == str(ran_in) and ran_in != parent and value == [0, 3, 6] and "PREPARED_IN" not in os.environ
with Standby(lambda: None) as standby:
    pass  # closed without work: the standby ends by itself
# The standby's one call runs with the collector paused (its garbage ends with the process).
import gc
with Standby(lambda: None) as standby:
    standby.run(gc.isenabled)
    assert standby.result() is False
assert gc.isenabled()
print("ok")
"""


def test_forked_calls_return_their_result_raise_their_error_and_survive_a_dead_child() -> None:
    done = subprocess.run([sys.executable, "-c", FORKED], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr


def test_a_forked_call_runs_here_when_forking_is_not_safe() -> None:
    stop = threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        with ForkedCall(os.getpid, fork=True) as call:
            assert not call.forked
            assert call.result() == os.getpid()
    finally:
        stop.set()
        other.join()
    with ForkedCall(os.getpid, fork=False) as call:
        assert not call.forked and call.result() == os.getpid()
    with pytest.raises(ZeroDivisionError), ForkedCall(lambda: 1 / 0, fork=False) as call:
        call.result()
    stop.clear()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        with Standby(lambda: None) as standby:
            assert not standby.forked
            standby.run(os.getpid)
            assert standby.result() == os.getpid()
    finally:
        stop.set()
        other.join()


def test_a_figure_is_drawn_with_the_collector_paused_and_its_cycles_freed_after() -> None:
    import gc
    import weakref

    class Node:
        me: object = None

    seen: list[bool] = []
    refs: list[weakref.ref[Node]] = []

    def draw() -> int:
        seen.append(gc.isenabled())
        node = Node()
        node.me = node  # a reference cycle, as a figure's artists make: only the collector frees it
        refs.append(weakref.ref(node))
        return 7

    assert gc.isenabled()
    assert without_gc(draw) == 7 and seen == [False] and gc.isenabled() and refs[0]() is None
    gc.disable()
    try:
        assert without_gc(draw) == 7 and not gc.isenabled()  # a caller's paused collector stays paused
    finally:
        gc.enable()


def test_a_paused_collector_resumes_once_early_or_at_the_end() -> None:
    import gc

    assert gc.isenabled()
    with CollectorPause() as paused:
        assert not gc.isenabled()
        paused.resume()
        assert gc.isenabled()
        gc.disable()  # paused again by someone else after the resume: not undone by the block's end
    assert not gc.isenabled()
    gc.enable()
    with pytest.raises(ValueError), CollectorPause():
        raise ValueError("the block failed")
    assert gc.isenabled()
    gc.disable()
    try:
        with CollectorPause() as paused:
            paused.resume()
            assert not gc.isenabled()  # the caller's pause is kept
        assert not gc.isenabled()
    finally:
        gc.enable()


def test_a_costly_module_is_due_once_its_work_passes_the_budget(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(runtime, "_work_without", {})
    name = "gonio_test_not_a_module"
    assert not load_due(name, 60, 100) and not load_due(name, 40, 100)  # 100 done: not past the budget
    assert load_due(name, 1, 100) and load_due(name, 1, 100)
    assert not load_due(name + "_other", 60, 100)  # counted per module
    assert load_due("sys", 1, 10**9)  # loaded already: at once
