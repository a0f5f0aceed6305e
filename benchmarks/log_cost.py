#!/usr/bin/env python3
"""What writing the log costs in a replay, this tree against a base revision, side by side in one run.

The raw log is benchmarks/replay_process.py's (written by the base's code into --work, made there if missing). Per
round, one process per side (the order reversed every other round), after its imports and numba's kernels are
loaded, replays the log: into a sink that takes nothing (its batch methods overridden too, so that no frame is
turned into objects), into an MCAP log (`offline.process_to_log`), and into a sink that records every call; then the
recorded calls are made on an McapLogSink alone, --repeats times (the least counts): the log's writing without the
estimator around it, the steadiest figure on a busy machine. CPU is process_time (every thread of the process), and
the main thread's own (thread_time: without the zstd worker thread; the replay into the MCAP log summarizes its
maneuvers in a forked process, whose CPU neither counts, where the replay into nothing summarizes them here). The
tables show medians over the rounds; the second, the sink alone's main-thread CPU by kind of call.

    python -m benchmarks.log_cost --base 6641212 [--seconds 300] [--rate-hz 1000] [--rounds 5]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from benchmarks.base_revision import ROOT, add_base_argument, in_turns, resolve, unpack

WORKER = """
import io, json, sys, time
from pathlib import Path
from slipdaq import compiled
from slipdaq.logformat.reader import config_from_log, iter_raw_batches
from slipdaq.offline.run import process, process_to_log
from slipdaq.sinks import Sink
from slipdaq.sinks.mcap_log import McapLogSink

class Nothing(Sink):
    def on_can_batch(self, batch): pass
    def on_wheel_batch(self, samples): pass
    def on_fast_slip_rows(self, rows, log_time_s): pass

CALLS = ("on_raw", "on_can_batch", "on_wheel_batch", "on_fix", "on_estimate", "on_fast_slip", "on_fast_slip_rows",
         "on_maneuver", "on_sensor", "on_diagnostics", "on_source_event")

class Recorder(Nothing):
    def __init__(self):
        self.calls = []
for name in CALLS:
    setattr(Recorder, name, (lambda n: lambda self, *args: self.calls.append((n, args)))(name))

raw, out, repeats = sys.argv[1], Path(sys.argv[2]), int(sys.argv[3])
cfg = config_from_log(raw)
compiled.prepare()
t0, m0 = time.process_time(), time.thread_time()
process(cfg, iter_raw_batches(raw), [Nothing()], stream=io.StringIO())
t1, m1 = time.process_time(), time.thread_time()
process_to_log(cfg, iter_raw_batches(raw), out, "replay", stream=io.StringIO())
t2, m2 = time.process_time(), time.thread_time()
recorder = Recorder()
process(cfg, iter_raw_batches(raw), [recorder], stream=io.StringIO())
sink_wall, sink_cpu, sink_main = [], [], []
for _ in range(repeats):
    w0, c0, s0 = time.perf_counter(), time.process_time(), time.thread_time()
    sink = McapLogSink(out, cfg, "replay")
    for name, args in recorder.calls:
        getattr(sink, name)(*args)
    sink.close()
    sink_wall.append(time.perf_counter() - w0)
    sink_cpu.append(time.process_time() - c0)
    sink_main.append(time.thread_time() - s0)
by_call = {}
for _ in range(repeats):  # the main thread's CPU per kind of call (a timer around each: apart from the runs above)
    sink = McapLogSink(out, cfg, "replay")
    spent = {}
    for name, args in recorder.calls:
        c0 = time.thread_time()
        getattr(sink, name)(*args)
        spent[name] = spent.get(name, 0.0) + time.thread_time() - c0
    sink.close()
    by_call = {k: min(v, by_call.get(k, v)) for k, v in spent.items()}
print(json.dumps({"nothing": t1 - t0, "log": t2 - t1, "nothing_main": m1 - m0, "log_main": m2 - m1,
                  "sink_wall": min(sink_wall), "sink_cpu": min(sink_cpu), "sink_main": min(sink_main),
                  "calls": by_call}))
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_base_argument(ap)
    ap.add_argument("--seconds", type=float, default=300.0)
    ap.add_argument("--rate-hz", type=float, default=1000.0)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--repeats", type=int, default=3, help="runs of the sink alone per round (the least counts)")
    ap.add_argument("--work", type=Path, default=None, help="replay_process.py's directory (default: a new one)")
    a = ap.parse_args()
    base = resolve(a.base)
    work = a.work or Path(tempfile.mkdtemp(prefix="log-cost-"))
    work.mkdir(parents=True, exist_ok=True)
    raw = work / f"raw-{a.seconds:g}s-{a.rate_hz:g}hz.mcap"
    if not raw.exists():
        subprocess.run([sys.executable, "-m", "benchmarks.replay_process", "--base", base, "--seconds",
                        str(a.seconds), "--rate-hz", str(a.rate_hz), "--rounds", "0", "--work", str(work)], check=True, cwd=ROOT)
    sides = {f"base {base}": unpack(base, work / f"base-{base}"), "this tree": ROOT / "src"}
    got: dict[str, list[dict[str, float]]] = {name: [] for name in sides}
    for r, name in in_turns(sides, a.rounds):
        out = subprocess.run([sys.executable, "-c", WORKER, str(raw), str(work / "log-cost-out.mcap"),
                              str(a.repeats)],
                             env=dict(os.environ, PYTHONPATH=str(sides[name])), check=True, capture_output=True,
                             text=True).stdout
        got[name].append(json.loads(out.strip().splitlines()[-1]))
        print(f"  round {r + 1} {name}: {got[name][-1]}", flush=True)
    frames = int(raw.with_suffix(".frames").read_text())
    print(f"\nA replay of {raw.name} ({frames:,} frames; {a.rounds} interleaved rounds, medians)\n")
    print("| side | CPU into a sink that takes nothing | CPU into an MCAP log | difference | main thread: into nothing "
          "| main thread: into the log | the sink alone, wall | the sink alone, CPU | the sink alone, main thread "
          "| frames written per second (wall) |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    med = {}
    for name, runs in got.items():
        m = med[name] = {k: statistics.median(r[k] for r in runs) for k in runs[0] if k != "calls"}
        diff = statistics.median(r["log"] - r["nothing"] for r in runs)
        print(f"| {name} | {m['nothing']:.2f} s | {m['log']:.2f} s | {diff:.2f} s | {m['nothing_main']:.2f} s "
              f"| {m['log_main']:.2f} s | {m['sink_wall']:.2f} s | {m['sink_cpu']:.2f} s | {m['sink_main']:.2f} s "
              f"| {frames / m['sink_wall']:,.0f} |")
    b, n = med[f"base {base}"], med["this tree"]
    print(f"| this tree / base | {n['nothing'] / b['nothing']:.2f} | {n['log'] / b['log']:.2f} | "
          f"| {n['nothing_main'] / b['nothing_main']:.2f} | {n['log_main'] / b['log_main']:.2f} "
          f"| {n['sink_wall'] / b['sink_wall']:.2f} | {n['sink_cpu'] / b['sink_cpu']:.2f} "
          f"| {n['sink_main'] / b['sink_main']:.2f} | |")
    calls = {name: {k: statistics.median(r["calls"].get(k, 0.0) for r in runs) for k in runs[0]["calls"]}
             for name, runs in got.items()}
    kinds = sorted(calls["this tree"], key=lambda k: -calls["this tree"][k])
    print("\nThe sink alone, the main thread's CPU by kind of call (the least of --repeats, medians):\n")
    print("| call | " + " | ".join(calls) + " | this tree / base |\n|---|" + "---:|" * (len(calls) + 1))
    for k in kinds:
        this, theirs = calls["this tree"][k], calls[f"base {base}"].get(k, 0.0)
        ratio = f"{this / theirs:.2f}" if theirs else ""
        print(f"| `{k}` | " + " | ".join(f"{c.get(k, 0.0):.3f} s" for c in calls.values()) + f" | {ratio} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
