#!/usr/bin/env python3
"""`slipdaq report` of a long log as a whole process (interpreter start, imports, the two-pass replay, the summary,
the page and its files): wall time, CPU time (user + system) and peak resident memory (the child's ru_maxrss), this
tree and, with --base REV, that revision side by side in one run. Figures for docs/performance.md ("The report of a
long log"); the target: a 2-hour log of 4 WPT messages at 1 kHz each within 60 s.

The log (--hours of the simulator's `cycle` drive on paved, repeated back to back: 4 WPT messages at --rate-hz each,
20 Hz NMEA, a raw-only log as benchmarks/replay_process.py writes one) is written once into --work DIR and reused
by later runs with the same --hours and --rate-hz. Per round, `python -m slipdaq report LOG -o OUT` runs once for
each side (the order reversed every other round); round 0, untimed, warms .pyc files and numba's kernel cache.

--recorded: the log reported is one as a run records it (its raw records and every derived topic, which the report's
two passes read past): the raw-only log replayed once.

--fits ROUNDS: this tree's report after its summaries (the tire files' fits, the page's data, the report's files
written), in one process, with the tire files fitted one after the other (tires.fit_here) and on threads
(tires.ThreadFits, what `slipdaq report` does), in turns, the order reversed every round: wall and CPU time.

--parts: this tree's report once more, in one process, part by part (the two-pass replay, the maneuver summaries,
the page's data, the tire files' fits, the writing of the report's files), each part's wall and CPU time: the
tire files fitted one after the other (tires.fit_here), not on threads (tires.ThreadFits), so that each part has a
CPU time of its own.

    python -m benchmarks.report_long [--hours 2] [--rate-hz 1000] [--work DIR] [--base REV] [--rounds 1] [--parts]
                                     [--fits ROUNDS] [--recorded]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.base_revision import ROOT, unpack
from benchmarks.doc_block import machine
from benchmarks.replay_process import MAKE_LOG  # the same drive, written as the replay benchmark writes it

PARTS = """
import contextlib, functools, io, json, sys, time
from pathlib import Path
from slipdaq.report import build, page, page_data, tires, write
from slipdaq.report.labels import labels_of
log, out = Path(sys.argv[1]), Path(sys.argv[2])
spent = {}

def timed(owner, name, label):  # the seconds (wall, CPU) a function of the report takes, added up under label
    f = getattr(owner, name)
    @functools.wraps(f)
    def wrapper(*args, **kw):
        t, c = time.perf_counter(), time.process_time()
        try:
            return f(*args, **kw)
        finally:
            w0, c0 = spent.get(label, (0.0, 0.0))
            spent[label] = (w0 + time.perf_counter() - t, c0 + time.process_time() - c)
    setattr(owner, name, wrapper)

build.ThreadFits = lambda: contextlib.nullcontext(tires.fit_here)  # one part after the other: each one's CPU time
timed(build, "read_log", "two-pass replay (read_log)")
timed(build, "summarize_log", "maneuver summaries (summarize_log)")
timed(build, "log_page", "page data: figures and plots.js (log_page)")
timed(build, "place_log", "writing plots.js (place_log)")
timed(tires.TireJob, "fit", "tire files: MF 6.1 fits (TireJob.fit)")
timed(page_data, "write_assets", "writing plotly.min.js and the page's script")
timed(write, "table_rows", "summary table rows")
timed(write, "write_csv", "writing summary.csv")
timed(write, "write_json", "writing summary.json")
timed(page, "write_html", "writing index.html")
t, c = time.perf_counter(), time.process_time()
result = build.make_report([log], out, progress=io.StringIO(), two_pass=True)
whole = (time.perf_counter() - t, time.process_time() - c)
spent["the rest (tire jobs, test sets, moving files into place)"] = (
    whole[0] - sum(w for w, _ in spent.values()), whole[1] - sum(c for _, c in spent.values()))
spent["make_report in all"] = whole
print(json.dumps({"parts": spent, "estimates": result.logs[0].estimates, "maneuvers": len(result.logs[0].maneuvers)}))
"""

FITS = """
import contextlib, io, json, shutil, sys, time
from pathlib import Path
from slipdaq.report.build import place_log, read_log, write_report
from slipdaq.report.labels import labels_of
from slipdaq.report.page_data import log_page
from slipdaq.report.summary import summarize_log
from slipdaq.report.tires import ThreadFits, fit_here
log, out, rounds = Path(sys.argv[1]), Path(sys.argv[2]), int(sys.argv[3])
data = read_log(log, two_pass=True, progress=io.StringIO())
s = summarize_log(data.rows, data.metadata, data.diagnostics, path=str(log), name=log.stem,
                  labels=labels_of(data.metadata), fast=data.fast, sensors=data.sensors)
fitters = {"in turn (tires.fit_here)": lambda: contextlib.nullcontext(fit_here), "on threads (tires.ThreadFits)": ThreadFits}
got = {k: [] for k in fitters}
for r in range(rounds):
    for name in (list(fitters) if r % 2 == 0 else list(fitters)[::-1]):
        shutil.rmtree(out, ignore_errors=True)
        t, c = time.perf_counter(), time.process_time()
        page = log_page(s, data.fast)
        with fitters[name]() as fits:  # as make_report
            write_report([s], out, plot=lambda lg, d: place_log(lg, d, page), fit_tires=fits)
        got[name].append((time.perf_counter() - t, time.process_time() - c))
        print(json.dumps({"round": r + 1, "fits": name, "wall_s": got[name][-1][0], "cpu_s": got[name][-1][1]}),
              flush=True)
print(json.dumps({"fits": got}))
"""


def python_path(src: Path) -> str:
    """PYTHONPATH for a side: its src first, then what PYTHONPATH held (packages installed elsewhere)."""
    return os.pathsep.join([str(src), *filter(None, [os.environ.get("PYTHONPATH")])])


def run_measured(cmd: list[str], env: dict[str, str]) -> tuple[float, float, float]:
    """(wall s, CPU s (user + system), peak resident MB) of cmd run as its own process."""
    t = time.perf_counter()
    p = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t
    err = p.stderr.read().decode(errors="replace") if p.stderr else ""
    if p.stderr:
        p.stderr.close()
    p.returncode = os.waitstatus_to_exitcode(status)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({p.returncode}): {err[-2000:]}")
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss * 1024 / 1e6  # ru_maxrss: KiB


def make_log(work: Path, hours: float, rate_hz: float, recorded: bool = False) -> tuple[Path, int]:
    """The drive's raw-only log in work (written once) and its WPT frames; recorded: the log as a run records it,
    its raw records and every derived topic (the raw-only log replayed once by this tree, also kept)."""
    log = work / f"drive-{hours:g}h-{rate_hz:g}hz.mcap"
    frames_file = log.with_suffix(".frames")
    if not (log.exists() and frames_file.exists()):
        t = time.perf_counter()
        made = subprocess.run([sys.executable, "-c", MAKE_LOG, str(log), str(hours * 3600.0), str(rate_hz)],
                              check=True, env=dict(os.environ, PYTHONPATH=python_path(ROOT / "src")),
                              capture_output=True, text=True)
        frames_file.write_text(made.stdout.strip().splitlines()[-1])
        print(f"wrote {log.name} in {time.perf_counter() - t:.0f} s", flush=True)
    frames = int(frames_file.read_text())
    if recorded:
        raw, log = log, work / f"recorded-{hours:g}h-{rate_hz:g}hz.mcap"
        if not log.exists():
            subprocess.run([sys.executable, "-m", "slipdaq", "replay", str(raw), "-o", str(log)], check=True,
                           env=dict(os.environ, PYTHONPATH=python_path(ROOT / "src")), capture_output=True)
    return log, frames


def tree_mb(d: Path) -> dict[str, float]:
    """MB of each file in d (recursively, by path relative to d), largest first."""
    got = {p.relative_to(d).as_posix(): p.stat().st_size / 1e6 for p in d.rglob("*") if p.is_file()}
    return dict(sorted(got.items(), key=lambda kv: -kv[1]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--hours", type=float, default=2.0, help="hours of log (default 2)")
    ap.add_argument("--rate-hz", type=float, default=1000.0, help="each WPT message's rate (default 1000)")
    ap.add_argument("--work", type=Path, default=None,
                    help="directory for the log (kept and reused) and the reports (default: a temporary one)")
    ap.add_argument("--base", default=None, metavar="REV", help="that revision's report too, side by side")
    ap.add_argument("--rounds", type=int, default=1, help="timed rounds (default 1; 0: none, with --parts or --fits)")
    ap.add_argument("--parts", action="store_true", help="this tree's report part by part, in one process")
    ap.add_argument("--recorded", action="store_true",
                    help="report a log as a run records it (raw and derived topics), not a raw-only one")
    ap.add_argument("--fits", type=int, default=0, metavar="ROUNDS",
                    help="the report after its summaries with the tire files fitted in turn and on threads, ROUNDS each")
    a = ap.parse_args()
    work = a.work or Path(tempfile.mkdtemp(prefix="slipdaq-report-long-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        log, frames = make_log(work, a.hours, a.rate_hz, a.recorded)
        print(f"{log.name}: {frames:,} WPT frames, {log.stat().st_size / 1e6:.0f} MB", flush=True)
        common = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        common["PYTHONPYCACHEPREFIX"] = str(work / "pycache")
        sides = {"this tree": dict(common, PYTHONPATH=python_path(ROOT / "src"))}
        if a.base:
            sides[f"base {a.base}"] = dict(common, PYTHONPATH=python_path(unpack(a.base, work / f"base-{a.base}")))
        got: dict[str, list[tuple[float, float, float]]] = {name: [] for name in sides}
        for r in range(a.rounds + 1):
            for name in (list(sides) if r % 2 == 0 else list(sides)[::-1]):
                out = work / f"report-{list(sides).index(name)}"
                shutil.rmtree(out, ignore_errors=True)
                if r == 0:  # warm-up: a short log's report (.pyc, numba's cache), untimed
                    short, _ = make_log(work, 60.0 / 3600.0, a.rate_hz)
                    run_measured([sys.executable, "-m", "slipdaq", "report", str(short), "-o", str(out)], sides[name])
                    shutil.rmtree(out)
                    continue
                got[name].append(run_measured([sys.executable, "-m", "slipdaq", "report", str(log), "-o", str(out)],
                                              sides[name]))
                w, c, m = got[name][-1]
                print(f"round {r} {name}: {w:.1f} s wall, {c:.1f} s CPU, {m:.0f} MB peak", flush=True)
        med = {n: tuple(statistics.median(x[k] for x in v) for k in range(3)) for n, v in got.items() if v}
        load = os.getloadavg()
        print(f"\n`python -m benchmarks.report_long {' '.join(sys.argv[1:])}`: `python -m slipdaq report` of "
              f"{a.hours:g} h of the cycle drive, 4 × {a.rate_hz:g} Hz WPT + 20 Hz NMEA ({frames:,} frames, log "
              f"{log.stat().st_size / 1e6:.0f} MB); median of {a.rounds}; {machine()}; load average "
              f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f} at the end\n")
        if med:
            print("| tree | wall | CPU (user + sys) | peak RSS | log s per wall s |\n|---|---:|---:|---:|---:|")
        for name, (w, c, m) in med.items():
            print(f"| {name} | {w:.1f} s | {c:.1f} s | {m:.0f} MB | {a.hours * 3600 / w:.0f} |")
        summary: dict[str, object] = {
            "hours": a.hours, "rate_hz": a.rate_hz, "frames": frames, "log_mb": log.stat().st_size / 1e6,
            "load_average": load, "sides": {n: {"wall_s": w, "cpu_s": c, "peak_rss_mb": m} for n, (w, c, m) in
                                            med.items()}}
        if a.parts:
            out = work / "report-parts"
            shutil.rmtree(out, ignore_errors=True)
            p = subprocess.run([sys.executable, "-c", PARTS, str(log), str(out)], check=True, capture_output=True,
                               text=True, env=sides["this tree"])
            parts = json.loads(p.stdout.strip().splitlines()[-1])
            whole_cpu = parts["parts"]["make_report in all"][1]
            print(f"\nthis tree's report part by part, in one process ({parts['estimates']:,} estimates, "
                  f"{parts['maneuvers']} maneuvers):\n\n| part | wall s | CPU s | share of CPU |\n|---|---:|---:|---:|")
            for k, (w, c) in parts["parts"].items():
                print(f"| {k} | {w:.1f} | {c:.1f} | {100 * c / whole_cpu:.0f} % |")
            summary["parts"] = parts
        if a.fits:
            out = work / "report-fits"
            p = subprocess.run([sys.executable, "-c", FITS, str(log), str(out), str(a.fits)], check=True,
                               capture_output=True, text=True, env=sides["this tree"])
            fits = json.loads(p.stdout.strip().splitlines()[-1])["fits"]
            print(f"\nthe report after its summaries (the tire files' fits, the page's data, the files written), "
                  f"in one process, {a.fits} interleaved rounds, medians:\n\n"
                  "| tire files fitted | wall | CPU |\n|---|---:|---:|")
            for name, v in fits.items():
                print(f"| {name} | {statistics.median(w for w, _ in v):.1f} s | "
                      f"{statistics.median(c for _, c in v):.1f} s |")
            summary["fits"] = fits
        written = work / ("report-0" if med else "report-parts" if a.parts else "report-fits")
        files = tree_mb(written)
        summary["report_mb"], summary["largest_files_mb"] = sum(files.values()), dict(list(files.items())[:5])
        print(f"\nthe report: {sum(files.values()):.1f} MB; its largest files: "
              + ", ".join(f"{k} {v:.1f} MB" for k, v in list(files.items())[:5]))
        print("\n" + json.dumps(summary))
    finally:
        if not a.work:
            shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
