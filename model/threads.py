"""The thread pools' policy: numba's and OpenBLAS's workers sleep between calls instead of spinning.

By default the OpenMP runtime behind numba's ``omp`` threading layer (libgomp) spins its workers after
each parallel call, and OpenBLAS runs one spinning thread per core. On a shared or loaded machine the
spinning threads take the cores from whatever runs next. Measured on a 2-vCPU EPYC at load average 8-10
(shared), with the kernel and a 30000 x 6 SVD (the fits' size) alternating: the 10k-pair GGX evaluation
took a median 7-27 ms with the defaults and 1.5-8 ms under this policy, the SVD 42-88 ms and 7-16 ms.

:func:`apply_thread_policy` is the one place this is set. ``model/__init__.py`` runs it before
anything else, and so does every entry point before it imports numpy (``gonio/__init__.py``,
``acquisition/__init__.py``, ``bench/__init__.py``, ``tests/conftest.py``). It sets, unless the user's
environment already does (that always wins):

- ``OMP_WAIT_POLICY=PASSIVE`` (libgomp's spin count 0; ``KMP_BLOCKTIME=0`` for Intel's runtime): read
  when the runtime loads, which is numba's first parallel launch, so the lazily imported numba kernels
  always see it. numba keeps one thread per core (fewer under ``OMP_NUM_THREADS``, below) and its own
  layer order (tbb, omp, workqueue; the workqueue layer waits on a condition variable, it does not spin).
- ``OPENBLAS_NUM_THREADS=1`` for the BLAS libraries loaded later (scipy's own OpenBLAS loads with
  ``scipy.linalg``), and the same limit through threadpoolctl on those already loaded (numpy's, if
  numpy came first): gonio's linear algebra is small (fits, calibrations), where a second thread costs
  more in wake-ups than it gains.

- ``NUMBA_NUM_THREADS`` from ``OMP_NUM_THREADS`` where only the latter is set, and Dr.Jit's pool to the
  same count (:func:`drjit_thread_budget`, applied where gonio loads Mitsuba): ``OMP_NUM_THREADS`` is the
  usual way to give a process its share of the cores, and Dask's nanny sets it to 1 in every worker it
  starts, but numba and Dr.Jit size their pools by the core count and ignore it. Two single-threaded Dask
  workers on 2 cores then ran 2 numba and 2 Dr.Jit threads each: 8 threads taking turns on 2 cores.

Subprocesses (dask workers, ``gonio`` commands run by tests) inherit the environment, hence the policy.
"""

from __future__ import annotations

import os
from typing import Any

#: What the policy sets where the environment does not already say otherwise.
POLICY_ENV: dict[str, str] = {"OMP_WAIT_POLICY": "PASSIVE", "KMP_BLOCKTIME": "0", "OPENBLAS_NUM_THREADS": "1"}

_state: dict[str, Any] = {}


def apply_thread_policy() -> None:
    """Set the passive wait policy and the BLAS thread count (idempotent; the user's environment wins)."""
    if _state:
        return
    # Which OpenMP runtimes were loaded before the policy: they read OMP_WAIT_POLICY at load, too early.
    _state["openmp_loaded_before"] = [lib["filepath"] for lib in _threadpool_info("openmp")]
    _state["user_set"] = sorted(k for k in POLICY_ENV if k in os.environ)
    for key, value in POLICY_ENV.items():
        os.environ.setdefault(key, value)
    budget = _int_env("OMP_NUM_THREADS")
    if budget is not None and "NUMBA_NUM_THREADS" not in os.environ:
        # Read when numba.core.config is imported; numba imported earlier keeps its pool.
        os.environ["NUMBA_NUM_THREADS"] = str(budget)
    blas_threads = _int_env("OPENBLAS_NUM_THREADS")
    if blas_threads is not None:
        from threadpoolctl import threadpool_limits

        # Applied for good (not as a context): the returned object would only restore the old limits.
        threadpool_limits(limits=blas_threads, user_api="blas")


def drjit_thread_budget() -> int | None:
    """Cap Dr.Jit's thread pool at ``OMP_NUM_THREADS`` where that is set; the cap (threads) or None."""
    budget = _int_env("OMP_NUM_THREADS")
    if budget is not None:
        import drjit as dr

        if dr.thread_count() > budget:
            dr.set_thread_count(budget)
    return budget


def thread_policy_info() -> dict[str, Any]:
    """The policy as it stands: the environment, the OpenMP runtimes loaded too early, each BLAS's threads."""
    apply_thread_policy()
    return {
        "env": {key: os.environ.get(key) for key in POLICY_ENV},
        "user_set": list(_state["user_set"]),
        "openmp_loaded_before": list(_state["openmp_loaded_before"]),
        "blas": [
            {"internal_api": lib["internal_api"], "num_threads": lib["num_threads"], "filepath": lib["filepath"]}
            for lib in _threadpool_info("blas")
        ],
    }


def _threadpool_info(user_api: str) -> list[dict[str, Any]]:
    """threadpoolctl's description of the loaded libraries of one kind ("blas" or "openmp")."""
    from threadpoolctl import threadpool_info

    return [lib for lib in threadpool_info() if lib.get("user_api") == user_api]


def _int_env(key: str) -> int | None:
    """A positive thread count from the environment, or None where it is unset or not one."""
    try:
        n = int(os.environ.get(key, ""))
    except ValueError:
        return None
    return n if n > 0 else None


# On import, so that importing model (or any entry point, see above) is what sets it.
apply_thread_policy()
