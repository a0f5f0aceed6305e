"""The maneuvers' summaries of an offline run computed in a second process, beside the pipeline: on two cores the
summaries (the fits, their bootstraps) no longer hold up the replay. The pipeline holds the sinks' later calls back
until each summary is in (Pipeline's hold_output), so the output is the same bytes as with the summaries at once.

The process is forked once, before the run's sinks start threads of their own, and gets each job (a picklable
callable and its arguments: `detector.Job.record` and the maneuver's number) through a pipe that a thread of the
run writes; another thread takes the results back. DetectorFeed decides the report's maneuvers as a pass makes its
rows and summarizes them there too. It ends when the run ends, on an error and on KeyboardInterrupt (terminated), and when the
run's process dies (the pipe closes)."""

from __future__ import annotations

import dataclasses
import itertools
import os
import queue
import threading
import traceback
from collections.abc import Callable
from concurrent.futures import Executor, Future
from multiprocessing import get_context
from multiprocessing.connection import Connection
from multiprocessing.reduction import ForkingPickler
from types import TracebackType
from typing import Any

from slipdaq import compiled
from slipdaq.config import Config
from slipdaq.maneuver.detector import Job, ManeuverDetector, TimeOrderFeed
from slipdaq.maneuver.events import PHASES
from slipdaq.maneuver.figures import ManeuverSummary
from slipdaq.offline.forked import started
from slipdaq.records.fast_rows import FastSlipBatch

MIN_RAW_RECORDS = 2_000
"""A run of fewer raw records (about 25 s of 4 WPT messages and 20 Hz NMEA logged offline: a maneuver or two)
summarizes at once: starting the second process (13–20 ms) would cost about what it gives (docs/performance.md)."""


class SummaryProcessError(RuntimeError):
    """The summary process ended before it gave a result back."""


def worth_a_process(raw_records: int | None) -> bool:
    """A second process pays: a log of at least MIN_RAW_RECORDS raw records, and a second core to run it on."""
    return raw_records is not None and raw_records >= MIN_RAW_RECORDS and len(os.sched_getaffinity(0)) > 1


def _serve(jobs: Connection, results: Connection, parent_ends: tuple[Connection, ...]) -> None:
    """The second process: each job's result (or the error it raised) back, in turn, until told to stop or the run's
    end of the pipe closes."""
    started(parent_ends)
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
    """One forked process that runs the jobs submitted, in order (concurrent.futures' Executor). A job is pickled
    where it is submitted and written to the pipe by a thread (a job larger than the pipe's buffer never holds up the
    run while the process is busy with the one before); another thread takes the results back."""

    def __init__(self) -> None:
        compiled.prepare()  # the kernels loaded once, before the fork: the process has them too
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
        self._ended = False
        """The process has ended: no result comes any more."""
        self._outbox: queue.SimpleQueue[bytes | None] = queue.SimpleQueue()
        self._sender = threading.Thread(target=self._send, name="slipdaq-summary-jobs", daemon=True)
        self._reader = threading.Thread(target=self._read, name="slipdaq-summary-results", daemon=True)
        self._sender.start()
        self._reader.start()

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        if kwargs:
            raise TypeError("SummaryProcess.submit takes positional arguments only")
        if self._closed:
            raise RuntimeError("the summary process is shut down")
        key = next(self._keys)
        job = ForkingPickler.dumps((key, fn, args))
        future: Future[Any] = Future()
        with self._lock:
            if self._ended:
                raise SummaryProcessError("the summary process has ended")
            self._futures[key] = future
        self._outbox.put(bytes(job))
        return future

    def _send(self) -> None:
        """The jobs, in turn, to the process (until told to stop, or it has gone)."""
        while (job := self._outbox.get()) is not None:
            try:
                self._jobs.send_bytes(job)
            except OSError:
                return

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
            self._ended = True
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
            self._outbox.put(bytes(ForkingPickler.dumps(None)))
            self._outbox.put(None)
        if wait:
            self.process.join()
            self._end_threads()

    def terminate(self) -> None:
        """The process ended now (SIGTERM), whatever it was doing; the summaries not in fail."""
        self._closed = True
        self._outbox.put(None)
        if self.process.is_alive():
            self.process.terminate()
        self.process.join()
        self._end_threads()

    def _end_threads(self) -> None:
        """After the process: the reader (its pipe at its end) and the sender (told to stop, or the pipe broken)."""
        self._reader.join()
        self._results.close()
        self._sender.join()
        self._jobs.close()

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 tb: TracebackType | None) -> None:
        """A run that ended with an error or an interrupt terminates the process; one that ended well waits for it."""
        if error is None:
            self.shutdown(wait=True)
        else:
            self.terminate()


SENSOR_WAIT_S = 5.0
"""A row or high-rate row goes to the detector once the pass's log time is this far past it: the brake samples and
time marks of its time have come by then (a time mark comes with a later UBX frame)."""


class DetectorFeed:
    """The maneuvers of a pass's rows decided as the pass makes them, in the order `report.summary.detect_maneuvers`
    feeds the finished rows (estimate and high-rate rows merged by time, an estimate before a high-rate row of the
    same time, as heapq.merge; the brake samples before the rows they precede), each summary computed on `executor`
    meanwhile: the same summaries, in the same order, as detect_maneuvers over the rows afterwards."""

    def __init__(self, config: Config | None, executor: Executor) -> None:
        self.detector = ManeuverDetector(config, phases=PHASES)
        self._executor = executor
        self._feed = TimeOrderFeed(self.detector)
        self._found: list[tuple[Job, Future[ManeuverSummary]]] = []

    def estimate(self, row: dict[str, Any]) -> None:
        self._feed.estimate(row)

    def fast(self, rows: FastSlipBatch) -> None:
        self._feed.fast(rows)

    def sensor(self, sample: dict[str, Any]) -> None:
        self.detector.add_sensor_row(sample)

    def log_time(self, log_time_s: float) -> None:
        """The pass has come this far: the rows SENSOR_WAIT_S before it, in merged order, to the detector."""
        self._submit(self._feed.take(log_time_s - SENSOR_WAIT_S))

    def _submit(self, jobs: list[Job]) -> None:
        self._found += [(job, self._executor.submit(_summary_apart, job)) for job in jobs]

    def finish(self) -> list[ManeuverSummary]:
        """Every row to the detector and the last maneuvers decided (here): all the summaries, in the order decided."""
        self._submit(self._feed.take(final=True))
        last = [job() for job in self.detector.finish()]
        return [dataclasses.replace(f.result(), rows=tuple(job.rows)) for job, f in self._found] + last


def _summary_apart(job: Job) -> ManeuverSummary:
    """A job's summary without its rows (the run has them: they are not sent back)."""
    return dataclasses.replace(job(), rows=())
