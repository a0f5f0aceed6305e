"""The local cluster of `slipdaq batch` (fleet.cluster.connect) as it runs: its forked workers and its scheduler
without the dashboard's periodic work (the statistical profiler, the system monitor every 500 ms, the event loop's
tick every 20 ms) and without work stealing; the memory monitor, which enforces a worker's memory limit, as Dask
sets it. Asked of the running processes themselves, through Dask's own API."""

from __future__ import annotations

from typing import Any

import dask
import pytest

pytest.importorskip("distributed")
from slipdaq.fleet.cluster import DASHBOARD_OFF, connect  # noqa: E402


def _callbacks_ms(server: Any) -> dict[str, float]:
    return {name: float(pc.callback_time) for name, pc in server.periodic_callbacks.items()}


def test_the_local_cluster_runs_without_the_dashboards_periodic_work() -> None:
    default_memory_ms = dask.utils.parse_timedelta(dask.config.get("distributed.worker.memory.monitor-interval"),
                                                   default="ms") * 1000
    with connect(None, 1) as client:
        workers = client.run(lambda dask_worker: _callbacks_ms(dask_worker))
        scheduler = client.run_on_scheduler(lambda dask_scheduler: (_callbacks_ms(dask_scheduler),
                                                                      sorted(dask_scheduler.extensions)))
        profile_on = client.run(lambda: dask.config.get("distributed.worker.profile.enabled"))
    assert len(workers) == 1
    (worker,) = workers.values()
    assert "profile" not in worker and "profile-cycle" not in worker, worker
    assert worker["monitor"] == 5000 and worker["tick"] == 1000, worker
    assert worker["memory_monitor"] == pytest.approx(default_memory_ms), worker
    callbacks, extensions = scheduler
    assert "stealing" not in extensions and "stealing" not in callbacks, scheduler
    assert callbacks["monitor"] == 5000 and callbacks["tick"] == 1000, callbacks
    assert list(profile_on.values()) == [False]


def test_the_settings_are_the_local_clusters_only() -> None:
    """Set around the cluster's start: the process's own Dask config is as it was after the cluster stops."""
    before = {key: dask.config.get(key) for key in DASHBOARD_OFF}
    with connect(None, 1):
        pass
    assert {key: dask.config.get(key) for key in DASHBOARD_OFF} == before
    assert before["distributed.worker.profile.enabled"] is True  # Dask's default: the cluster's setting is its own
