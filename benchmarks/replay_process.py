#!/usr/bin/env python3
"""`slipdaq replay` as a whole process (interpreter start and imports included: the issue's definition of the replay
target), this tree against a base revision, side by side in one run.

A raw-only log (config, DBC, /can/raw batches, /nmea/raw) of --seconds of 4 WPT messages at --rate-hz each + 20 Hz
NMEA from the simulator's cycle is written once by the base's code (so both read the same file). Then, per round,
`python -m slipdaq replay RAW -o OUT` runs once for each side (the order reversed every other round, so that a busy
spell of the machine falls on both), each side's `src` on PYTHONPATH (the base from `git archive`). Wall time and
CPU time (user + system, of the child) per run; the table shows medians, frames/s of the median wall time, and the
ratio (with --two-pass also the first pass's wall time). The CPU is also split: the main thread's (time.thread_time
at its exit, start-up included) and that of the
processes it forks (the log's and the maneuver summaries'), which share the machine's other core: with both near the
wall time, neither side can go faster by moving work to the other. The child runs slipdaq's `__main__` as `-m` does
(runpy), with that reading at its exit. Each side's output is kept for the guard (benchmarks/replay_check.py compares
outputs the same way).

With --two-pass: `replay --two-pass` (two passes over the log, the second written), frames/s counting the log's
frames once. With --recorded: the log replayed is one as a run records it, its raw records and every derived topic
(/estimate, /slip/fast, /wpt/count, ...: about three messages for each raw one), which a replay reads past: the
raw-only log replayed once by the base.

A second table says what two cores allow each side: the least wall time of a run of that CPU whose start (taken as
`python -m slipdaq replay --help`'s wall time, timed after each run: less than the real start) runs on one core and
the rest on both, no less than its main thread's CPU; and the CPU over every process at which that bound meets the
target (500,000 frames/s, or 300,000 with --two-pass).

    python -m benchmarks.replay_process --base 6641212 [--seconds 300] [--rate-hz 1000] [--rounds 5] [--two-pass]
                                        [--recorded]
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.base_revision import ROOT, add_base_argument, in_turns, resolve, unpack

MAKE_LOG = """
import sys
from dataclasses import replace
from pathlib import Path
from slipdaq.config import load_config, packaged_config_path
from slipdaq.records import CanFrame
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sinks.mcap_log import McapLogSink
cfg = load_config(packaged_config_path())
sink = McapLogSink(Path(sys.argv[1]), cfg, mode="bench-raw")
settings = replace(SimSettings(), wpt_rate_hz=float(sys.argv[3]), gps_rate_hz=20.0, gps_latency_s=0.05,
                   can_jitter_s=0.0002)
frames = 0
for ev in generate(cfg, "cycle", "paved", settings, duration_s=float(sys.argv[2])):
    if ev.record is not None:
        sink.on_raw(ev.record)
        frames += isinstance(ev.record, CanFrame)
sink.close()
print(frames)
"""


def python_path(src: Path) -> str:
    """PYTHONPATH for a side: its src first, then what PYTHONPATH held (packages installed elsewhere)."""
    return os.pathsep.join([str(src), *filter(None, [os.environ.get("PYTHONPATH")])])


SPLIT = """
import resource, runpy, sys, time
out = sys.argv.pop(1)
sys.argv[0] = "slipdaq"
first = [0.0]
if "--two-pass" in sys.argv:  # the first pass's wall time (offline.run.first_pass, as replay_two_pass calls it)
    from slipdaq.offline import run
    def timed(*args, _first_pass=run.first_pass, **kwargs):
        t0 = time.perf_counter()
        try:
            return _first_pass(*args, **kwargs)
        finally:
            first[0] = time.perf_counter() - t0
    run.first_pass = timed
try:
    runpy.run_module("slipdaq", run_name="__main__", alter_sys=True)
finally:
    forked = resource.getrusage(resource.RUSAGE_CHILDREN)
    with open(out, "w") as f:
        f.write(f"{time.thread_time()} {forked.ru_utime + forked.ru_stime} {first[0]}")
"""
"""The child: `python -m slipdaq ARGS` as runpy runs it, then its main thread's CPU, its forked processes' and (with
--two-pass) the first pass's wall time into the file named first."""


def run_replay(src: Path, raw: Path, out: Path, *flags: str) -> tuple[float, float, float, float, float]:
    """(wall s, CPU s of the child, of its main thread, of the processes it forked, the first pass's wall s or 0) of
    one `slipdaq replay`."""
    split = out.with_suffix(".cpu")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", SPLIT, str(split), "replay", str(raw), "-o", str(out), *flags], check=True,
                   env=dict(os.environ, PYTHONPATH=python_path(src)), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    main_thread, forked, first = (float(x) for x in split.read_text().split())
    split.unlink()
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), main_thread, forked, first


def start_wall(src: Path) -> float:
    """Wall s of `python -m slipdaq replay --help` (the interpreter and the CLI's imports): less than a replay's start
    before its first record, which one core runs alone."""
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "slipdaq", "replay", "--help"], check=True, stdout=subprocess.DEVNULL,
                   env=dict(os.environ, PYTHONPATH=python_path(src)))
    return time.perf_counter() - t0


def two_core_bound(cpu_s: float, main_thread_s: float, start_s: float) -> float:
    """The least wall time two cores allow a run of cpu_s of CPU (every process) whose first start_s run on one core
    and whose main thread takes main_thread_s: both cores busy from the start's end to the last instruction."""
    return max(main_thread_s, start_s + (cpu_s - start_s) / 2)


def cpu_at_bound(wall_s: float, start_s: float) -> float:
    """The CPU (every process) whose two_core_bound is wall_s, its main thread no longer than that: its inverse."""
    return 2 * wall_s - start_s


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_base_argument(ap)
    ap.add_argument("--seconds", type=float, default=300.0, help="seconds of log (default 300)")
    ap.add_argument("--rate-hz", type=float, default=1000.0, help="each WPT message's rate (default 1000)")
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds (default 5)")
    ap.add_argument("--work", type=Path, default=None, help="directory for the logs (default: a temporary one)")
    ap.add_argument("--two-pass", action="store_true", help="replay --two-pass")
    ap.add_argument("--recorded", action="store_true", help="replay a log with every derived topic, as a run records it")
    a = ap.parse_args()
    flags = ["--two-pass"] if a.two_pass else []
    base = resolve(a.base)
    work = a.work or Path(tempfile.mkdtemp(prefix="replay-process-"))
    work.mkdir(parents=True, exist_ok=True)
    sides = {f"base {base}": unpack(base, work / f"base-{base}"), "this tree": ROOT / "src"}
    raw = work / f"raw-{a.seconds:g}s-{a.rate_hz:g}hz.mcap"
    frames_file = raw.with_suffix(".frames")
    if not raw.exists():
        made = subprocess.run([sys.executable, "-c", MAKE_LOG, str(raw), str(a.seconds), str(a.rate_hz)], check=True,
                              env=dict(os.environ, PYTHONPATH=python_path(sides[f"base {base}"])), capture_output=True,
                              text=True)
        frames_file.write_text(made.stdout.strip().splitlines()[-1])
    frames = int(frames_file.read_text())
    if a.recorded:
        recorded = work / f"recorded-{a.seconds:g}s-{a.rate_hz:g}hz.mcap"
        if not recorded.exists():
            run_replay(sides[f"base {base}"], raw, recorded)
        raw = recorded
    print(f"{raw.name}: {frames:,} frames, {raw.stat().st_size / 1e6:.1f} MB", flush=True)
    for src in sides.values():  # numba's cache for each tree, imports warm
        run_replay(src, raw, work / "warm.mcap", *flags)
    got: dict[str, list[tuple[float, float, float, float, float]]] = {name: [] for name in sides}
    starts: dict[str, list[float]] = {name: [] for name in sides}
    for r, name in in_turns(sides, a.rounds):
        got[name].append(run_replay(sides[name], raw, work / f"out-{name.split()[0]}.mcap", *flags))
        starts[name].append(start_wall(sides[name]))
        w, c, m, f, p1 = got[name][-1]
        print(f"  round {r + 1} {name}: {w:.2f} s wall, {c:.2f} s CPU (main thread {m:.2f} s, forked {f:.2f} s)"
              + f", first pass {p1:.2f} s" * a.two_pass + f"; start {starts[name][-1]:.2f} s", flush=True)
    med = {name: tuple(statistics.median(x[k] for x in v) for k in range(5)) for name, v in got.items()}
    start = {name: statistics.median(v) for name, v in starts.items()}
    b, n = med[f"base {base}"], med["this tree"]
    print(f"\n`python -m slipdaq replay{' --two-pass' * a.two_pass}` of {a.seconds:g} s of 4 × {a.rate_hz:g} Hz "
          f"+ 20 Hz NMEA ({frames:,} frames{', a recorded log: every derived topic in it' * a.recorded}), "
          f"{a.rounds} interleaved rounds, medians\n")
    first = " first pass (wall) |" * a.two_pass
    print(f"| side | wall | CPU (user + sys) | main thread | forked processes |{first} frames/s (wall) | frames/s (CPU) |"
          "\n|---|---:|---:|---:|---:|" + "---:|" * a.two_pass + "---:|---:|")
    for name, (w, c, m, f, p1) in med.items():
        print(f"| {name} | {w:.2f} s | {c:.2f} s | {m:.2f} s | {f:.2f} s |" + f" {p1:.2f} s |" * a.two_pass
              + f" {frames / w:,.0f} | {frames / c:,.0f} |")
    ratios = " | ".join(f"{x / y:.2f}" if y else "—" for x, y in zip(n[:4 + a.two_pass], b))  # a short log: no fork
    print(f"| this tree / base | {ratios} | {b[0] / n[0]:.2f}× | {b[1] / n[1]:.2f}× |")
    target = 300_000 if a.two_pass else 500_000
    print(f"\nWhat two cores allow (medians): the least wall time with both cores busy from the end of a start that "
          f"one core runs alone (taken as `replay --help`'s wall time, less than the real start) to the last "
          f"instruction, and no less than the main thread's CPU; the CPU over every process at which that bound "
          f"meets {target:,} frames/s.\n")
    print("| side | start (`replay --help`) | bound | frames/s at the bound | CPU for the target | of the side's CPU |"
          "\n|---|---:|---:|---:|---:|---:|")
    for name, (_, c, m, *_rest) in med.items():
        s, bound = start[name], two_core_bound(c, m, start[name])
        need = cpu_at_bound(frames / target, s)
        cells = f"{need:.2f} s | {need / c:.2f}" if need > s else "none: the start alone is longer | —"
        print(f"| {name} | {s:.2f} s | {bound:.2f} s | {frames / bound:,.0f} | {cells} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
