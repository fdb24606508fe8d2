"""Drawing the report's figures side by side in forked processes, where that is safe, while this process works on.

matplotlib holds the GIL while it draws, so threads gain nothing; forked processes inherit the analysis as it
is (nothing pickled but the written figure's paths) and draw into the same directory. A fork copies only the
calling thread, so it is taken only when nothing else could be holding a lock the child needs: no thread
but the main one (and tqdm's monitor), numba's thread pool never started (its default workqueue layer is
not fork-safe) and Mitsuba (LLVM's threads) not loaded. Otherwise, and for a single figure or ``jobs`` = 1,
the figures are drawn one after the other in this process; the files are the same bytes either way.

The same holds for one call: :class:`ForkedCall` runs it in a forked child and hands back its (pickled) result,
which is how ``gonio analyze`` exports the chosen model (Mitsuba, a CPU second or more) while this process draws
when it has no :class:`Standby` for the exports. Each figure is drawn with the garbage collector paused
(:func:`without_gc`).
:func:`start_draws` forks the figure workers and returns at once; :meth:`PendingDraws.finish` waits for them,
drawing here, meanwhile, any figure no worker has begun when this process has matplotlib loaded (it then forks
one worker fewer: loading matplotlib only to help would cost more than it saves).
"""

from __future__ import annotations

import gc
import multiprocessing
import signal
import sys
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from multiprocessing.connection import Connection
from typing import Any

#: The draws of the pool being run; the forked children find them here (a closure cannot be pickled).
_DRAWS: list[Callable[[], Any]] = []


def _draw(i: int) -> Any:
    return without_gc(_DRAWS[i])


def imports_done() -> None:
    """In a standby after its imports: freeze what they made, and leave the collector paused for the one call the
    standby runs before it ends (``gonio analyze`` pauses the collector while its processes import).

    An import is many objects that live as long as the process, so the collector's passes over them (a tenth of
    importing scipy and matplotlib) free nothing; frozen, later full passes skip them too. The call's own garbage
    ends with the process: a figure's reference cycles are freed by a pass over everything it allocated (0.1 CPU
    s after a 1000-point run's slices), which a process about to end need not make; the figure workers it forks
    inherit the paused collector (see :func:`without_gc`). Only for a forked process that ends with its work:
    frozen objects are never collected.
    """
    gc.freeze()
    gc.disable()


def without_gc(fn: Callable[[], Any]) -> Any:
    """``fn()`` with the cyclic garbage collector paused, then one pass over what it allocated.

    A figure is tens of thousands of objects that live until it is saved: the collector's passes while it is built
    find nothing to free, and each full one walks every loaded module's objects too (a tenth of a 1000-point
    run's drawing). One young-generation pass afterwards frees the figure's reference cycles.
    """
    if not gc.isenabled():
        return fn()
    gc.disable()
    try:
        return fn()
    finally:
        gc.enable()
        gc.collect(0)


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


class PendingDraws:
    """Draws begun by :func:`start_draws`; :meth:`finish` returns their results, :meth:`close` abandons them."""

    def __init__(self, draws: Sequence[Callable[[], Any]], pool: ProcessPoolExecutor | None,
                 futures: list[Future[Any]]) -> None:  # fmt: skip
        self._draws, self._pool, self._futures = list(draws), pool, futures

    @property
    def forked(self) -> bool:
        """Whether worker processes are drawing (else finish() draws everything here)."""
        return self._pool is not None

    def finish(self, done: Callable[[Any], None]) -> list[Any]:
        """Each draw's result in order, ``done`` called after each; the draws no worker took are drawn here."""
        results: list[Any] = [None] * len(self._draws)
        todo = set(range(len(self._draws)))
        if self._pool is not None:
            try:
                if "matplotlib.figure" in sys.modules:  # help with the queue's tail rather than wait
                    for i in reversed(range(len(self._draws))):
                        if self._futures[i].cancel():
                            results[i] = without_gc(self._draws[i])
                            todo.discard(i)
                            done(results[i])
                index = {self._futures[i]: i for i in todo}
                for f in as_completed(index):
                    results[index[f]] = f.result()
                    todo.discard(index[f])
                    done(results[index[f]])
            except BrokenProcessPool:
                pass  # a worker died (out of memory, a signal): what is left is drawn here
            finally:
                self.close()
        for i in sorted(todo):
            results[i] = without_gc(self._draws[i])
            done(results[i])
        return results

    def close(self) -> None:
        """Stop the workers (waiting for a figure being drawn, so no file is left half written)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
            _DRAWS.clear()

    def __enter__(self) -> PendingDraws:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def start_draws(draws: Sequence[Callable[[], Any]], jobs: int) -> PendingDraws:
    """Begin the draws in up to ``jobs`` forked processes when safe (else nothing begins until finish())."""
    helping = "matplotlib.figure" in sys.modules  # then this process draws too, in finish()
    workers = min(jobs, len(draws)) - (1 if helping else 0)
    if workers >= 1 and len(draws) > 1 and fork_safe():
        _DRAWS[:] = draws
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("fork"))
        try:
            return PendingDraws(draws, pool, [pool.submit(_draw, i) for i in range(len(draws))])
        except (BrokenProcessPool, OSError):  # could not fork (out of processes or memory): draw them here
            pool.shutdown(wait=True, cancel_futures=True)
            _DRAWS.clear()
    return PendingDraws(draws, None, [])


def run_draws(draws: Sequence[Callable[[], Any]], jobs: int, done: Callable[[Any], None]) -> list[Any]:
    """Each draw's result in order, drawn by up to ``jobs`` forked processes when safe; ``done`` after each."""
    with start_draws(draws, jobs) as pending:
        return pending.finish(done)


def _ended(*_: object) -> None:
    raise SystemExit(1)  # unwinds the call, so a pool it runs is shut down and its workers end with it


def _call_child(fn: Callable[[], Any], conn: Connection, parents: Connection) -> None:
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
