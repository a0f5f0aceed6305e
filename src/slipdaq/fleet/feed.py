"""The log tasks of `slipdaq batch` kept out on its cluster: longest log first, as many at a time as the cluster has
threads (a worker holds only the task it runs: a worker's death counts against that task alone, fleet_cluster), the
next one submitted as soon as one ends, from distributed's callback thread, not when the batch has taken its result;
each result fetched as its task ends, by the client's own thread (as_completed with the results), so that taking it
is only what the batch does with it."""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator, Sequence
from typing import Any

from slipdaq.fleet.task import Job, LogResult, process_log


class Feed:
    """Iterate to get (job, its LogResult, or the exception that lost its task) as the tasks end."""

    def __init__(self, client: Any, jobs: Sequence[Job], threads: Callable[[], int]) -> None:
        from distributed import as_completed

        self.client, self.threads = client, threads
        self.queue = sorted(jobs, key=lambda j: -j.size_bytes)[::-1]  # popped from the end: the longest first
        self.jobs: dict[Any, Job] = {}
        self.out = 0
        """Submitted and not ended."""
        self.lock = threading.Lock()
        self.added = threading.Event()
        """Set when a task ended and its successor was submitted."""
        self.broken: BaseException | None = None
        self.ended = as_completed(with_results=True, raise_errors=False)
        self._submit()

    def _submit(self) -> None:
        with self.lock:
            slots = self.threads()
            while self.queue and self.out < slots:
                job = self.queue.pop()
                fut = self.client.submit(process_log, job, key=("slipdaq-batch", job.stem), pure=False)
                self.jobs[fut] = job
                self.out += 1
                self.ended.add(fut)
                fut.add_done_callback(self._one_ended)

    def _one_ended(self, fut: Any) -> None:  # on distributed's callback thread
        try:
            with self.lock:
                self.out -= 1
            self._submit()
            self.added.set()
        except BaseException as e:  # the client closing, ...: the iteration stops with it
            self.broken = e

    def __iter__(self) -> Iterator[tuple[Job, LogResult | BaseException]]:
        while True:
            got = next(self.ended, None)
            if self.broken is not None:
                raise self.broken
            if got is None:
                with self.lock:
                    if not self.queue and not self.out:
                        return
                self.added.wait(0.05)  # a task ended, its successor not submitted yet
                self.added.clear()
                continue
            fut, value = got
            with self.lock:
                job = self.jobs.pop(fut)
            fut.release()
            if fut.status == "finished":
                yield job, value
            else:  # its worker died twice (KilledWorker), the task was lost: (type, exception, traceback) or the error
                yield job, value[1] if isinstance(value, tuple) else value
