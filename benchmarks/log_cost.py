#!/usr/bin/env python3
"""What writing the log costs in a replay: CPU of `offline.process_to_log` (the MCAP sink) minus the same run into a
sink that takes nothing, this tree against a base revision, side by side in one run.

The raw log is benchmarks/replay_process.py's (written by the base's code into --work, made there if missing). Per
round, one process per side (the order reversed every other round) reads the log twice after its imports and
numba's kernels are loaded: once into a sink that takes nothing (its batch methods overridden too, so that no frame
is turned into objects), once into an MCAP log; CPU time (process_time: every thread of the process) of each. The
table shows medians over the rounds and their difference, the log's cost.

    python benchmarks/log_cost.py --base 6641212 [--seconds 300] [--rate-hz 1000] [--rounds 5]
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from base_revision import ROOT, add_base_argument, resolve, unpack  # noqa: E402

WORKER = """
import io, json, sys, time
from pathlib import Path
from slipdaq import compiled
from slipdaq.logformat.reader import config_from_log, iter_raw_batches
from slipdaq.offline import process, process_to_log
from slipdaq.sinks import Sink

class Nothing(Sink):
    def on_can_batch(self, batch): pass
    def on_wheel_batch(self, samples): pass
    def on_fast_slip_rows(self, rows, log_time_s): pass

raw, out = sys.argv[1], Path(sys.argv[2])
cfg = config_from_log(raw)
compiled.prepare()
t0 = time.process_time()
process(cfg, iter_raw_batches(raw), [Nothing()], stream=io.StringIO())
t1 = time.process_time()
process_to_log(cfg, iter_raw_batches(raw), out, "replay", stream=io.StringIO())
t2 = time.process_time()
print(json.dumps({"nothing": t1 - t0, "log": t2 - t1}))
"""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_base_argument(ap)
    ap.add_argument("--seconds", type=float, default=300.0)
    ap.add_argument("--rate-hz", type=float, default=1000.0)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--work", type=Path, default=None, help="replay_process.py's directory (default: a new one)")
    a = ap.parse_args()
    base = resolve(a.base)
    work = a.work or Path(tempfile.mkdtemp(prefix="log-cost-"))
    work.mkdir(parents=True, exist_ok=True)
    raw = work / f"raw-{a.seconds:g}s-{a.rate_hz:g}hz.mcap"
    if not raw.exists():
        subprocess.run([sys.executable, str(Path(__file__).parent / "replay_process.py"), "--base", base, "--seconds",
                        str(a.seconds), "--rate-hz", str(a.rate_hz), "--rounds", "0", "--work", str(work)], check=True)
    sides = {f"base {base}": unpack(base, work / f"base-{base}"), "this tree": ROOT / "src"}
    got: dict[str, list[dict[str, float]]] = {name: [] for name in sides}
    for r in range(a.rounds):
        for name in (list(sides) if r % 2 == 0 else list(sides)[::-1]):
            out = subprocess.run([sys.executable, "-c", WORKER, str(raw), str(work / "log-cost-out.mcap")],
                                 env=dict(os.environ, PYTHONPATH=str(sides[name])), check=True, capture_output=True,
                                 text=True).stdout
            got[name].append(json.loads(out.strip().splitlines()[-1]))
            print(f"  round {r + 1} {name}: {got[name][-1]}", flush=True)
    print(f"\nCPU of a replay of {raw.name} ({a.rounds} interleaved rounds, medians)\n")
    print("| side | into a sink that takes nothing | into an MCAP log | the log's cost |\n|---|---:|---:|---:|")
    cost = {}
    for name, runs in got.items():
        nothing, log = (statistics.median(r[k] for r in runs) for k in ("nothing", "log"))
        cost[name] = statistics.median(r["log"] - r["nothing"] for r in runs)
        print(f"| {name} | {nothing:.2f} s | {log:.2f} s | {cost[name]:.2f} s |")
    print(f"| this tree / base | | | {cost['this tree'] / cost[f'base {base}']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
