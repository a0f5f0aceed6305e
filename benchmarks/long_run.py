#!/usr/bin/env python3
"""A test day's run, time-compressed: the simulator's cycle drive (an acceleration from standstill to 60 km/h, 3 s of
cruise and a stop, every 15 s, repeated back to back with counters and times running on) through the import path,
not in real time. Figures for docs/reliability.md ("A day's run").

Hours (default): the drive is generated in this process and fed as `slipdaq import` feeds a log (offline.batched,
read_ahead, Pipeline.process_all) into an MCAP log; per hour of log (--hour-s of it, 3600 s by default): the seconds
the pipeline and the log took for it (the simulator's own time left out), the peak and end resident memory, the
maneuvers decided and the log's chunks. Memory and seconds per hour must not grow from one hour to the next.

    python -m benchmarks.long_run [--hours 10] [--hour-s 3600] [--wpt-rate-hz 1000] [--gps-rate-hz 10]

Import target (--import-target): the same drive written as a candump -L and an NMEA log of --short-min and
--long-min minutes (default 4.4 and 70), each imported by `python -m slipdaq import` in its own process (with
--base REV, that revision's import too, side by side): wall time and peak resident memory (the child's ru_maxrss);
the long one may take at most 16.8 x the time (16 x the data) and 5 MB more memory.

    python -m benchmarks.long_run --import-target [--wpt-rate-hz 1000] [--base REV] [--rounds 1] [--work DIR]

The imported logs stay in --work DIR as out-0-short.mcap, out-0-long.mcap (this tree), out-1-... (--base).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

from benchmarks.base_revision import ROOT, unpack
from benchmarks.doc_block import machine
from slipdaq.allocator import fix_malloc_thresholds

MAKE_LOGS = """
import sys
from dataclasses import replace
from pathlib import Path
from slipdaq.config import load_config, packaged_config_path
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.logs import write_drive_logs
cfg = load_config(packaged_config_path())
s = replace(SimSettings(), wpt_rate_hz=float(sys.argv[3]), gps_rate_hz=10.0, gps_latency_s=0.05, can_jitter_s=0.0002)
write_drive_logs(generate(cfg, "cycle", "paved", s, duration_s=float(sys.argv[4])), Path(sys.argv[1]), Path(sys.argv[2]))
"""
TIME_RATIO_MAX = 16.8
RSS_MORE_MAX_MB = 5.0


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


@dataclass
class Hour:
    hour: int
    pipeline_s: float
    rss_peak_mb: float
    rss_end_mb: float
    maneuvers: int
    chunks: int


def hours(n_hours: int, hour_s: float, wpt_rate_hz: float, gps_rate_hz: float, log: Path) -> tuple[list[Hour], float]:
    """The drive through the import path into a log at `log`, hour by hour; also the simulator's own seconds."""
    from slipdaq import compiled
    from slipdaq.config import load_config, packaged_config_path
    from slipdaq.offline.run import batched, read_ahead
    from slipdaq.pipeline import Pipeline
    from slipdaq.sim.emit import SimSettings, generate
    from slipdaq.sinks.mcap_log import McapLogSink

    cfg = load_config(packaged_config_path())
    settings = replace(SimSettings(), wpt_rate_hz=wpt_rate_hz, gps_rate_hz=gps_rate_hz, gps_latency_s=0.05,
                       can_jitter_s=0.0002)
    sink = McapLogSink(log, cfg, mode="import", metadata={})
    pipeline = Pipeline(cfg, [sink])
    compiled.prepare()
    sim_s = 0.0
    t0_s: float | None = None
    source = generate(cfg, "cycle", "paved", settings, duration_s=n_hours * hour_s)

    def records():  # type: ignore[no-untyped-def]
        nonlocal sim_s
        t = time.perf_counter()
        for e in source:
            if e.record is not None:
                nonlocal t0_s
                t0_s = e.record.timestamp_s if t0_s is None else t0_s  # the log's first record: hours count from it
                sim_s += time.perf_counter() - t
                yield e.record
                t = time.perf_counter()

    out: list[Hour] = []
    spent = peak = 0.0
    made = maneuvers = 0
    writer = sink.log._writer  # the MCAP writer: its statistics count the chunks

    def close_hour() -> None:
        nonlocal spent, peak, made, maneuvers
        chunks = writer._stats.chunk_count
        out.append(Hour(len(out) + 1, spent, peak, rss_mb(), pipeline.maneuver_count - maneuvers, chunks - made))
        print(f"hour {out[-1].hour}: {spent:.1f} s, RSS peak {peak:.1f} MB, end {out[-1].rss_end_mb:.1f} MB, "
              f"{out[-1].maneuvers} maneuvers (sim {sim_s:.0f} s so far)", flush=True)
        spent, peak, made, maneuvers = 0.0, 0.0, chunks, pipeline.maneuver_count

    for run in read_ahead(batched(records())):  # the run is read (simulated) before the clock starts
        t = time.perf_counter()
        pipeline.process_all(run)
        spent += time.perf_counter() - t
        assert pipeline.last_time_s is not None and t0_s is not None
        peak = max(peak, rss_mb())
        if pipeline.last_time_s - t0_s >= (len(out) + 1) * hour_s:
            close_hour()
    t = time.perf_counter()
    pipeline.finish()
    sink.close()
    spent += time.perf_counter() - t
    if spent > 0 and len(out) < n_hours:
        close_hour()
    return out, sim_s


def hours_table(rows: list[Hour], hour_s: float) -> str:
    unit = "hour" if hour_s == 3600 else f"{hour_s / 60:g} min"
    out = [f"| {unit} | seconds | × first | RSS peak MB | RSS end MB | maneuvers | log chunks |",
           "|---:|---:|---:|---:|---:|---:|---:|"]
    first = rows[0].pipeline_s
    for h in rows:
        out.append(f"| {h.hour} | {h.pipeline_s:.1f} | {h.pipeline_s / first:.2f} | {h.rss_peak_mb:.1f} | "
                   f"{h.rss_end_mb:.1f} | {h.maneuvers} | {h.chunks} |")
    return "\n".join(out)


def run_measured(cmd: list[str], env: dict[str, str]) -> tuple[float, float]:
    """(wall seconds, peak resident MB) of cmd run as its own process."""
    t = time.perf_counter()
    p = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({status}): {p.stderr.read().decode()[-2000:] if p.stderr else ''}")
    if p.stderr:
        p.stderr.close()
    p.returncode = os.waitstatus_to_exitcode(status)
    return wall, usage.ru_maxrss / 1024 * 1.048576  # kB (KiB) -> MB


def import_target(a: argparse.Namespace) -> int:
    tmp = a.work or Path(tempfile.mkdtemp(prefix="slipdaq-longrun-", dir=a.tmp_dir))
    tmp.mkdir(parents=True, exist_ok=True)
    try:
        common = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        common["PYTHONPYCACHEPREFIX"] = str(tmp / "pycache")
        env = dict(common, PYTHONPATH=str(ROOT / "src"))
        for f in ("slipdaq.toml", "wpt.dbc", "sensors.dbc"):
            shutil.copy(ROOT / "config" / f, tmp / f)
        lengths = {"short": a.short_min, "long": a.long_min}
        for key, minutes in lengths.items():
            if a.work and (tmp / f"{key}.nmea").exists():  # written by an earlier run with the same options
                continue
            t = time.perf_counter()
            subprocess.run([sys.executable, "-c", MAKE_LOGS, str(tmp / f"{key}.log"), str(tmp / f"{key}.nmea"),
                            str(a.wpt_rate_hz), str(minutes * 60)], env=env, check=True)
            print(f"wrote {minutes:g} min of 4 x {a.wpt_rate_hz:g} Hz + 10 Hz NMEA in {time.perf_counter() - t:.0f} s",
                  flush=True)
        trees = {"this tree": env}
        if a.base:
            trees[a.base] = dict(common, PYTHONPATH=str(unpack(a.base, tmp / f"base-{a.base}")))
        results: dict[tuple[str, str], list[tuple[float, float]]] = {}
        for r in range(a.rounds + 1):  # round 0, the short log only: .pyc files, numba's kernel cache, untimed
            for name, tree_env in trees.items():
                for key in lengths if r else ["short"]:
                    cmd = [sys.executable, "-m", "slipdaq", "import", "--can", str(tmp / f"{key}.log"), "--nmea",
                           str(tmp / f"{key}.nmea"), "--config", str(tmp / "slipdaq.toml"), "-o",
                           str(tmp / f"out-{list(trees).index(name)}-{key}.mcap"), "--no-calibration"]
                    got = run_measured(cmd, tree_env)
                    print(f"round {r}: {name}, {lengths[key]:g} min: {got[0]:.2f} s, {got[1]:.1f} MB", flush=True)
                    if r:
                        results.setdefault((name, key), []).append(got)
        print(f"\n{machine()}; load {os.getloadavg()[0]:.1f}; 4 x {a.wpt_rate_hz:g} Hz + 10 Hz NMEA, median of "
              f"{a.rounds}\n")
        print(f"| tree | {a.short_min:g} min: s | MB | {a.long_min:g} min: s | MB | time × | memory + MB |")
        print("|---|---:|---:|---:|---:|---:|---:|")
        ok = True
        for name in trees:
            (ws, ms), (wl, ml) = (_median(results[name, k]) for k in lengths)
            print(f"| {name} | {ws:.2f} | {ms:.1f} | {wl:.2f} | {ml:.1f} | {wl / ws:.1f} | {ml - ms:+.1f} |")
            if name == "this tree":
                ok = wl / ws <= TIME_RATIO_MAX and ml - ms <= RSS_MORE_MAX_MB
        print(f"\ntarget (time × <= {TIME_RATIO_MAX}, memory <= +{RSS_MORE_MAX_MB:g} MB): {'met' if ok else 'MISSED'}")
        return 0 if ok else 1
    finally:
        if not a.work:
            shutil.rmtree(tmp, ignore_errors=True)


def _median(xs: list[tuple[float, float]]) -> tuple[float, float]:
    w = sorted(x[0] for x in xs)
    m = sorted(x[1] for x in xs)
    return w[len(w) // 2], m[len(m) // 2]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--hours", type=int, default=10, help="hours of log (default 10)")
    ap.add_argument("--hour-s", type=float, default=3600.0, help="seconds of log per row of the table (default 3600)")
    ap.add_argument("--wpt-rate-hz", type=float, default=1000.0, help="frames per second per wheel (default 1000)")
    ap.add_argument("--gps-rate-hz", type=float, default=10.0)
    ap.add_argument("--import-target", action="store_true", help="the import of --short-min against --long-min")
    ap.add_argument("--short-min", type=float, default=4.4)
    ap.add_argument("--long-min", type=float, default=70.0)
    ap.add_argument("--rounds", type=int, default=1, help="timed rounds of the import target (default 1)")
    ap.add_argument("--base", default=None, metavar="REV", help="the import target of this revision too")
    ap.add_argument("--tmp-dir", default=None)
    ap.add_argument("--work", type=Path, default=None,
                    help="the import target's directory: its logs are kept there and reused (default: a temporary one)")
    a = ap.parse_args()
    fix_malloc_thresholds()  # as the process of slipdaq run or import does (slipdaq/allocator.py)
    if a.import_target:
        return import_target(a)
    with tempfile.TemporaryDirectory(dir=a.tmp_dir) as tmp:
        t = time.perf_counter()
        rows, sim_s = hours(a.hours, a.hour_s, a.wpt_rate_hz, a.gps_rate_hz, Path(tmp) / "day.mcap")
        log_mb = (Path(tmp) / "day.mcap").stat().st_size / 1e6
    print(f"\n`python -m benchmarks.long_run {' '.join(sys.argv[1:])}`: {a.hours} x {a.hour_s:g} s of the cycle drive, "
          f"4 x {a.wpt_rate_hz:g} Hz + {a.gps_rate_hz:g} Hz NMEA, log {log_mb:.0f} MB; {time.perf_counter() - t:.0f} s "
          f"in all ({sim_s:.0f} s of it the simulator's); {machine()}; load {os.getloadavg()[0]:.1f} at the end\n")
    print(hours_table(rows, a.hour_s))
    return 0


if __name__ == "__main__":
    sys.exit(main())
