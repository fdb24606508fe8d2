"""Drawing the report's figures side by side in forked processes, where that is safe.

matplotlib holds the GIL while it draws, so threads gain nothing; forked processes inherit the analysis as it
is (nothing pickled but the written figure's paths) and draw into the same directory. A fork copies only the
calling thread, so it is taken only when nothing else could be holding a lock the child needs: no thread
but the main one (and tqdm's monitor), numba's thread pool never started (its default workqueue layer is
not fork-safe) and Mitsuba (LLVM's threads) not loaded. Otherwise, and for a single figure or ``jobs`` = 1,
the figures are drawn one after the other in this process; the files are the same bytes either way.
"""

from __future__ import annotations

import multiprocessing
import sys
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from typing import Any

#: The draws of the pool being run; the forked children find them here (a closure cannot be pickled).
_DRAWS: list[Callable[[], Any]] = []


def _draw(i: int) -> Any:
    return _DRAWS[i]()


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


def run_draws(draws: Sequence[Callable[[], Any]], jobs: int, done: Callable[[Any], None]) -> list[Any]:
    """Each draw's result in order, drawn by up to ``jobs`` forked processes when safe; ``done`` after each."""
    if jobs > 1 and len(draws) > 1 and fork_safe():
        _DRAWS[:] = draws
        try:
            ctx = multiprocessing.get_context("fork")
            with ProcessPoolExecutor(max_workers=min(jobs, len(draws)), mp_context=ctx) as pool:
                futures = {pool.submit(_draw, i): i for i in range(len(draws))}
                results: list[Any] = [None] * len(draws)
                for f in as_completed(futures):
                    results[futures[f]] = f.result()
                    done(results[futures[f]])
                return results
        except BrokenProcessPool:
            pass  # a worker died (out of memory, a signal): draw them here instead
        finally:
            _DRAWS.clear()
    out = []
    for draw in draws:
        out.append(draw())
        done(out[-1])
    return out
