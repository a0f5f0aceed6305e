"""`slipdaq report`: read logs, summarize (summary.py), draw (plots.py), write index.html and the tables (write.py).
make_report reads and summarizes; write_report writes the report of summarized logs (also `slipdaq batch`'s).

Output layout in DIR:
    index.html, summary.json, summary.csv
    <log>/<phase>-<plot>.png        five plots per maneuver (plots.PLOTS), <log> = the log's file stem
    compare-<phase>-fx-slip.png     Fx against slip of every log, grouped by labels (two or more logs)
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from slipdaq.logformat.errors import LogError
from slipdaq.logformat.reader import iter_topic, read_metadata
from slipdaq.logformat.topics import TOPIC_DIAGNOSTICS, TOPIC_ESTIMATE, TOPIC_FAST_SLIP, TOPIC_SENSORS
from slipdaq.outputs import atomic_tree
from slipdaq.report.labels import labels_of
from slipdaq.report.summary import Comparison, LogSummary, compare, summarize_log, table_rows
from slipdaq.sources.read_errors import guarded

TABLES = ("summary.csv", "summary.json", "index.html")
"""The report's top files, written into DIR in this order after its plots (the index last: it links the rest)."""


@dataclass
class LogData:
    path: Path
    metadata: dict[str, str]
    rows: list[dict[str, Any]]
    diagnostics: dict[str, Any] | None
    fast: list[dict[str, Any]] = field(default_factory=list)
    """/slip/fast rows."""
    sensors: list[dict[str, Any]] = field(default_factory=list)
    """/can/sensors samples."""


@dataclass
class ReportResult:
    out_dir: Path
    logs: list[LogSummary]
    comparisons: list[Comparison]
    pngs: list[Path]
    index: Path
    summary_json: Path
    summary_csv: Path


def read_log(path: str | Path, two_pass: bool = False, progress: TextIO | None = None) -> LogData:
    """Metadata, estimate rows and the last diagnostics of a slipdaq log; LogError or InputError (one line)
    otherwise. two_pass: the estimates post-processed two-pass from the log's raw records (offline.two_pass_rows),
    the logged ones when it has none."""
    path = Path(path)
    if not path.is_file():
        raise LogError(f"{path}: no such file")
    metadata = read_metadata(path)
    if two_pass:
        from slipdaq.offline import two_pass_rows

        got = two_pass_rows(path, stream=progress)
        if got is not None:
            return LogData(path, metadata | {"report_estimates": "two-pass"}, got.rows, got.diagnostics, got.fast,
                           got.sensors)
    data = LogData(path, metadata | {"report_estimates": "logged"}, [], None)
    topics = (TOPIC_ESTIMATE, TOPIC_DIAGNOSTICS, TOPIC_FAST_SLIP, TOPIC_SENSORS)
    for topic, _t, d in guarded(path, iter_topic(path, topics)):
        if topic == TOPIC_ESTIMATE:
            data.rows.append(d)
        elif topic == TOPIC_FAST_SLIP:
            data.fast.append(d)
        elif topic == TOPIC_SENSORS:
            data.sensors.append(d)
        else:
            data.diagnostics = d
    return data


def unique_name(name: str, taken: set[str]) -> str:
    """A file-safe name for a log (from its file stem) that is not in `taken` nor one of TABLES; added to `taken`."""
    base = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "log"
    slug, n = base, 2
    while slug in taken or slug in TABLES:
        slug, n = f"{base}-{n}", n + 1
    taken.add(slug)
    return slug


PlotMaker = Callable[[LogSummary, Path], dict[str, dict[str, Path]]]
"""Draws (or places) the plots of one log in a directory: {maneuver key: {plot stem: path}}."""


def _sayer(progress: TextIO | None) -> Callable[[str], None]:
    return (lambda msg: print(f"report: {msg}", file=progress, flush=True)) if progress else (lambda msg: None)


def plot_log(log: LogSummary, out_dir: Path, say: Callable[[str], None] = lambda msg: None) -> dict[str, dict[str, Path]]:
    """The plots of every maneuver of one log in out_dir (plots.plot_maneuver): {maneuver key: {plot stem: path}}."""
    from slipdaq.report import plots

    made: dict[str, dict[str, Path]] = {}
    for m in log.maneuvers:
        made[m.key] = plots.plot_maneuver(log, m, out_dir)
        say(f"{log.name}: {m.title}: {len(made[m.key])} plots")
    if not log.maneuvers:
        say(f"{log.name}: no maneuver with a defined slip")
    return made


def make_report(
    log_paths: Sequence[str | Path],
    out_dir: str | Path,
    *,
    group_by: Sequence[str] | None = None,
    progress: TextIO | None = None,
    two_pass: bool = False,
) -> ReportResult:
    """Every log read first (a bad one fails before anything is written), summarized, then written (write_report)."""
    say = _sayer(progress)
    data = []
    for p in log_paths:
        d = read_log(p, two_pass)
        say(f"read {p}: {len(d.rows)} estimates ({d.metadata['report_estimates']})")
        data.append(d)
    taken: set[str] = set()
    logs = [summarize_log(d.rows, d.metadata, d.diagnostics, path=str(d.path), name=unique_name(d.path.stem, taken),
                          labels=labels_of(d.metadata), group_by=group_by, fast=d.fast, sensors=d.sensors)
            for d in data]
    return write_report(logs, out_dir, inputs=log_paths, progress=progress)


def write_report(
    logs: Sequence[LogSummary],
    out_dir: str | Path,
    *,
    inputs: Sequence[str | Path] = (),
    progress: TextIO | None = None,
    plot: PlotMaker | None = None,
) -> ReportResult:
    """The report of summarized logs (unique names) in out_dir: per log its plots in DIR/<name>/ (`plot`, default
    plot_log), the comparison plots, the tables, index.html last; built in a temporary directory in DIR and moved
    into place when all are done (outputs.atomic_tree): a report that fails leaves DIR as it was."""
    from slipdaq.report import plots, write

    out = Path(out_dir)
    say = _sayer(progress)
    logs = list(logs)
    with atomic_tree(out, inputs=inputs, last=TABLES) as build:
        plot_paths: dict[str, dict[str, dict[str, str]]] = {}
        pngs: list[Path] = []
        for log in logs:
            made = plot(log, build / log.name) if plot else plot_log(log, build / log.name, say)
            plot_paths[log.name] = {k: {s: p.relative_to(build).as_posix() for s, p in v.items()}
                                    for k, v in made.items()}
            pngs += (out / p.relative_to(build) for v in made.values() for p in v.values())
        comparisons = compare(logs) if len(logs) > 1 else []
        compare_plots: dict[str, str] = {}
        for c in comparisons:
            p = plots.plot_comparison(c.phase, logs, build / f"compare-{c.phase}-fx-slip.png")
            compare_plots[c.phase] = p.relative_to(build).as_posix()
            pngs.append(out / compare_plots[c.phase])
            say(f"comparison {c.phase}: {', '.join(g.group for g in c.groups)}")
        rows = table_rows(logs)
        cs, js, index = (build / name for name in TABLES)
        write.write_csv(rows, cs)
        write.write_json(logs, comparisons, rows, plot_paths, compare_plots, js)
        write.write_html(logs, comparisons, plot_paths, compare_plots, index)
    cs, js, index = (out / name for name in TABLES)
    say(f"wrote {index} ({len(pngs)} plots), {js}, {cs}")
    return ReportResult(out, logs, comparisons, pngs, index, js, cs)
