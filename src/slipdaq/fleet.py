"""`slipdaq batch`: many logs on Dask, one task per log; this module only orchestrates.

A task (process_log) re-runs one log two-pass and summarizes it (report.build.read_log, report.summary.summarize_log),
lays out its page's plots (report.page_data.log_page: the data the browser draws, every high-rate row of its
maneuvers), with `--png` draws its PNGs (report.build.plot_log), and writes its estimates as Parquet
(sinks.parquet_export.write_parquet) into a temporary directory on the worker; it returns them as bytes in a
LogResult, or the error text. Who writes a log's Parquet and cache files: on the local cluster (workers on this
machine) the task itself, into DIR, returning its summary only; on a cluster of --scheduler this process, from the
bytes the task returned (only the logs need to be readable by the workers, at the same path, not DIR); with DIR an
fsspec URL (fleet_storage) the task, through fsspec. A task copies a log at a URL into a local temporary file first.
This process builds the report from the cache files (uploaded when DIR is a URL).

Output layout in DIR:
    estimates/<name>-<key>.parquet   the Parquet dataset: one file per log (the estimate rows, `log`, `label_<KEY>`)
    cache/<name>-<key>.pickle        the LogResult without its Parquet bytes (summary, page data, PNGs): what a
                                     re-run needs
    report/                          report.build.write_report over every log: one page (index.html: every log's
                                     maneuvers in one table, the comparison, each log's plots), <name>/plots.js,
                                     plotly.min.js, summary.csv, summary.json; with --png <name>/*.png, compare-*.png

<name> is the log's file stem made file-safe and unique in the run (report.build.unique_name); <key> hashes the
log's size and mtime, its stored metadata (the config, the DBC, the calibration it started from, its labels), the
name and slipdaq's version; for a log at a URL, its size and ETag (or last-modified) from fsspec's info instead of the
size, mtime and metadata (the log is not read by this process). Skip rule: a log whose Parquet and cache files with
its current key exist is not processed again; its summary and plots are read from the cache file (with --png: unless
its cache has no PNGs). A new output of a name removes the older files of that name.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import io
import json
import os
import pickle
import re
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import slipdaq
from slipdaq.fleet_storage import FleetError, UrlStore, expand_logs, is_url, local_copy, url_identity
from slipdaq.outputs import atomic_output, refuse_inputs
from slipdaq.report.build import Placed
from slipdaq.report.page_data import PagePlots
from slipdaq.report.summary import LogSummary

CACHE_FORMAT = 2
"""Part of the key: a change of the cache file's contents makes every output stale."""
ESTIMATES, CACHE, REPORT = "estimates", "cache", "report"
PlotBytes = dict[str, dict[str, tuple[str, bytes]]]
"""maneuver key -> plot stem -> (file name, PNG bytes)."""


@dataclass(frozen=True)
class Job:
    path: str
    """As given (in messages and the report)."""
    name: str
    key: str
    file: str
    """Absolute, as the workers open it (or the URL)."""
    png: bool = False
    """Draw the PNGs too (`batch --png`)."""
    out: str | None = None
    """DIR (a URL, or an absolute path) when the task writes its outputs itself (None: it returns them)."""
    inputs: tuple[str, ...] = ()
    """With a local `out`: the inputs its files must not be (inputs_inside)."""

    @property
    def stem(self) -> str:
        return f"{self.name}-{self.key}"


@dataclass(frozen=True)
class LogResult:
    """What a task returns (small and picklable): the summary, the page's plots, the PNGs and the Parquet bytes, or
    the error."""

    path: str
    name: str
    key: str
    summary: LogSummary | None = None
    page: PagePlots | None = None
    pngs: PlotBytes = field(default_factory=dict)
    png: bool = False
    """The PNGs were drawn (`pngs` is empty for a log without maneuvers)."""
    parquet: bytes = b""
    rows: int = 0
    seconds: float = 0.0
    error: str | None = None
    plots: int = 0
    """How many plots the page has (and PNGs were drawn): for the progress line."""
    png_files: int = 0
    written: bool = False
    """The task wrote its Parquet and cache files itself: `parquet`, `page` and `pngs` are empty."""


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

    @property
    def estimates(self) -> str:
        """Where the Parquet dataset is."""
        return f"{self.out_dir}/{ESTIMATES}" if isinstance(self.out_dir, str) else str(Path(self.out_dir) / ESTIMATES)


def log_key(path: str | Path, name: str) -> str:
    """The hash in a log's output names (16 hex digits)."""
    from slipdaq.logformat.reader import read_metadata

    if is_url(path):  # its ETag (or last-modified) stands for its contents: the log is not read here
        ident = {"format": CACHE_FORMAT, "version": slipdaq.__version__, "log": url_identity(str(path)), "name": name}
        return hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()[:16]
    st = os.stat(path)
    ident = {"format": CACHE_FORMAT, "version": slipdaq.__version__, "size": st.st_size, "mtime_ns": st.st_mtime_ns,
             "metadata": read_metadata(path), "name": name}
    return hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()[:16]


def failure(r: LogResult) -> str:
    """'LOG: error' (the log named once)."""
    err = r.error or ""
    return err if err.startswith((r.path, os.path.abspath(r.path))) else f"{r.path}: {err}"


def _error_text(e: BaseException) -> str:
    from slipdaq.config import ConfigError
    from slipdaq.sources.read_errors import InputError

    if isinstance(e, (InputError, ConfigError, OSError)) and str(e):
        return str(e)
    return f"{type(e).__name__}: {e}"


def process_log(job: Job) -> LogResult:
    """The task: one log two-pass, its summary, page plots (PNGs with job.png) and Parquet bytes (with job.out: written
    there, and only the summary returned); any error as text (never raises)."""
    from slipdaq.report.build import plot_log, read_log
    from slipdaq.report.labels import labels_of
    from slipdaq.report.page_data import log_page
    from slipdaq.report.summary import summarize_log
    from slipdaq.sinks.parquet_export import write_parquet

    t0 = time.perf_counter()
    try:
        with local_copy(job.file) as local:
            data = read_log(local, two_pass=True, progress=io.StringIO())
        labels = labels_of(data.metadata)
        summary = summarize_log(data.rows, data.metadata, data.diagnostics, path=job.path, name=job.name,
                                labels=labels, fast=data.fast, sensors=data.sensors)
        page = log_page(summary, data.fast)
        with tempfile.TemporaryDirectory(prefix="slipdaq-batch-") as tmp:
            made = plot_log(summary, Path(tmp) / "plots") if job.png else {}
            pngs = {k: {s: (p.name, p.read_bytes()) for s, p in v.items()} for k, v in made.items()}
            pq = Path(tmp) / "estimates.parquet"
            n = write_parquet(data.rows, pq, log_name=job.name, labels=labels)
            blob = pq.read_bytes()
        r = LogResult(job.path, job.name, job.key, summary, page, pngs, job.png, blob, n, time.perf_counter() - t0,
                      plots=sum(len(v) for v in page.plots.values()), png_files=sum(len(v) for v in pngs.values()))
        if job.out is not None:
            if is_url(job.out):
                save_to(UrlStore(job.out), r)
            else:
                save(Path(job.out), r, job.inputs)
            r = dataclasses.replace(r, parquet=b"", page=None, pngs={}, written=True)
    except Exception as e:  # reported with its log; the other logs go on
        return LogResult(job.path, job.name, job.key, seconds=time.perf_counter() - t0, error=_error_text(e))
    return dataclasses.replace(r, seconds=time.perf_counter() - t0)


# ---- DIR: the dataset, the cache, the report --------------------------------------------------------------------

Out = Path | UrlStore
"""DIR: a local directory, or a URL."""


def _rel(job: Job | LogResult) -> tuple[str, str]:
    stem = f"{job.name}-{job.key}"
    return f"{ESTIMATES}/{stem}.parquet", f"{CACHE}/{stem}.pickle"


def _paths(out: Path, job: Job | LogResult) -> tuple[Path, Path]:
    parquet, cache = _rel(job)
    return out / parquet, out / cache


def _where(out: Out, job: Job | LogResult) -> str:
    """The Parquet file's path or URL (in messages)."""
    return out.where(_rel(job)[0]) if isinstance(out, UrlStore) else str(_paths(out, job)[0])


def _read_cache(out: Out, job: Job | LogResult) -> bytes:
    return out.read(_rel(job)[1]) if isinstance(out, UrlStore) else _paths(out, job)[1].read_bytes()


def load_cached(out: Out, job: Job) -> LogResult | None:
    """The LogResult of an up-to-date log (its Parquet and cache files with its key exist), else None."""
    if isinstance(out, UrlStore):
        if not all(out.exists(r) for r in _rel(job)):
            return None
    elif not all(p.is_file() for p in _paths(out, job)):
        return None
    try:
        got = pickle.loads(_read_cache(out, job))
    except Exception:  # a cache file this version cannot read: process the log again
        return None
    if not isinstance(got, LogResult) or got.key != job.key or got.summary is None or got.page is None:
        return None
    if job.png and not got.png:  # PNGs asked for now, not drawn then
        return None
    return dataclasses.replace(got, path=job.path)


def save(out: Path, result: LogResult, inputs: Sequence[str]) -> Path:
    """The Parquet file, then the cache file (each written whole, then renamed), then the older files of the name
    removed; returns the Parquet file's path."""
    parquet, cache = _paths(out, result)
    with atomic_output(parquet, inputs=inputs) as tmp:
        tmp.write_bytes(result.parquet)
    with atomic_output(cache, inputs=inputs) as tmp:
        tmp.write_bytes(pickle.dumps(dataclasses.replace(result, parquet=b""), protocol=pickle.HIGHEST_PROTOCOL))
    older = re.compile(re.escape(result.name) + r"-[0-9a-f]{16}\.(parquet|pickle)")
    for p in (*parquet.parent.iterdir(), *cache.parent.iterdir()):
        if older.fullmatch(p.name) and p not in (parquet, cache):
            p.unlink(missing_ok=True)
    return parquet


def save_to(store: UrlStore, result: LogResult) -> str:
    """save() at a URL (by the task): the Parquet object, then the cache object, then the older objects of the name
    removed; returns the Parquet object's URL."""
    parquet, cache = _rel(result)
    store.write(parquet, result.parquet)
    store.write(cache, pickle.dumps(dataclasses.replace(result, parquet=b""), protocol=pickle.HIGHEST_PROTOCOL))
    older = re.compile(re.escape(result.name) + r"-[0-9a-f]{16}\.(parquet|pickle)")
    for d in (ESTIMATES, CACHE):
        for n in store.names(d):
            if older.fullmatch(n) and f"{d}/{n}" not in (parquet, cache):
                store.remove(f"{d}/{n}")
    return store.where(parquet)


def inputs_inside(directory: Path, inputs: Sequence[str]) -> list[str]:
    """The inputs that a file written under `directory` could be: inside it once resolved, or a hard link of a file
    in it. Only these go to the outputs' checks (outputs.refuse_inputs compares every output with every input)."""
    d = directory.resolve()
    inodes = {(st.st_dev, st.st_ino) for f in d.rglob("*") if f.is_file() for st in (f.stat(),)} if d.is_dir() else set()
    found = []
    for i in inputs:
        r = Path(i).resolve()
        with contextlib.suppress(OSError):
            if r.is_relative_to(d) or (r.stat().st_dev, r.stat().st_ino) in inodes:
                found.append(i)
    return found


def _placer(out: Out, results: dict[str, LogResult], png: bool) -> Callable[[LogSummary, Path], Placed]:
    """report.build.PlotMaker writing a log's page data (and with png its PNGs) as its task made them, read back from
    its cache file (they are not kept in memory meanwhile)."""
    from slipdaq.report.page_data import LOG_SCRIPT

    def place(log: LogSummary, out_dir: Path) -> Placed:
        cached: LogResult = pickle.loads(_read_cache(out, results[log.name]))
        assert cached.page is not None  # load_cached and the tasks make sure
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / LOG_SCRIPT).write_bytes(cached.page.script)
        made: dict[str, dict[str, Path]] = {}
        for key, by_stem in (cached.pngs if png else {}).items():
            made[key] = {}
            for stem, (file, data) in by_stem.items():
                (out_dir / file).write_bytes(data)
                made[key][stem] = out_dir / file
        return Placed(cached.page, made)
    return place


# ---- the cluster and the run --------------------------------------------------------------------------------------

@contextlib.contextmanager
def connect(scheduler: str | None, workers: int | None) -> Iterator[Any]:
    """A dask.distributed Client: of the scheduler at `scheduler`, else of a local cluster of `workers` processes
    (default: this machine's cores), one thread each, no dashboard; closed (the local cluster stopped) at the end."""
    try:
        import pyarrow  # noqa: F401  (the tasks need it)
        from distributed import Client, LocalCluster
    except ImportError as e:
        raise FleetError(f"needs the fleet extra (Dask distributed, pyarrow): pip install -e \".[fleet]\" ({e})") \
            from None
    import logging

    quiet = logging.getLogger("distributed")
    saved = quiet.level
    if logging.getLogger().getEffectiveLevel() > logging.INFO:  # not -v: Dask's own messages only when errors
        quiet.setLevel(logging.ERROR)
    try:
        with _client(Client, LocalCluster, scheduler, workers) as client:
            yield client
    finally:
        quiet.setLevel(saved)


@contextlib.contextmanager
def _client(client_cls: Any, cluster_cls: Any, scheduler: str | None, workers: int | None) -> Iterator[Any]:
    import logging

    if scheduler:
        try:
            client = client_cls(scheduler, timeout="20s")
        except (OSError, TimeoutError) as e:
            raise FleetError(f"cannot reach the Dask scheduler at {scheduler}: {e}") from None
        with client:
            yield client
        return
    n = workers or os.cpu_count() or 1
    with cluster_cls(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                     silence_logs=logging.ERROR) as cluster, client_cls(cluster) as client:
        yield client


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
    return f"{r.path}: {what} -> {_where(out, r)}"


def _ident(log: str | Path) -> str | Path:
    """What makes two logs the same (duplicates are dropped): the URL as given, or the resolved path."""
    return str(log) if is_url(log) else Path(log).resolve()


def _jobs(logs: Sequence[str | Path], png: bool = False, out: str | None = None) -> tuple[list[Job], list[LogResult]]:
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
            jobs.append(Job(str(log), name, log_key(log, name), file, png, out))
        except Exception as e:
            failed.append(LogResult(str(log), name, "", error=_error_text(e)))
    return jobs, failed


def run_batch(logs: Sequence[str | Path], out_dir: str | Path, *, scheduler: str | None = None,
              workers: int | None = None, group_by: Sequence[str] | None = None,
              stream: TextIO | None = None, png: bool = False) -> BatchResult:
    """Every log that is not up to date as one Dask task; each result saved as it comes; then the report over every
    log that succeeded (processed or up to date): one page. A log that fails is in `failed` with its error. png: the
    PNGs too (a log cached without them is processed again). Logs and out_dir may be fsspec URLs (a URL log with a
    glob is expanded); with out_dir a URL, each task writes its own outputs there."""
    from slipdaq.report.build import TABLES, write_report
    from slipdaq.report.summary import group_of

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
    try:
        jobs, failed = _jobs(logs, png, out.url if isinstance(out, UrlStore) else None)
        for r in failed:
            progress.line(f"FAILED {failure(r)}")
        results: dict[str, LogResult] = {}
        todo: list[Job] = []
        for job in jobs:
            cached = load_cached(out, job)
            if cached is None:
                todo.append(job)
                continue
            results[job.name] = dataclasses.replace(cached, page=None, pngs={})
            progress.line(_ok_line(cached, out, cached=True))
        skipped = set(results)
        if todo:
            with connect(scheduler, workers) as client:
                from distributed import as_completed

                if scheduler and not client.scheduler_info().get("workers"):
                    print(f"batch: no worker at {scheduler} yet; the tasks wait for one (`dask worker {scheduler}`)",
                          file=stream, flush=True)
                if isinstance(out, Path) and not scheduler:  # the local cluster's workers share DIR: they write it
                    for d in (ESTIMATES, CACHE):
                        (out / d).mkdir(parents=True, exist_ok=True)
                    mine = tuple(os.path.abspath(i) for i in inputs)
                    todo = [dataclasses.replace(j, out=str(out.resolve()), inputs=mine) for j in todo]
                futures = {client.submit(process_log, job, key=f"slipdaq-batch-{job.stem}", pure=False): job
                           for job in todo}
                for fut in as_completed(futures):
                    job = futures[fut]
                    try:
                        r = fut.result()
                    except Exception as e:  # the worker died (KilledWorker), the task was lost, ...
                        r = LogResult(job.path, job.name, job.key, error=_error_text(e))
                    fut.release()
                    if r.error is None:
                        if not r.written:  # a cluster of --scheduler: DIR is this machine's
                            assert isinstance(out, Path)  # a task writes at a URL itself
                            save(out, r, inputs)
                        results[job.name] = dataclasses.replace(r, parquet=b"", page=None, pngs={})
                        progress.line(_ok_line(r, out, cached=False))
                    else:
                        failed.append(r)
                        progress.line(f"FAILED {failure(r)}")
    finally:
        progress.close()
    order = [j.name for j in jobs if j.name in results]
    summaries = [dataclasses.replace(s, path=results[n].path, group=group_of(s.labels, group_by))
                 for n in order if (s := results[n].summary) is not None]
    index: Path | str | None = None
    if not summaries:
        pass
    elif isinstance(out, UrlStore):  # built here, then uploaded: the tables and the page last
        with tempfile.TemporaryDirectory(prefix="slipdaq-report-") as tmp:
            write_report(summaries, Path(tmp) / REPORT, plot=_placer(out, results, png), png=png)
            out.put_tree(Path(tmp) / REPORT, REPORT, last=TABLES)
        index = out.where(f"{REPORT}/{TABLES[-1]}")
    else:
        index = write_report(summaries, out / REPORT, inputs=inputs, plot=_placer(out, results, png), png=png).index
    rank = {str(log): i for i, log in enumerate(logs)}
    failed.sort(key=lambda r: rank.get(r.path, 0))
    return BatchResult(out_dir if isinstance(out, UrlStore) else out, [results[n] for n in order if n not in skipped],
                       [results[n] for n in order if n in skipped],
                       failed, index)
