"""`slipdaq batch`: many logs on Dask, one task per log; this module only orchestrates.

A task (fleet_task.process_log) re-runs one log two-pass and summarizes it, lays out its page's plots, with `--png`
draws its PNGs, encodes its share of the report's tables, and writes its estimates as Parquet; it returns its summary
(and, where it cannot write DIR itself, its outputs as bytes), or the error text. Who writes a log's Parquet and cache
files and its page data: the task itself, into DIR, where its worker sees DIR (every worker of the local cluster; a
worker of --scheduler that finds the report's build directory, made here under a random name, at the same path)
and may write it; else this process, from the bytes the task returned (only the logs need to be readable by the
workers, at the same path, not DIR); with DIR an fsspec URL (fleet_storage) the task, through fsspec. A task copies a
log at a URL into a local temporary file first.

The tasks are submitted longest log first (by size); the workers are warm before their first task and a task whose
worker died is retried once (fleet_cluster). The report (report.build.ReportBuild) is built as the tasks end: a task
that writes DIR writes its page data where the report is being built (fleet_task.place_page), elsewhere each log's
page data is placed from its result as it comes; each task encodes its log's share of the tables (LogResult.pieces),
which the report joins after the last, with the comparison and the index, while the report's tire files are fitted
on the cluster, one task per label group and wheel (fleet_task.fit_tire), the most points first. Where the time went
is in BatchResult.client (ClientTime).

Output layout in DIR: estimates/ and cache/ (fleet_task), and
    report/                          one page (index.html: every log's maneuvers in one table, the comparison, each
                                     log's plots), <name>/plots.js, plotly.min.js, summary.csv, summary.json; with
                                     --png <name>/*.png, compare-*.png
"""

from __future__ import annotations

import contextlib
import dataclasses
import gc
import os
import pickle
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO, TypeVar

from slipdaq.fleet.storage import FleetError, UrlStore, expand_logs, is_url
from slipdaq.fleet.task import (
    CACHE,
    ESTIMATES,
    REPORT,
    Job,
    LogResult,
    Out,
    error_text,
    failure,
    fit_tire,
    inputs_inside,
    load_cached,
    log_identity,
    output_where,
    place_page,
    process_log,
    read_cache,
    save,
)
from slipdaq.outputs import refuse_inputs
from slipdaq.report.build import Placed, ReportBuild
from slipdaq.report.summary import LogSummary
from slipdaq.report.tires import TireFitter
from slipdaq.report.write import LogPieces

T = TypeVar("T")

__all__ = ["BatchResult", "ClientTime", "FleetError", "Job", "LogResult", "failure", "process_log", "run_batch"]


@dataclass
class ClientTime:
    """Where run_batch's wall time went, in seconds: what this process did itself (the serial part of a batch) and
    how long it waited on the tasks."""

    planning_s: float = 0.0
    """The logs listed, their keys made, the up-to-date ones read from the cache."""
    cluster_start_s: float = 0.0
    """The cluster started (or reached) and its workers warm."""
    waiting_s: float = 0.0
    """Blocked on the tasks (none ended yet), the tire fits' included."""
    collecting_s: float = 0.0
    """Each result taken: saved where the task could not, its plots placed in the report, its line printed."""
    report_s: float = 0.0
    """The report's tables and page after the last result (not the waits on its tire fits: waiting_s)."""
    cluster_stop_s: float = 0.0
    """The local cluster stopped (or the scheduler left)."""
    first_result_s: float | None = None
    """From run_batch's start to the first task's result."""
    tasks_s: float = 0.0
    """The tasks' own times (LogResult.seconds, and each tire fit's), summed."""
    total_s: float = 0.0
    """run_batch from start to end."""

    @property
    def outside_tasks_s(self) -> float:
        """run_batch's time not spent waiting on the tasks."""
        return self.total_s - self.waiting_s

    @contextlib.contextmanager
    def timing(self, phase: str) -> Iterator[None]:
        """Adds the block's wall time to the field `phase`."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            setattr(self, phase, getattr(self, phase) + time.perf_counter() - t0)

    def line(self) -> str:
        """One line for the progress stream."""
        return (f"{self.tasks_s:.1f} s in the tasks (summed), {self.total_s:.1f} s in all; outside the tasks "
                f"{self.outside_tasks_s:.2f} s: cluster start {self.cluster_start_s:.2f} s, planning "
                f"{self.planning_s:.2f} s, results {self.collecting_s:.2f} s, report {self.report_s:.2f} s, "
                f"cluster stop {self.cluster_stop_s:.2f} s")


@dataclass
class BatchResult:
    out_dir: Path | str
    """A path, or the URL given."""
    done: list[LogResult]
    """Processed in this run, in the order of the logs."""
    skipped: list[LogResult]
    """Up to date: read from the cache."""
    failed: list[LogResult]
    report: Path | str | None
    """index.html (its URL when DIR is one); None when no log succeeded."""
    client: ClientTime = dataclasses.field(default_factory=ClientTime)

    @property
    def estimates(self) -> str:
        """Where the Parquet dataset is."""
        return f"{self.out_dir}/{ESTIMATES}" if isinstance(self.out_dir, str) else str(Path(self.out_dir) / ESTIMATES)


def _placer(out: Out, results: dict[str, LogResult], png: bool) -> Callable[[LogSummary, Path], Placed]:
    """report.build.PlotMaker: a log's page data (and with png its PNGs) as its task made them, where its task wrote
    them itself (LogResult.placed), else from its result as it comes (not kept in memory afterwards), or read back
    from its cache file where its task wrote that at a URL and returned neither."""

    def place(log: LogSummary, out_dir: Path) -> Placed:
        r = results[log.name]
        if r.placed:
            assert r.page is not None  # the task makes sure
            return Placed(r.page, {k: {s: out_dir / f for s, (f, _) in v.items()} for k, v in r.pngs.items()}
                          if png else {})
        if r.page is None:
            r = pickle.loads(read_cache(out, r))
            assert r.page is not None  # the tasks make sure
        return Placed(r.page, place_page(out_dir, r, png))
    return place


class _Progress:
    """One line per finished log on the stream, above a progress bar when the stream is a terminal."""

    def __init__(self, stream: TextIO, total: int) -> None:
        self.stream, self.total, self.count = stream, total, 0
        self._bar: Any = None
        self._stack = contextlib.ExitStack()
        if stream.isatty():
            from rich.console import Console
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

            self._bar = self._stack.enter_context(Progress(
                TextColumn("batch"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                console=Console(file=stream), transient=True))
            self._task = self._bar.add_task("batch", total=total)

    def line(self, text: str) -> None:
        self.count += 1
        msg = f"batch: [{self.count}/{self.total}] {text}"
        if self._bar is not None:
            self._bar.console.print(msg, markup=False, highlight=False)
            self._bar.update(self._task, completed=self.count)
        else:
            print(msg, file=self.stream, flush=True)

    def close(self) -> None:
        self._stack.close()


def _ok_line(r: LogResult, out: Out, cached: bool) -> str:
    pngs = f", {r.png_files} PNGs" if r.png else ""
    maneuvers = len(r.summary.maneuvers) if r.summary else 0
    what = "up to date" if cached else f"{r.rows} estimates, {maneuvers} maneuvers, {r.plots} plots{pngs} ({r.seconds:.1f} s)"
    return f"{r.path}: {what} -> {output_where(out, r)}"


def _ident(log: str | Path) -> str | Path:
    """What makes two logs the same (duplicates are dropped): the URL as given, or the resolved path."""
    return str(log) if is_url(log) else Path(log).resolve()


def _jobs(logs: Sequence[str | Path], png: bool = False, out: str | None = None,
          group_by: Sequence[str] | None = None) -> tuple[list[Job], list[LogResult]]:
    """A job per log (duplicates dropped), and the failures of logs whose key cannot be made (not readable)."""
    from slipdaq.report.build import unique_name

    taken: set[str] = set()
    seen: set[str | Path] = set()
    jobs: list[Job] = []
    failed: list[LogResult] = []
    for log in logs:
        if _ident(log) in seen:
            continue
        seen.add(_ident(log))
        name = unique_name(Path(str(log).rstrip("/")).stem, taken)
        try:
            file = str(log) if is_url(log) else os.path.abspath(log)
            key, size = log_identity(log, name)
            jobs.append(Job(str(log), name, key, file, png, out, size_bytes=size,
                            group_by=tuple(group_by) if group_by else None))
        except Exception as e:
            failed.append(LogResult(str(log), name, "", error=error_text(e)))
    return jobs, failed


class _NoLog(Exception):
    """No log succeeded: the report is not written."""


class _Report:
    """The fleet report, built as the logs come (ReportBuild): in DIR/report (moved into place at the end, as
    write_report does), or in a temporary directory uploaded at the end when DIR is a URL. Nothing is written when no
    log succeeds."""

    def __init__(self, out: Out, results: dict[str, LogResult], png: bool, inputs: Sequence[str]) -> None:
        self.out, self.png, self.inputs = out, png, inputs
        self.place = _placer(out, results, png)
        self.stack = contextlib.ExitStack()
        self.build: ReportBuild | None = None

    def __enter__(self) -> _Report:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stack.__exit__(*exc)  # an error or an interrupt: the half-built report is removed, not moved into place

    def _open(self) -> ReportBuild:
        if self.build is None:
            from slipdaq.outputs import atomic_tree
            from slipdaq.report.build import TABLES

            if isinstance(self.out, UrlStore):
                d = Path(self.stack.enter_context(tempfile.TemporaryDirectory(prefix="slipdaq-report-"))) / REPORT
                d.mkdir()
                self.build = ReportBuild(d, d, plot=self.place, png=self.png)
            else:
                d = self.out / REPORT
                tree = self.stack.enter_context(atomic_tree(d, inputs=self.inputs, last=TABLES))
                self.build = ReportBuild(tree, d, plot=self.place, png=self.png)
        return self.build

    def page_dir(self) -> Path:
        """Where the report is being built: a log's page data goes in <it>/<name>/."""
        return self._open().build

    def add(self, log: LogSummary, pieces: LogPieces | None = None) -> None:
        self._open().add(log, pieces)

    def finish(self, logs: Sequence[LogSummary], fit_tires: TireFitter | None = None) -> Path | str | None:
        """index.html's path (or URL) once it is in place; None without a log (the report's directory removed).
        fit_tires: where the tire files are fitted (default: here)."""
        if self.build is None or not self.build.links:
            self.stack.__exit__(_NoLog, _NoLog(), None)  # as on an error: nothing moved into place
            return None
        from slipdaq.report.build import TABLES

        if fit_tires is not None:
            self.build.fit_tires = fit_tires
        self.build.finish(logs)
        if isinstance(self.out, UrlStore):  # uploaded: the tables and the page last
            self.out.put_tree(self.build.build, REPORT, last=TABLES)
            self.stack.close()
            return self.out.where(f"{REPORT}/{TABLES[-1]}")
        self.stack.close()  # atomic_tree moves the files into place
        return self.out / REPORT / TABLES[-1]


def run_batch(logs: Sequence[str | Path], out_dir: str | Path, *, scheduler: str | None = None,
              workers: int | None = None, group_by: Sequence[str] | None = None,
              stream: TextIO | None = None, png: bool = False) -> BatchResult:
    """Every log that is not up to date as one Dask task, longest first; each result saved and its plots placed in
    the report as it comes; then the report's tables and page over every log that succeeded (processed or up to
    date). A log that fails is in `failed` with its error. png: the PNGs too (a log cached without them is processed
    again). Logs and out_dir may be fsspec URLs (a URL log with a glob is expanded); with out_dir a URL, each task
    writes its own outputs there."""
    from slipdaq.report.summary import group_of

    clock = ClientTime()
    t0 = time.perf_counter()
    logs = expand_logs(logs)
    out: Out
    inputs: list[str] = []
    if isinstance(out_dir, str) and is_url(out_dir):
        out = UrlStore(out_dir)
        out.check_writable()
    else:
        out = Path(out_dir)
        local = [str(p) for p in logs if not is_url(p)]
        refuse_inputs([out], local)
        inputs = inputs_inside(out, local)
    stream = stream or sys.stderr
    progress = _Progress(stream, len(dict.fromkeys(_ident(p) for p in logs)))
    results: dict[str, LogResult] = {}
    with contextlib.ExitStack() as stack:
        stack.callback(progress.close)
        report = stack.enter_context(_Report(out, results, png, inputs))

        def succeeded(r: LogResult, cached: bool) -> None:
            if r.summary is not None:  # the path as given now, the group of --group-by
                r = dataclasses.replace(r, summary=dataclasses.replace(r.summary, path=r.path,
                                                                       group=group_of(r.summary.labels, group_by)))
            results[r.name] = r
            if r.summary is not None:
                report.add(r.summary, r.pieces)  # its plots placed by its name, its share of the tables
            if not r.placed:  # its page data and PNGs are in the report now, its Parquet in DIR
                results[r.name] = dataclasses.replace(r, parquet=b"", page=None, pngs={})
            progress.line(_ok_line(r, out, cached=cached))

        jobs, failed = _jobs(logs, png, out.url if isinstance(out, UrlStore) else None, group_by)
        for r in failed:
            progress.line(f"FAILED {failure(r)}")
        todo: list[Job] = []
        for job in jobs:
            cached = load_cached(out, job)
            if cached is None:
                todo.append(job)
            else:
                succeeded(cached, cached=True)
        skipped = set(results)
        clock.planning_s = time.perf_counter() - t0

        def finish(fit_tires: TireFitter | None = None) -> Path | str | None:  # the report over every log that succeeded
            waited = clock.waiting_s
            with clock.timing("report_s"):
                summaries = [s for j in jobs if (n := j.name) in results and (s := results[n].summary) is not None]
                index = report.finish(summaries, fit_tires)
            clock.report_s -= clock.waiting_s - waited
            return index

        if todo:
            def ok(r: LogResult) -> None:
                if clock.first_result_s is None:
                    clock.first_result_s = time.perf_counter() - t0
                clock.tasks_s += r.seconds
                succeeded(r, cached=False)

            lost, index = _run_tasks(todo, out, inputs, report.page_dir, scheduler, workers, stream, ok,
                                     lambda r: progress.line(f"FAILED {failure(r)}"), clock, finish)
            failed += lost
        else:
            index = finish()
        order = [j.name for j in jobs if j.name in results]
    rank = {str(log): i for i, log in enumerate(logs)}
    failed.sort(key=lambda r: rank.get(r.path, 0))
    clock.total_s = time.perf_counter() - t0
    return BatchResult(out_dir if isinstance(out, UrlStore) else out, [results[n] for n in order if n not in skipped],
                       [results[n] for n in order if n in skipped],
                       failed, index, clock)


def _run_tasks(todo: list[Job], out: Out, inputs: Sequence[str], page_dir: Callable[[], Path],
               scheduler: str | None, workers: int | None, stream: TextIO, ok: Callable[[LogResult], None],
               bad: Callable[[LogResult], None], clock: ClientTime, then: Callable[[TireFitter], T]) -> tuple[list[LogResult], T]:
    """The jobs as Dask tasks, longest log first, as many out as the cluster has threads (fleet_feed.Feed); a task
    whose worker sees DIR writes its files there and its page data in page_dir(); each result handed to `ok` (saved
    first where the task could not write DIR) or `bad` as it comes; after the last, `then` (the report), its tire
    files fitted on the cluster. Returns the failures and what `then` returned. Each step's time goes to the
    clock."""
    t = time.perf_counter()
    gc.disable()  # Dask's modules: as slipdaq.__main__ imports the CLI's (fleet_cluster._warm_here)
    try:
        from slipdaq.fleet.cluster import connect
    finally:
        gc.enable()
    failed: list[LogResult] = []
    with connect(scheduler, workers) as client:
        clock.cluster_start_s += time.perf_counter() - t
        if scheduler and not client.scheduler_info().get("workers"):
            print(f"batch: no worker at {scheduler} yet; the tasks wait for one (`dask worker {scheduler}`)",
                  file=stream, flush=True)
        if isinstance(out, Path):  # a worker that sees DIR writes it (every one of the local cluster)
            for d in (ESTIMATES, CACHE):
                (out / d).mkdir(parents=True, exist_ok=True)
            mine = tuple(os.path.abspath(i) for i in inputs)
            pages = str(page_dir().resolve())
            todo = [dataclasses.replace(j, out=str(out.resolve()), inputs=mine, page_dir=pages)
                    for j in todo]
        from slipdaq.fleet.feed import Feed

        ended = iter(Feed(client, todo, lambda: _threads(client)))
        while True:
            with clock.timing("waiting_s"):
                got = next(ended, None)
            if got is None:
                break
            with clock.timing("collecting_s"):
                job, value = got
                r = value if isinstance(value, LogResult) else LogResult(job.path, job.name, job.key,
                                                                          error=_task_lost(value))
                if r.error is None:
                    if not r.written:  # a cluster of --scheduler: DIR is this machine's
                        assert isinstance(out, Path)  # a task writes at a URL itself
                        save(out, r, inputs)
                    ok(r)
                else:
                    if job.page_dir is not None:  # what a task that failed may have left of its page data
                        shutil.rmtree(Path(job.page_dir) / job.name, ignore_errors=True)
                    failed.append(r)
                    bad(r)
        last = then(_tire_fitter(client, clock))
        t = time.perf_counter()
    clock.cluster_stop_s += time.perf_counter() - t
    return failed, last


def _threads(client: Any) -> int:
    """The cluster's threads now: the local cluster's own count (kept by the scheduler's messages as workers come and
    go), the scheduler's of --scheduler asked of it."""
    if client.cluster is not None:
        return max(1, sum(w["nthreads"] for w in list(client.cluster.scheduler_info["workers"].values())))
    return max(1, sum(client.nthreads().values()))


def _tire_fitter(client: Any, clock: ClientTime) -> TireFitter:
    """report.tires.TireFitter on the cluster: a task per tire file, the most points first; their waits and times go
    to the clock as the log tasks' do."""
    from slipdaq.report.tires import TireJob, TireResult

    def fit(jobs: Sequence[TireJob]) -> Callable[[], list[TireResult]]:
        futures = {i: client.submit(fit_tire, jobs[i], key=("slipdaq-tire", i), pure=False)
                   for i in sorted(range(len(jobs)), key=lambda i: -jobs[i].points)}

        def wait() -> list[TireResult]:
            with clock.timing("waiting_s"):
                done = [futures[i].result() for i in range(len(jobs))]
            clock.tasks_s += sum(seconds for _, seconds in done)
            return [r for r, _ in done]
        return wait
    return fit


def _task_lost(e: BaseException) -> str:
    from distributed import KilledWorker

    if isinstance(e, KilledWorker):
        return "its worker died each time it was tried (once, and once again on another worker on the local cluster): " \
               "out of memory, killed, a crash in a library"
    return error_text(e)
