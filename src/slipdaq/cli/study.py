"""The study verbs: report (one or more logs as a page and tables), batch (many logs on Dask)."""

from __future__ import annotations

import argparse
import sys

from slipdaq.cli.common import (
    EXIT_FAIL,
    EXIT_OK,
    OUTPUT_RULES,
    _positive,
    _require_png,
)

BATCH_HELP = """\
Each log is one task on Dask: re-run two-pass from its raw records (as `replay --two-pass`; the logged
estimates for a log without raw records), summarized and plotted (as `report`). Default: a local cluster
of --workers processes on this machine, nothing to start; --scheduler: an existing Dask cluster (start
`dask scheduler` on one host and `dask worker tcp://HOST:8786` on each machine; every worker must read
the logs at the same paths, e.g. a shared file system; this process writes a local DIR; on the local
cluster each task writes its own files). Needs the fleet extra:
pip install -e ".[fleet]".

Logs and DIR may be fsspec URLs: 's3://bucket/day1/*.mcap' (quoted: fsspec expands the glob) -o
s3://bucket/out. A worker copies a log at a URL to a local temporary file and reads that; with DIR a URL
each task writes its Parquet and cache objects there itself, and this process uploads the report.
Credentials and endpoint from the environment (AWS_ACCESS_KEY_ID, AWS_SECRET_ACCESS_KEY,
AWS_ENDPOINT_URL or FSSPEC_S3_ENDPOINT_URL, AWS_PROFILE, ...) of this process and of every worker.

Output in DIR:
  estimates/NAME-KEY.parquet  one file per log: its estimates (the CSV's columns), `log` and `label_KEY`
  cache/NAME-KEY.pickle       the log's summary and plots, for re-runs
  report/                     index.html (one page: every log's maneuvers, the comparison across logs by
                              labels, interactive plots), summary.csv and summary.json (one row per log,
                              maneuver and wheel); with --png the PNGs
NAME is the log's file stem; KEY hashes the log's size and mtime, its stored config, DBC, calibration
and labels, and slipdaq's version (a log at a URL: its size and ETag or last-modified instead). A re-run
skips a log whose files with its current KEY exist (the report is written again from the cache); a new
output of a NAME removes the older one.

Progress: one line per finished log on stderr (with a progress bar on a terminal). A log that fails is
reported with its error and the others go on. Exit status: 0 every log succeeded, 1 one or more failed
(each listed at the end), 2 bad usage."""



def add_parsers(sub: argparse._SubParsersAction) -> None:
    """This group's verbs on the command line."""
    p = sub.add_parser("report", help="plots and tables of the slip study from one or more logs",
                       description="For each log and each maneuver phase in it (accelerate, cruise, brake): per "
                       "wheel, slip and speed against time, speed, force Fx, effective radius Re, stiffness Cx and "
                       "μ against slip as interactive plots (hover, zoom, legend), with the linear region's fitted "
                       "line and the end of linearity marked; a table of every maneuver and a summary table (peak "
                       "linear Fx and its slip, mean Re, peak and fitted Cx, r0, GPS latency, lost frames, bad "
                       "sentences); several logs compared side by side, grouped by their labels. Writes "
                       "DIR/index.html (opens offline: plotly.js and the data beside it), DIR/summary.json and "
                       "DIR/summary.csv; --png also the plots as PNG files." + OUTPUT_RULES)
    p.add_argument("logs", nargs="+", metavar="LOG.mcap")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="directory for the report (created)")
    p.add_argument("--group-by", action="append", metavar="KEY",
                   help="compare logs grouped by this label (repeatable; default: every label but maneuver)")
    p.add_argument("--live", action="store_true",
                   help="use the estimates as logged (default: each log is post-processed two-pass, as "
                   "`replay --two-pass` does, from its raw records, in memory; the logs are not changed)")
    p.add_argument("--png", action="store_true", help="also write the plots as PNG files (800x600, for documents; "
                   "needs matplotlib: pip install 'slipdaq[png]')")

    p = sub.add_parser("batch", help="many logs on Dask: Parquet dataset, fleet summary table, comparison report",
                       description=BATCH_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("logs", nargs="+", metavar="LOG.mcap", help="a path, or a URL (a glob in a URL is expanded)")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output directory (created), or a URL")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--scheduler", metavar="ADDRESS", help="run on the Dask cluster of this scheduler, e.g. "
                       "tcp://HOST:8786 (default: a local cluster on this machine, no server to start)")
    where.add_argument("--workers", type=_positive, metavar="N",
                       help="worker processes of the local cluster, one thread each (default: this machine's cores)")
    p.add_argument("--group-by", action="append", metavar="KEY",
                   help="compare logs grouped by this label (repeatable; default: every label but maneuver)")
    p.add_argument("--png", action="store_true", help="also write the report's plots as PNG files (needs matplotlib: "
                   "pip install 'slipdaq[png]')")


def cmd_report(args: argparse.Namespace) -> int:
    from slipdaq.report.build import make_report

    if args.png:
        _require_png()
    make_report(args.logs, args.output, group_by=args.group_by, progress=sys.stdout, two_pass=not args.live,
                png=args.png)
    return EXIT_OK


def cmd_batch(args: argparse.Namespace) -> int:
    from slipdaq.fleet.batch import FleetError, failure, run_batch

    if args.png:
        _require_png()
    try:
        res = run_batch(args.logs, args.output, scheduler=args.scheduler, workers=args.workers, group_by=args.group_by,
                        png=args.png)
    except FleetError as e:
        print(f"slipdaq: batch: {e}", file=sys.stderr)
        return EXIT_FAIL
    print(f"batch: {res.client.line()}", file=sys.stderr)
    report = f"; report {res.report}" if res.report else "; no report (no log succeeded)"
    print(f"batch: {len(res.done)} processed, {len(res.skipped)} up to date, {len(res.failed)} failed -> "
          f"{res.estimates}{report}")
    for r in res.failed:
        print(f"slipdaq: batch: failed: {failure(r)}", file=sys.stderr)
    return EXIT_FAIL if res.failed else EXIT_OK


COMMANDS = {"report": cmd_report, "batch": cmd_batch}
