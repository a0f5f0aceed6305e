"""The Dask cluster of `slipdaq batch`: a local one, or the scheduler at an address; its workers warm before the
first task; a task whose worker dies is retried once.

Warm: the local cluster's workers are forked from this process once it has imported the task's modules and loaded
the compiled kernels (slipdaq.fleet.warm): the imports are made once, not once per worker, and a worker is up in
milliseconds. A forked worker has this process's environment, as a spawned one would: the same user's credentials
and endpoint of the logs' object store. A worker of --scheduler imports them when it joins (WarmUp), before it takes
a task.

A worker that dies (killed, out of memory, a crash in a library) loses its task; the scheduler gives the task to
another worker, and reports it failed (distributed's KilledWorker) once it has lost `ALLOWED_FAILURES` + 1 workers.
A death counts against every task its worker held: fleet.run_batch has no more tasks out than the cluster has
threads, so that a worker holds the one it runs (except just after a death, while its worker restarts). The local
cluster is started with this setting; a scheduler of --scheduler keeps its own (`distributed.scheduler.allowed-failures`,
3 by default).
"""

from __future__ import annotations

import contextlib
import gc
import logging
import os
from collections.abc import Iterator
from typing import Any

from slipdaq.fleet.storage import FleetError


def need_fleet_extra() -> None:
    """FleetError naming the extra to install where Dask distributed or pyarrow is missing."""
    try:
        import distributed  # noqa: F401
        import pyarrow  # noqa: F401  (the tasks need it)
    except ImportError as e:
        raise FleetError(f"needs the fleet extra (Dask distributed, pyarrow): pip install -e \".[fleet]\" ({e})") \
            from None


need_fleet_extra()
from distributed import Client, LocalCluster  # noqa: E402
from distributed.diagnostics.plugin import WorkerPlugin  # noqa: E402

ALLOWED_FAILURES = 1
"""A task is retried once on another worker after its worker died, then reported failed."""
DASHBOARD_OFF = {
    "distributed.worker.profile.enabled": False,
    "distributed.admin.system-monitor.interval": "5s",
    "distributed.admin.tick.interval": "1s",
    "distributed.scheduler.work-stealing": False,
}
"""The local cluster's processes without what only the dashboard (not started) reads: the statistical profiler (a
stack sample of every thread every 10 ms, in each worker, the task's thread held meanwhile), the system monitor's
CPU, memory, disk and network samples (every 500 ms in each process) and the event loop's health tick (every 20 ms);
and without work stealing, which has nothing to steal: fleet.feed has no more tasks out than the cluster has threads.
The workers' memory monitor (their memory limit) keeps its interval."""


@contextlib.contextmanager
def connect(scheduler: str | None, workers: int | None) -> Iterator[Any]:
    """A dask.distributed Client: of the scheduler at `scheduler`, else of a local cluster of `workers` processes
    (default: this machine's cores), one thread each, no dashboard; its workers warm (WarmUp); closed (the local
    cluster stopped) at the end."""
    need_fleet_extra()
    quiet = logging.getLogger("distributed")
    saved = quiet.level
    if logging.getLogger().getEffectiveLevel() > logging.INFO:  # not -v: Dask's own messages only when errors
        quiet.setLevel(logging.ERROR)
    try:
        with _client(Client, LocalCluster, scheduler, workers) as client:
            client.register_plugin(WarmUp(), name="slipdaq-warm-up")
            yield client
    finally:
        quiet.setLevel(saved)


@contextlib.contextmanager
def _client(client_cls: Any, cluster_cls: Any, scheduler: str | None, workers: int | None) -> Iterator[Any]:
    import dask

    if scheduler:
        try:
            client = client_cls(scheduler, timeout="20s")
        except (OSError, TimeoutError) as e:
            raise FleetError(f"cannot reach the Dask scheduler at {scheduler}: {e}") from None
        with client:
            yield client
        return
    _warm_here()
    n = workers or os.cpu_count() or 1
    with dask.config.set({"distributed.scheduler.allowed-failures": ALLOWED_FAILURES,
                          "distributed.worker.multiprocessing-method": "fork", **DASHBOARD_OFF}):
        with cluster_cls(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                         silence_logs=logging.ERROR) as cluster, client_cls(cluster) as client:
            yield client


def _warm_here() -> None:
    """slipdaq.fleet.warm imported in this process before it forks the workers, with the garbage collector paused
    (as slipdaq.__main__ does: these objects live as long as the process, a collection that walks them frees
    nothing) and then frozen (gc.freeze): a worker's collections do not touch, and so copy, the pages it shares."""
    gc.disable()
    try:
        import slipdaq.fleet.warm  # noqa: F401

        gc.freeze()
    finally:
        gc.enable()


class WarmUp(WorkerPlugin):
    """A Dask worker plugin: the worker imports the task's modules and loads the compiled kernels when it joins
    (slipdaq.fleet.warm), not in its first task; with the garbage collector paused, then frozen, as in this process
    before it forks the local workers (_warm_here)."""

    idempotent = True

    def setup(self, worker: Any) -> None:
        _warm_here()

    def teardown(self, worker: Any) -> None:
        pass
