"""Drawing the report's figures side by side in forked processes, where that is safe, while this process works on.

matplotlib holds the GIL while it draws, so threads gain nothing; forked processes inherit the analysis as it
is (nothing pickled but the written figure's paths) and draw into the same directory. The workers are forked only
where :func:`model.runtime.fork_safe` allows; otherwise, and for a single figure or ``jobs`` = 1, the figures are
drawn one after the other in this process; the files are the same bytes either way. Each figure is drawn with the
garbage collector paused (:func:`model.runtime.without_gc`).

:func:`start_draws` forks the figure workers and returns at once; :meth:`PendingDraws.finish` waits for them,
drawing here, meanwhile, any figure no worker has begun when this process has matplotlib loaded (it then forks
one worker fewer: loading matplotlib only to help would cost more than it saves). One call forked beside this
process, or a process forked early to load what its call needs, is :class:`model.runtime.ForkedCall` or
:class:`model.runtime.Standby` (the exports, the ladder's fits).
"""

from __future__ import annotations

import multiprocessing
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from model.runtime import fork_safe, without_gc

#: The draws of the pool being run; the forked children find them here (a closure cannot be pickled).
_DRAWS: list[Callable[[], Any]] = []


def _draw(i: int) -> Any:
    return without_gc(_DRAWS[i])


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
