"""The Dask side of a batch: a cluster to run on, and running a list of tasks on it with a progress bar.

By default a local cluster (one single-threaded worker process per core this process may use, on the
loopback interface, no set-up); with ``scheduler`` an existing cluster (``dask scheduler`` and
``dask worker ADDRESS`` on a lab's machines, or dask-jobqueue's ``SLURMCluster``: see README.md). Workers are
processes, so a worker killed or lost (OOM, a node that goes away) takes only its running task with it: Dask
runs that task again on another worker (up to ``distributed.scheduler.allowed-failures`` times, then it
reports ``KilledWorker``, which the batch records as that task's failure). Dask's own nanny pins each worker's
BLAS and OpenMP to one thread, which is what keeps two workers from fighting over one core (gonio holds numba's
and Dr.Jit's pools to the same, model/runtime.py).

A local cluster's workers keep glibc's own malloc settings: Dask's nanny would start them with
``MALLOC_TRIM_THRESHOLD_=65536`` (to hand freed memory back to the system at once), which made every input's
analysis fault its pages in again (system time), for memory an analysis frees and takes again at the next
input. Its scheduler and workers also check their event loops and sample the running task's stack less often
than Dask's defaults (:data:`LOCAL_CONFIG`): Dask's ticks kept an idle local cluster's cores measurably busy, and
that share comes out of the tasks when every core has a worker (docs/benchmarks.md, the batch section). A lab's
own cluster keeps its own configuration.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import uuid
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from tqdm import tqdm

from analysis.result import AnalysisError, Log

#: Dask settings of a local cluster (see the module docstring); each still detects a stalled event loop, and the
#: dashboard's profile page still fills, ten times more coarsely.
LOCAL_CONFIG: dict[str, str] = {
    "distributed.admin.tick.interval": "200ms",
    "distributed.worker.profile.interval": "100ms",
}


@dataclass(frozen=True)
class ClusterSettings:
    """Where tasks run: an existing scheduler's address, or a local cluster of ``workers`` (default: the cores)."""

    scheduler: str | None = None
    workers: int | None = None
    dashboard: bool = True
    #: Where a local cluster's dashboard listens: this machine only (port 0 picks a free one; 8787 is Dask's).
    dashboard_address: str = "127.0.0.1:8787"
    #: How long to try reaching ``scheduler`` before saying it cannot be reached (s).
    connect_timeout_s: float = 30.0

    def __post_init__(self) -> None:
        if self.workers is not None and self.workers < 1:
            raise AnalysisError(f"--workers {self.workers}: expected at least 1")
        if self.scheduler is not None and self.workers is not None:
            raise AnalysisError("--workers sizes a local cluster; with --scheduler the cluster is the one running "
                                "there")


@dataclass(frozen=True)
class Task:
    """One task: its key (unique in the batch), the function and its arguments, its priority (higher first)."""

    key: str
    fn: Callable[..., Any]
    args: tuple[Any, ...] = ()
    priority: int = 0


def cores() -> int:
    """The cores this process may run on (a container or a batch job may see more than it gets)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def dashboard_link(client: Any) -> str | None:
    """The address of the cluster's dashboard, or None when its scheduler runs none."""
    try:
        services = client.scheduler_info().get("services", {})
    except Exception:  # an old or unusual scheduler: no dashboard to point at
        return None
    return str(client.dashboard_link) if "dashboard" in services else None


@contextlib.contextmanager
def cluster_client(settings: ClusterSettings | None = None, log: Log | None = None) -> Iterator[Any]:
    """A ``distributed.Client`` on the settings' cluster for the length of the block; says where its dashboard is."""
    from distributed import Client, LocalCluster

    s = settings or ClusterSettings()
    say = log or (lambda _: None)
    cluster = None
    if s.scheduler is not None:
        try:
            client = Client(s.scheduler, timeout=f"{s.connect_timeout_s}s")
        except (OSError, TimeoutError) as exc:
            raise AnalysisError(f"--scheduler {s.scheduler}: cannot reach a Dask scheduler there: {exc}") from exc
        where = f"Dask scheduler {s.scheduler}, {len(client.scheduler_info().get('workers', {}))} workers"
    else:
        import dask

        n = s.workers or cores()
        spawn_env = {k: v for k, v in dask.config.get("distributed.nanny.pre-spawn-environ", {}).items()
                     if k != "MALLOC_TRIM_THRESHOLD_"}  # fmt: skip
        with dask.config.set({"distributed.nanny.pre-spawn-environ": spawn_env, **LOCAL_CONFIG}):
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, host="127.0.0.1",
                                   dashboard_address=s.dashboard_address if s.dashboard else None,
                                   silence_logs=logging.ERROR)  # fmt: skip
        client = Client(cluster)
        where = f"local Dask cluster of {n} worker{'s' if n > 1 else ''} (one thread each)"
    link = dashboard_link(client)
    say(f"{where}; dashboard: {link}" if link else f"{where}; no dashboard running")
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def run_tasks(
    client: Any,
    tasks: Sequence[Task],
    *,
    desc: str,
    progress: bool = True,
    total: int | None = None,
    initial: int = 0,
    on_done: Callable[[str, Any], None] | None = None,
) -> dict[str, Any]:
    """Run every task on the client's cluster; results by key (a task that raised, or killed its workers: the error).

    The bar counts tasks done (``initial`` of ``total`` before any ran, e.g. skipped as finished) with its
    ETA; ``on_done(key, result)`` is called as each finishes. Ctrl-C cancels what has not run.
    """
    from distributed import as_completed

    token = uuid.uuid4().hex[:8]  # keys unique on a shared scheduler, and across restarts of one batch
    futures = {client.submit(t.fn, *t.args, key=f"{t.key}-{token}", pure=False, priority=t.priority): t.key
               for t in tasks}  # fmt: skip
    results: dict[str, Any] = {}
    failed = 0
    bar = tqdm(total=total if total is not None else len(tasks), initial=initial, desc=desc, unit="task",
               disable=not progress, file=sys.stderr, dynamic_ncols=True)  # fmt: skip
    try:
        for fut in as_completed(futures):
            key = futures[fut]
            try:
                res = fut.result()
            except Exception as exc:  # KilledWorker, or a task that raised: the caller records it
                res = exc
            results[key] = res
            failed += isinstance(res, Exception) or (isinstance(res, dict) and res.get("status") == "failed")
            bar.update(1)
            if failed:
                bar.set_postfix_str(f"{failed} failed")
            if on_done is not None:
                on_done(key, res)
    except BaseException:
        client.cancel(list(futures))
        raise
    finally:
        bar.close()
    return results
