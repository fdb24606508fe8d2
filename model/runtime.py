"""The process's plumbing, each policy in one place: its thread pools, its forks, its garbage collector, and when a
heavy module is worth loading. It imports nothing of gonio's, so every layer may use it.

**Thread pools.** numba's and OpenBLAS's workers sleep between calls instead of spinning. By default the OpenMP
runtime behind numba's ``omp`` threading layer (libgomp) spins its workers after each parallel call, and OpenBLAS
runs one spinning thread per core. On a shared or loaded machine the spinning threads take the cores from whatever
runs next: with the kernel and a fit-sized SVD alternating, both ran several times quicker under this policy
(docs/benchmarks.md, model throughput).

:func:`apply_thread_policy` is the one place this is set. ``model/__init__.py`` runs it (by importing this module)
before anything else, and so does every entry point before it imports numpy (``gonio/__init__.py``,
``acquisition/__init__.py``, ``bench/__init__.py``, ``tests/conftest.py``). It sets, unless the user's environment
already does (that always wins):

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

**Forks.** A fork copies only the calling thread, so it is taken only when nothing else could be holding a lock the
child needs (:func:`fork_safe`): no thread but the main one (and tqdm's monitor), numba's thread pool never started
(its default workqueue layer is not fork-safe) and Mitsuba (LLVM's threads) not loaded. :class:`ForkedCall` runs one
call in a forked child and hands back its (pickled) result; :class:`Standby` is a child forked early to load what
its one call will need while this process works on. Where forking is not safe the call is made here; either way it
gives the same result. Forked children inherit the analysis as it is, nothing pickled but what they hand back.

**The garbage collector.** :class:`CollectorPause` pauses it around work that makes many objects that live on
(imports, a figure), whose passes would free nothing; :func:`imports_done` freezes a standby's imports for good.

**Late loads.** :func:`load_due` says when a module that costs a lot to load (numba) has become worth loading: at once
where it is loaded already, else once enough work has been done without it.

Every entry point imports this module first, so it loads nothing that is not loaded already (gc is built in):
threadpoolctl, multiprocessing, signal and cloudpickle are imported where they are used.
"""

from __future__ import annotations

import gc
import os
import sys
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from multiprocessing.connection import Connection
    from types import TracebackType

# --- thread pools -------------------------------------------------------------------------------------------------

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


# --- late loads ---------------------------------------------------------------------------------------------------

#: Work done in this process without each module, by the callers of load_due (a forked child inherits it).
_work_without: dict[str, int] = {}


def load_due(module: str, work: int, budget: int) -> bool:
    """Whether a call doing ``work`` units should load ``module``: yes where it is loaded, else once the work done
    without it (this call's included, counted per module in this process) exceeds ``budget`` units."""
    if module in sys.modules:
        return True
    done = _work_without.get(module, 0) + work
    _work_without[module] = done
    return done > budget


# --- the garbage collector ----------------------------------------------------------------------------------------


class CollectorPause:
    """The cyclic garbage collector paused from entry until :meth:`resume` or the block's end.

    A caller's paused collector stays paused. With ``collect_after``, resuming makes one young-generation pass, which
    frees the reference cycles the paused work left (a figure's artists) without walking every module's objects.
    """

    def __init__(self, collect_after: bool = False) -> None:
        self._collect_after = collect_after
        self._paused = False

    def __enter__(self) -> CollectorPause:
        self._paused = gc.isenabled()
        gc.disable()
        return self

    def resume(self) -> None:
        """End the pause now (before the block ends); nothing where the caller had paused it."""
        if self._paused:
            self._paused = False
            gc.enable()
            if self._collect_after:
                gc.collect(0)

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:  # fmt: skip
        self.resume()


def without_gc(fn: Callable[[], Any]) -> Any:
    """``fn()`` with the cyclic garbage collector paused, then one pass over what it allocated.

    A figure is tens of thousands of objects that live until it is saved: the collector's passes while it is built
    find nothing to free, and each full one walks every loaded module's objects too. One young-generation pass
    afterwards frees the figure's reference cycles.
    """
    with CollectorPause(collect_after=True):
        return fn()


def imports_done() -> None:
    """In a standby after its imports: freeze what they made, and leave the collector paused for the one call the
    standby runs before it ends (``gonio analyze`` pauses the collector while its processes import).

    An import is many objects that live as long as the process, so the collector's passes over them free nothing;
    frozen, later full passes skip them too. The call's own garbage ends with the process: a figure's reference
    cycles are freed by a pass over everything it allocated, which a process about to end need not make; the figure
    workers it forks inherit the paused collector (see :func:`without_gc`). Only for a forked process that ends with
    its work: frozen objects are never collected.
    """
    gc.freeze()
    gc.disable()


# --- forks --------------------------------------------------------------------------------------------------------


def fork_safe() -> bool:
    """Whether this process may fork workers now (see the module docstring)."""
    if not sys.platform.startswith("linux") or "mitsuba" in sys.modules:
        return False
    numba_parallel = sys.modules.get("numba.np.ufunc.parallel")
    if numba_parallel is not None and getattr(numba_parallel, "_is_initialized", True):
        return False
    main = threading.main_thread()
    monitor = sys.modules.get("tqdm._monitor")  # none runs unless tqdm is loaded (a quiet analysis never loads it)
    tmonitor = getattr(monitor, "TMonitor", ()) if monitor is not None else ()
    return all(t is main or isinstance(t, tmonitor) for t in threading.enumerate())


def _ended(*_: object) -> None:
    raise SystemExit(1)  # unwinds the call, so a pool it runs is shut down and its workers end with it


def _call_child(fn: Callable[[], Any], conn: Connection, parents: Connection) -> None:
    import signal

    parents.close()  # the parent's end: with it closed here, a parent that dies breaks the pipe, never blocks it
    # Ctrl-C reaches the whole process group: the parent handles it (and ends this child), not a second traceback.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _ended)
    try:
        answer: tuple[bool, Any] = (True, fn())
    except BaseException as exc:  # handed to the parent, which raises it
        answer = (False, exc)
    try:
        try:
            conn.send(answer)
        except (BrokenPipeError, OSError):
            pass  # the parent has gone or given up: nobody to tell
        except Exception:  # an exception that does not pickle: its type and message
            conn.send((False, RuntimeError(f"{type(answer[1]).__name__}: {answer[1]}")))
    finally:
        conn.close()


class ForkedCall:
    """``fn()`` begun in a forked child when ``fork`` is asked and safe (else run by :meth:`result`, here, then).

    The child's result (or exception) comes back pickled. A child that dies without a word (a signal, out of
    memory) has its call (or ``fallback``) run again here: gonio's writers are atomic, so what it left is whole or
    absent.
    """

    def __init__(self, fn: Callable[[], Any], fork: bool, fallback: Callable[[], Any] | None = None) -> None:
        self._fn = fn
        self._fallback = fallback or fn
        self._proc: Any = None
        self._conn: Connection | None = None
        if fork and fork_safe():
            import multiprocessing

            ctx = multiprocessing.get_context("fork")
            self._conn, child = ctx.Pipe(duplex=False)
            self._proc = ctx.Process(target=_call_child, args=(fn, child, self._conn), name="gonio-forked-call")
            self._proc.start()
            child.close()

    @property
    def forked(self) -> bool:
        """Whether a child runs the call."""
        return self._proc is not None

    def result(self) -> Any:
        """The call's result (waiting for the child, or calling it now); its exception is raised here."""
        if self._conn is None:
            return self._fn()
        try:
            answer = self._conn.recv()
        except EOFError:  # the child died before it answered
            answer = None
        finally:
            self.close()
        if answer is None:
            return self._fallback()
        ok, value = answer
        if not ok:
            raise value
        return value

    def close(self, wait: bool = True) -> None:
        """Wait for the child to end (ending it if it does not, or at once unless ``wait``), release the pipe."""
        if self._proc is not None:
            self._proc.join(timeout=1.0 if wait else 0.0)
            if self._proc.is_alive():
                self._proc.terminate()
                self._proc.join()
            self._proc = None
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def __enter__(self) -> ForkedCall:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Standby:
    """A process forked early, which loads what its work will need (``prepare``) while this one goes on, then runs
    the one call :meth:`run` hands it (cloudpickled: it may close over anything) and hands back its result.

    ``gonio analyze`` forks two before it fits, one to load matplotlib and the report's modules and one to load
    Mitsuba, on the second core while this process fits; the figures are then drawn in the first while the second
    exports. Where forking is not safe, or the call cannot be pickled, :meth:`result` makes the call here. After
    ``prepare`` the standby freezes what it imported and keeps its collector paused for the call (:func:`imports_done`).
    """

    def __init__(self, prepare: Callable[[], None]) -> None:
        self._fn: Callable[[], Any] | None = None
        self._send: Connection | None = None
        self._call: ForkedCall | None = None
        if not fork_safe():
            return
        import multiprocessing

        recv, send = multiprocessing.get_context("fork").Pipe(duplex=False)
        self._send = send

        def wait_and_run() -> Any:
            send.close()  # this end is the parent's: closed here, the parent's close() reads as "no work" (EOF)
            prepare()
            imports_done()
            try:
                job = recv.recv_bytes()
            except EOFError:  # closed without work: nothing to do
                return None
            import pickle

            return pickle.loads(job)()

        self._call = ForkedCall(wait_and_run, fork=True, fallback=self._run_here)
        recv.close()

    def _run_here(self) -> Any:
        if self._fn is None:
            raise RuntimeError("Standby: no call was handed over")
        return self._fn()

    @property
    def forked(self) -> bool:
        """Whether the standby process exists (it may still be loading)."""
        return self._call is not None and self._call.forked

    def run(self, fn: Callable[[], Any]) -> None:
        """Hand ``fn`` to the standby process (or keep it for :meth:`result` to call here)."""
        self._fn = fn
        if self._send is None or not self.forked:
            return
        import cloudpickle  # Dask's, a dependency: plain pickle refuses the fit specs' closures

        try:
            job = cloudpickle.dumps(fn)
        except Exception:  # something in fn does not pickle: draw here instead
            self.close()
            return
        self._send.send_bytes(job)

    def result(self) -> Any:
        """What the handed call returned (raising its exception here)."""
        if self._call is None:
            return self._run_here()
        try:
            return self._call.result()
        finally:
            self.close()

    def close(self) -> None:
        """Release the standby (it ends once it sees no work is coming)."""
        if self._send is not None:
            self._send.close()
            self._send = None
        if self._call is not None:
            self._call.close(wait=self._fn is not None)  # with no work handed over it is only loading: end it
            self._call = None

    def __enter__(self) -> Standby:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# On import, so that importing model (or any entry point, see above) is what sets it.
apply_thread_policy()
