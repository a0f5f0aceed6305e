"""The maneuvers' summaries of an offline run computed in a second process, beside the pipeline: on two cores the
summaries (the fits, their bootstraps) no longer hold up the replay. The pipeline holds the sinks' later calls back
until each summary is in (Pipeline's hold_output), so the output is the same bytes as with the summaries at once.

The process is forked once, before the run's sinks start threads of their own, and gets each job (a picklable
callable and its arguments: `detector.Job.record` and the maneuver's number) through a pipe; a thread of the run
takes the results back. It ends when the run ends, on an error and on KeyboardInterrupt (terminated), and when the
run's process dies (the pipe closes)."""

from __future__ import annotations

import itertools
import os
import signal
import threading
import traceback
from collections.abc import Callable
from concurrent.futures import Executor, Future
from multiprocessing import get_context
from multiprocessing.connection import Connection
from types import TracebackType
from typing import Any

MIN_RAW_RECORDS = 1
"""A run of fewer raw records summarizes at once: the second process costs more than it gives (docs/performance.md)."""


class SummaryProcessError(RuntimeError):
    """The summary process ended before it gave a result back."""


def worth_a_process(raw_records: int | None) -> bool:
    """A second process pays: a log of at least MIN_RAW_RECORDS raw records, and a second core to run it on."""
    return raw_records is not None and raw_records >= MIN_RAW_RECORDS and len(os.sched_getaffinity(0)) > 1


def _serve(jobs: Connection, results: Connection, parent_ends: tuple[Connection, ...]) -> None:
    """The second process: each job's result (or the error it raised) back, in turn, until told to stop or the run's
    end of the pipe closes."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a ^C is the run's to handle: it terminates this process
    for end in parent_ends:
        end.close()
    while True:
        try:
            job = jobs.recv()
        except EOFError:
            return
        if job is None:
            return
        key, fn, args = job
        try:
            out: tuple[int, bool, Any] = (key, True, fn(*args))
        except Exception as e:
            e.add_note("in the summary process:\n" + traceback.format_exc())
            out = (key, False, e)
        try:
            results.send(out)
        except Exception as e:  # a result or error that does not pickle
            results.send((key, False, SummaryProcessError(f"{out[2]!r}: {e}")))


class SummaryProcess(Executor):
    """One forked process that runs the jobs submitted, in order (concurrent.futures' Executor)."""

    def __init__(self) -> None:
        ctx = get_context("fork")
        jobs_in, self._jobs = ctx.Pipe(duplex=False)
        self._results, results_out = ctx.Pipe(duplex=False)
        self.process = ctx.Process(target=_serve, args=(jobs_in, results_out, (self._jobs, self._results)),
                                   name="slipdaq-summaries", daemon=True)
        self.process.start()
        jobs_in.close()
        results_out.close()
        self._futures: dict[int, Future[Any]] = {}
        self._lock = threading.Lock()
        self._keys = itertools.count()
        self._closed = False
        self._reader = threading.Thread(target=self._read, name="slipdaq-summary-results", daemon=True)
        self._reader.start()

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        if kwargs:
            raise TypeError("SummaryProcess.submit takes positional arguments only")
        if self._closed:
            raise RuntimeError("the summary process is shut down")
        key = next(self._keys)
        future: Future[Any] = Future()
        with self._lock:
            self._futures[key] = future
        try:
            self._jobs.send((key, fn, args))
        except BaseException as e:
            with self._lock:
                self._futures.pop(key, None)
            if isinstance(e, OSError):  # the process is gone
                raise SummaryProcessError("the summary process has ended") from e
            raise
        return future

    def _read(self) -> None:
        """The results, as they come, into their futures; once the process ends, the rest fail."""
        while True:
            try:
                key, ok, value = self._results.recv()
            except (EOFError, OSError):
                break
            with self._lock:
                future = self._futures.pop(key)
            future.set_result(value) if ok else future.set_exception(value)
        with self._lock:
            left, self._futures = list(self._futures.values()), {}
        for future in left:
            future.set_exception(SummaryProcessError("the summary process ended before the summary was in"))

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        """The process told to stop once its jobs are done (wait: waited for; cancel_futures: terminated now)."""
        if cancel_futures:
            self.terminate()
            return
        if not self._closed:
            self._closed = True
            try:
                self._jobs.send(None)
            except OSError:
                pass
        if wait:
            self.process.join()
            self._reader.join()
            self._close_pipes()

    def terminate(self) -> None:
        """The process ended now (SIGTERM), whatever it was doing; the summaries not in fail."""
        self._closed = True
        if self.process.is_alive():
            self.process.terminate()
        self.process.join()
        self._reader.join()
        self._close_pipes()

    def _close_pipes(self) -> None:
        self._jobs.close()
        self._results.close()

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 tb: TracebackType | None) -> None:
        """A run that ended with an error or an interrupt terminates the process; one that ended well waits for it."""
        if error is None:
            self.shutdown(wait=True)
        else:
            self.terminate()
