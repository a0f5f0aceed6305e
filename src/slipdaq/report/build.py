"""`slipdaq report`: read logs, summarize (summary.py), lay out the page's plots (page_data.py), write index.html
(page.py) and the tables (write.py); with `--png` also the PNGs (plots.py, matplotlib: imported only then).
make_report reads and summarizes; write_report writes the report of summarized logs (also `slipdaq batch`'s).

Output layout in DIR:
    index.html, summary.json, summary.csv
    plotly.min.js, slipdaq-report.js   the plotting library and the page's script, once per report
    compare.js                         the comparison plots' data (two or more logs)
    <log>/plots.js                     the data of a log's plots, <log> = the log's file stem
    tires/<group>/<wheel>.tir          each tire's Magic Formula file (MF 6.1) per label group (report/tires.py)
    --png: <log>/<key>-<plot>.png      six PNGs per maneuver (style.PLOTS); compare-<phase>-fx-slip.png
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
from slipdaq.maneuver.figures import ManeuverSummary
from slipdaq.outputs import atomic_tree, refuse_inputs
from slipdaq.report.labels import labels_of
from slipdaq.report.page import LogLinks
from slipdaq.report.page_data import COMPARE_SCRIPT, LOG_SCRIPT, PAGE_JS, PLOTLY_JS, PagePlots, log_page
from slipdaq.report.summary import Comparison, LogSummary, compare, summarize_log
from slipdaq.report.tires import TIRES_DIR, ThreadFits, TireFitter, fit_here, start_tires, write_tires
from slipdaq.report.write import LogPieces
from slipdaq.sources.read_errors import guarded

TABLES = ("summary.csv", "summary.json", "index.html")
"""The report's top files, written into DIR in this order after its plots (the index last: it links the rest)."""
RESERVED = (*TABLES, PLOTLY_JS, PAGE_JS, COMPARE_SCRIPT, TIRES_DIR)
"""Names in DIR that no log's directory takes."""


@dataclass
class LogData:
    path: Path
    metadata: dict[str, str]
    rows: list[dict[str, Any]]
    diagnostics: dict[str, Any] | None
    fast: Sequence[dict[str, Any]] = field(default_factory=list)
    """/slip/fast rows (a two-pass run's: offline.run.Rows's columns)."""
    sensors: list[dict[str, Any]] = field(default_factory=list)
    """/can/sensors samples."""
    maneuvers: list[ManeuverSummary] | None = None
    """Its maneuvers, decided beside the two-pass replay (None: to be decided from the rows)."""


@dataclass
class ReportResult:
    out_dir: Path
    logs: list[LogSummary]
    comparisons: list[Comparison]
    pngs: list[Path]
    """Empty unless `png`."""
    index: Path
    summary_json: Path
    summary_csv: Path


def read_log(path: str | Path, two_pass: bool = False, progress: TextIO | None = None,
             maneuvers: bool = False) -> LogData:
    """Metadata, estimate rows and the last diagnostics of a slipdaq log; LogError or InputError (one line)
    otherwise. two_pass: the estimates post-processed two-pass from the log's raw records (offline.two_pass_rows),
    the logged ones when it has none; maneuvers: with two_pass, a long log's maneuvers summarized in a second
    process beside the second pass (LogData.maneuvers)."""
    path = Path(path)
    if not path.is_file():
        raise LogError(f"{path}: no such file")
    metadata = read_metadata(path)
    if two_pass:
        from slipdaq.offline.run import two_pass_rows

        got = two_pass_rows(path, stream=progress, maneuvers=maneuvers)
        if got is not None:
            return LogData(path, metadata | {"report_estimates": "two-pass"}, got.rows, got.diagnostics, got.fast,
                           got.sensors, got.maneuvers)
    fast: list[dict[str, Any]] = []
    data = LogData(path, metadata | {"report_estimates": "logged"}, [], None, fast)
    topics = (TOPIC_ESTIMATE, TOPIC_DIAGNOSTICS, TOPIC_FAST_SLIP, TOPIC_SENSORS)
    for topic, _t, d in guarded(path, iter_topic(path, topics)):
        if topic == TOPIC_ESTIMATE:
            data.rows.append(d)
        elif topic == TOPIC_FAST_SLIP:
            fast.append(d)
        elif topic == TOPIC_SENSORS:
            data.sensors.append(d)
        else:
            data.diagnostics = d
    return data


def unique_name(name: str, taken: set[str]) -> str:
    """A file-safe name for a log (from its file stem) that is not in `taken` nor one of RESERVED; added to `taken`."""
    base = re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "log"
    slug, n = base, 2
    while slug in taken or slug in RESERVED:
        slug, n = f"{base}-{n}", n + 1
    taken.add(slug)
    return slug


@dataclass(frozen=True)
class Placed:
    """What a PlotMaker wrote for one log: its page's plots (DIR/<log>/plots.js) and, with `png`, its PNGs."""

    page: PagePlots
    pngs: dict[str, dict[str, Path]] = field(default_factory=dict)


PlotMaker = Callable[[LogSummary, Path], Placed]
"""Writes (or places) the page data and the PNGs of one log in its directory."""


def _sayer(progress: TextIO | None) -> Callable[[str], None]:
    return (lambda msg: print(f"report: {msg}", file=progress, flush=True)) if progress else (lambda msg: None)


def plot_log(log: LogSummary, out_dir: Path, say: Callable[[str], None] = lambda msg: None) -> dict[str, dict[str, Path]]:
    """The PNGs of every maneuver of one log in out_dir (plots.plot_maneuver; matplotlib imported here):
    {maneuver key: {plot stem: path}}."""
    from slipdaq.report import plots

    made: dict[str, dict[str, Path]] = {}
    for m in log.maneuvers:
        made[m.key] = plots.plot_maneuver(log, m, out_dir)
        say(f"{log.name}: {m.title}: {len(made[m.key])} PNGs")
    return made


def place_log(log: LogSummary, out_dir: Path, page: PagePlots, png: bool = False,
              say: Callable[[str], None] = lambda msg: None) -> Placed:
    """A log's page data in out_dir (plots.js) and, with png, its PNGs."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / LOG_SCRIPT).write_bytes(page.script)
    for m in log.maneuvers:
        say(f"{log.name}: {m.title}: {len(page.plots.get(m.key, {}))} plots")
    if not log.maneuvers:
        say(f"{log.name}: no maneuver with a defined slip")
    return Placed(page, plot_log(log, out_dir, say) if png else {})


def refuse_report_inputs(out_dir: str | Path, log_paths: Sequence[str | Path]) -> None:
    """OutputError, before any log is read, when DIR is one of the inputs or one of its top files (RESERVED) would
    be (a plot inside a log's folder that would be one is refused when the files are moved into place)."""
    out = Path(out_dir)
    refuse_inputs([out] + [out / name for name in RESERVED], log_paths)


def make_report(
    log_paths: Sequence[str | Path],
    out_dir: str | Path,
    *,
    group_by: Sequence[str] | None = None,
    progress: TextIO | None = None,
    two_pass: bool = False,
    png: bool = False,
    summaries_beside: bool = True,
) -> ReportResult:
    """Every log read first (a bad one fails before anything is written), summarized and its plots laid out (with
    every high-rate row of its maneuvers), then written (write_report), the tire files fitted on threads
    (tires.ThreadFits); png: the PNGs too. summaries_beside (two_pass): a long log's maneuvers summarized in a second
    process beside its second pass (read_log's maneuvers; the same report; about 4 % more CPU for about a tenth less
    wall time where a second core is free, docs/performance.md)."""
    say = _sayer(progress)
    refuse_report_inputs(out_dir, log_paths)
    data = []
    for p in log_paths:
        d = read_log(p, two_pass, maneuvers=summaries_beside)
        say(f"read {p}: {len(d.rows)} estimates ({d.metadata['report_estimates']})")
        data.append(d)
    taken: set[str] = set()
    logs = [summarize_log(d.rows, d.metadata, d.diagnostics, path=str(d.path), name=unique_name(d.path.stem, taken),
                          labels=labels_of(d.metadata), group_by=group_by, fast=d.fast, sensors=d.sensors,
                          found=d.maneuvers)
            for d in data]
    pages = {log.name: log_page(log, d.fast) for log, d in zip(logs, data)}
    del data
    with ThreadFits() as fits:
        return write_report(logs, out_dir, inputs=log_paths, progress=progress, png=png,
                            plot=lambda log, d: place_log(log, d, pages[log.name], png, say), fit_tires=fits)


class ReportBuild:
    """write_report in two steps, in a directory being built (`build`, moved to `out` by the caller): each log's plots
    placed as the log comes (add), then the comparison, the tables and the index over the logs in their order
    (finish). `slipdaq batch` adds each log as its task ends."""

    def __init__(self, build: Path, out: Path, *, plot: PlotMaker | None = None, png: bool = False,
                 say: Callable[[str], None] = lambda msg: None, fit_tires: TireFitter = fit_here) -> None:
        self.build, self.out, self.png, self.say, self.fit_tires = build, out, png, say, fit_tires
        self.plot: PlotMaker = plot or (lambda log, d: place_log(log, d, log_page(log), png, say))
        self.links: dict[str, LogLinks] = {}
        self.pngs: list[Path] = []
        self.pieces: dict[str, LogPieces] = {}

    def add(self, log: LogSummary, pieces: LogPieces | None = None) -> None:
        """A log's plots placed; pieces: its share of the tables made already (write.log_pieces), used where made
        for what the report has of it (its path, group, plots, PNGs)."""
        placed = self.plot(log, self.build / log.name)
        rel = {k: {s: p.relative_to(self.build).as_posix() for s, p in v.items()} for k, v in placed.pngs.items()}
        self.links[log.name] = LogLinks(placed.page, rel)
        self.pngs += (self.out / p for v in rel.values() for p in v.values())
        if pieces is not None:
            self.pieces[log.name] = pieces

    def finish(self, logs: Sequence[LogSummary]) -> ReportResult:
        """The comparison (two or more logs), the tables and index.html over `logs` (each one added before); the tire
        files fitted meanwhile (fit_tires)."""
        from slipdaq.report import page, page_data, sets, write

        build, logs, links = self.build, list(logs), self.links
        tires = start_tires(logs, self.fit_tires)
        comparisons = compare(logs) if len(logs) > 1 else []
        compare_pngs: dict[str, str] = {}
        if comparisons:
            (build / COMPARE_SCRIPT).write_bytes(page_data.compare_script(comparisons, logs))
        for c in comparisons:
            if self.png:
                from slipdaq.report import plots

                p = plots.plot_comparison(c.phase, logs, build / f"compare-{c.phase}-fx-slip.png")
                compare_pngs[c.phase] = p.relative_to(build).as_posix()
                self.pngs.append(self.out / compare_pngs[c.phase])
            self.say(f"comparison {c.phase}: {', '.join(g.group for g in c.groups)}")
        page_data.write_assets(build)
        groups = sets.group_sets(logs)
        group_records = {g.group: g.sets.records() for g in groups}
        diffs = sets.differences(groups)
        cs, js, index = (build / name for name in TABLES)
        pieces = write.pieces_of(logs, {n.name: links[n.name].page.plots for n in logs},
                                 {n.name: links[n.name].pngs for n in logs},
                                 {n.name: links[n.name].page.overview for n in logs}, self.pieces)
        write.write_csv(pieces, cs)
        write.write_json(logs, comparisons, pieces, compare_pngs, js, group_sets=group_records, differences=diffs)
        tire_groups = tires()
        tire_links = {g: {w: f"{TIRES_DIR}/{rel}" for w, rel in files.items()}
                      for g, files in write_tires(build / TIRES_DIR, tire_groups).items()}
        self.say(f"tire files: {sum(len(v) for v in tire_links.values())} in {TIRES_DIR}/")
        page.write_html(logs, comparisons, {n.name: links[n.name] for n in logs}, compare_pngs, index,
                        tires=(tire_groups, tire_links), group_sets=group_records, differences=diffs)
        cs, js, index = (self.out / name for name in TABLES)
        return ReportResult(self.out, logs, comparisons, self.pngs, index, js, cs)

    def wrote(self, result: ReportResult) -> str:
        n_plots = sum(len(v) for n in result.logs for v in self.links[n.name].page.plots.values())
        pngs = f", {len(self.pngs)} PNGs" if self.png else ""
        return f"wrote {result.index} ({n_plots} plots{pngs}), {result.summary_json}, {result.summary_csv}"


def write_report(
    logs: Sequence[LogSummary],
    out_dir: str | Path,
    *,
    inputs: Sequence[str | Path] = (),
    progress: TextIO | None = None,
    plot: PlotMaker | None = None,
    png: bool = False,
    fit_tires: TireFitter = fit_here,
) -> ReportResult:
    """The report of summarized logs (unique names) in out_dir: per log its plots' data (and PNGs) in DIR/<log>/
    (`plot`, default: laid out from the summary alone, then place_log), the comparison, the tables, plotly.js and the
    page's script, index.html last; built in a temporary directory in DIR and moved into place when all are done
    (outputs.atomic_tree): a report that fails leaves DIR as it was. png: the comparison's PNGs too. fit_tires:
    where the tire files are fitted (tires.TireFitter)."""
    out, say = Path(out_dir), _sayer(progress)
    with atomic_tree(out, inputs=inputs, last=TABLES) as build:
        report = ReportBuild(build, out, plot=plot, png=png, say=say, fit_tires=fit_tires)
        for log in logs:
            report.add(log)
        result = report.finish(logs)
    say(report.wrote(result))
    return result
