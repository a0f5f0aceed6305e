"""A Dask worker preload (`distributed.worker.preload`) for tests/test_batch_worker_death.py: a worker that starts a
task whose key names `doomed` dies at once (os._exit, as if killed); one that starts a task naming `flaky` dies only
the first time. Each start is counted in SLIPDAQ_TEST_KILL_DIR/<name> (one line per attempt)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from distributed.diagnostics.plugin import WorkerPlugin


class Killer(WorkerPlugin):
    def transition(self, key: Any, start: str, finish: str, **kwargs: Any) -> None:
        if finish != "executing":
            return
        name = next((n for n in ("doomed", "flaky") if n in str(key)), None)
        if name is None:
            return
        tally = Path(os.environ["SLIPDAQ_TEST_KILL_DIR"]) / name
        with tally.open("a") as fh:
            fh.write("attempt\n")
        if name == "doomed" or len(tally.read_text().splitlines()) == 1:
            os._exit(1)


async def dask_setup(worker: Any) -> None:
    await worker.plugin_add(Killer(), name="slipdaq-test-killer")
