"""One `slipdaq batch` task (process_log: one log two-pass, its summary, page data, PNGs and Parquet) and the files it
leaves in DIR: the Parquet dataset and the cache, their names, the skip rule (load_cached), who may write them (save,
save_to, inputs_inside).

Output layout in DIR:
    estimates/<name>-<key>.parquet   the Parquet dataset: one file per log (the estimate rows, `log`, `label_<KEY>`)
    cache/<name>-<key>.pickle        the LogResult without its Parquet bytes (summary, page data, PNGs): what a
                                     re-run needs

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
import errno
import hashlib
import io
import json
import os
import pickle
import re
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import slipdaq
from slipdaq.fleet.storage import UrlStore, is_url, local_copy, url_identity
from slipdaq.outputs import atomic_output
from slipdaq.report.page_data import LOG_SCRIPT, PagePlots
from slipdaq.report.summary import LogSummary, group_of
from slipdaq.report.tires import TireJob, TireResult
from slipdaq.report.write import LogPieces, log_pieces

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
    size_bytes: int = 0
    """The log's size: the longest logs go first."""
    page_dir: str | None = None
    """With a local `out`: the directory where the report is being built; a task whose worker sees it writes its page
    data there (place_page) and returns only its plots' names (elsewhere it returns everything: _writes_out)."""
    group_by: tuple[str, ...] | None = None
    """`batch --group-by`: the log's group in the report (its share of the tables is made for it, LogResult.pieces)."""

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
    """The task wrote its Parquet and cache files itself: `parquet`, `page` and `pngs` are empty (but with `placed`)."""
    placed: bool = False
    """The task wrote its page data where the report is built (Job.page_dir): `page` has no script, `pngs` no
    bytes."""
    pieces: LogPieces | None = None
    """Its share of the report's tables, encoded (report.write.log_pieces): joined by the report, not made there."""


def log_identity(path: str | Path, name: str) -> tuple[str, int]:
    """The hash in a log's output names (16 hex digits), and the log's size in bytes."""
    from slipdaq.logformat.reader import read_metadata

    if is_url(path):  # its ETag (or last-modified) stands for its contents: the log is not read here
        info = url_identity(str(path))
        ident = {"format": CACHE_FORMAT, "version": slipdaq.__version__, "log": info, "name": name}
        return hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()[:16], int(info["size"] or 0)
    st = os.stat(path)
    ident = {"format": CACHE_FORMAT, "version": slipdaq.__version__, "size": st.st_size, "mtime_ns": st.st_mtime_ns,
             "metadata": read_metadata(path), "name": name}
    return hashlib.sha256(json.dumps(ident, sort_keys=True).encode()).hexdigest()[:16], st.st_size


def failure(r: LogResult) -> str:
    """'LOG: error' (the log named once)."""
    err = r.error or ""
    return err if err.startswith((r.path, os.path.abspath(r.path))) else f"{r.path}: {err}"


def error_text(e: BaseException) -> str:
    from slipdaq.config import ConfigError
    from slipdaq.sources.read_errors import InputError

    if isinstance(e, (InputError, ConfigError, OSError)) and str(e):
        return str(e)
    return f"{type(e).__name__}: {e}"


def process_log(job: Job) -> LogResult:
    """The task: one log two-pass, its summary, page plots (PNGs with job.png) and Parquet bytes (with job.out: written
    there, and only the summary returned); any error as text (never raises)."""
    from slipdaq.export.parquet_file import write_parquet
    from slipdaq.report.build import plot_log, read_log
    from slipdaq.report.labels import labels_of
    from slipdaq.report.page_data import log_page
    from slipdaq.report.summary import summarize_log

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
                      plots=sum(len(v) for v in page.plots.values()), png_files=sum(len(v) for v in pngs.values()),
                      pieces=_pieces(job, summary, page, pngs))
        if job.out is not None and _writes_out(job, r):
            placed = job.page_dir is not None
            r = dataclasses.replace(r, parquet=b"", page=dataclasses.replace(page, script=b"") if placed else None,
                                    pngs={k: {s: (f, b"") for s, (f, _) in v.items()} for k, v in pngs.items()}
                                    if placed else {}, written=True, placed=placed)
    except Exception as e:  # reported with its log; the other logs go on
        return LogResult(job.path, job.name, job.key, seconds=time.perf_counter() - t0, error=error_text(e))
    return dataclasses.replace(r, seconds=time.perf_counter() - t0)


def _writes_out(job: Job, r: LogResult) -> bool:
    """The log's Parquet and cache files written in job.out, and its page data in job.page_dir; False where this
    worker does not see DIR (a worker of --scheduler on another machine: job.page_dir, made by the batch under a
    random name, is not there) or may not write it (then the batch writes them from the result)."""
    if is_url(job.out or ""):
        save_to(UrlStore(str(job.out)), r)
        return True
    if job.page_dir is None or not os.path.isdir(job.page_dir):
        return False
    try:
        save(Path(str(job.out)), r, job.inputs)
        place_page(Path(job.page_dir) / job.name, r, job.png, sync=True)
    except OSError as e:
        if isinstance(e, PermissionError) or e.errno == errno.EROFS:
            return False
        raise
    return True


def _pieces(job: Job, summary: LogSummary, page: PagePlots, pngs: PlotBytes) -> LogPieces:
    """The log's share of the report's tables, made for its path, its group (job.group_by) and its plots' and PNGs'
    names in the report (DIR/report/<name>/<file>, place_page)."""
    log = dataclasses.replace(summary, path=job.path, group=group_of(summary.labels, job.group_by))
    links = {k: {s: f"{job.name}/{f}" for s, (f, _) in v.items()} for k, v in pngs.items()} if job.png else {}
    return log_pieces(log, page.plots, links, page.overview)


def place_page(out_dir: Path, r: LogResult, png: bool, sync: bool = False) -> dict[str, dict[str, Path]]:
    """A log's page data in the report being built (out_dir: its directory there): plots.js, with png its PNGs; with
    sync each file synced to disk (by a task: the report's move into place then finds nothing left to sync). Returns
    the PNGs' paths by maneuver key and stem."""
    assert r.page is not None
    out_dir.mkdir(parents=True, exist_ok=True)
    made: dict[str, dict[str, Path]] = {}
    files = [(out_dir / LOG_SCRIPT, r.page.script)]
    for key, by_stem in (r.pngs if png else {}).items():
        made[key] = {stem: out_dir / file for stem, (file, _) in by_stem.items()}
        files += [(out_dir / file, data) for file, data in by_stem.values()]
    for path, data in files:
        with open(path, "wb") as fh:
            fh.write(data)
            if sync:
                fh.flush()
                os.fsync(fh.fileno())
    return made


def fit_tire(job: TireJob) -> tuple[TireResult, float]:
    """The task of one report tire file (report.tires.TireJob): its result and how long it took (seconds)."""
    t0 = time.perf_counter()
    result = job.fit()
    return result, time.perf_counter() - t0


# ---- DIR: the dataset, the cache, the report --------------------------------------------------------------------

Out = Path | UrlStore
"""DIR: a local directory, or a URL."""


def _rel(job: Job | LogResult) -> tuple[str, str]:
    stem = f"{job.name}-{job.key}"
    return f"{ESTIMATES}/{stem}.parquet", f"{CACHE}/{stem}.pickle"


def _paths(out: Path, job: Job | LogResult) -> tuple[Path, Path]:
    parquet, cache = _rel(job)
    return out / parquet, out / cache


def output_where(out: Out, job: Job | LogResult) -> str:
    """The Parquet file's path or URL (in messages)."""
    return out.where(_rel(job)[0]) if isinstance(out, UrlStore) else str(_paths(out, job)[0])


def read_cache(out: Out, job: Job | LogResult) -> bytes:
    return out.read(_rel(job)[1]) if isinstance(out, UrlStore) else _paths(out, job)[1].read_bytes()


def load_cached(out: Out, job: Job) -> LogResult | None:
    """The LogResult of an up-to-date log (its Parquet and cache files with its key exist), else None."""
    if isinstance(out, UrlStore):
        if not all(out.exists(r) for r in _rel(job)):
            return None
    elif not all(p.is_file() for p in _paths(out, job)):
        return None
    try:
        got = pickle.loads(read_cache(out, job))
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
