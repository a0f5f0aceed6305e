#!/usr/bin/env python3
"""`slipdaq run`'s CPU and frame → estimate latency, this tree against a base revision, in turns in one run.

Each run is `benchmarks.perf_cpu`'s (the loopback-UDP bus read as SocketCAN, a sender process, 20 Hz NMEA on a
pseudo-terminal, the daemon's CPU from /proc over the sending window), at the default read interval; the daemon runs
with one side's `src` on PYTHONPATH (the base from `git archive`). Per load, `--rounds` rounds of both sides, the
order reversed every other round so that a busy spell falls on both; the table gives each run's CPU share and p99,
and their medians.

    python -m benchmarks.perf_cpu_base --base REV [--rates 4000,9000] [--rounds 4] [--seconds 20]
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np

from benchmarks.base_revision import ROOT, add_base_argument, in_turns, resolve, side_json, unpack


def _side(argv: list[str]) -> int:
    """One run with the slipdaq on this process's path: its result as a JSON line."""
    from benchmarks.perf_cpu import run_cpu

    ap = argparse.ArgumentParser()
    ap.add_argument("--rate", type=float, required=True)
    ap.add_argument("--seconds", type=float, required=True)
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="slipdaq-cpu-") as td:
        r = run_cpu(argparse.Namespace(cpu_seconds=a.seconds, cpu_profile=None), Path(td), a.rate, "side")
    p99 = float(np.percentile(r.latency.frame_ms, 99)) if r.latency is not None and r.latency.frame_ms else None
    print(json.dumps({"cpu": r.cpu_share, "p99_ms": p99, "sent": r.frames_sent, "logged": r.frames_logged,
                      "lost": r.lost}))
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "_side":
        return _side(argv[1:])
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_base_argument(ap)
    ap.add_argument("--rates", default="4000,9000", help="total WPT frames/s of each load (default 4000,9000)")
    ap.add_argument("--rounds", type=int, default=4, help="rounds of both sides per load (default 4)")
    ap.add_argument("--seconds", type=float, default=20.0, help="seconds per run (default 20)")
    a = ap.parse_args(argv)
    base = resolve(a.base)
    work = Path(tempfile.mkdtemp(prefix="perf-cpu-base-"))
    sides = {"this tree": ROOT / "src", f"base {base}": unpack(base, work / f"base-{base}")}
    rows = []
    for rate in (float(x) for x in a.rates.split(",")):
        got: dict[str, list[dict[str, float]]] = {name: [] for name in sides}
        for r, name in in_turns(sides, a.rounds):
            got[name].append(side_json(sides[name], __file__, "_side", "--rate", str(rate), "--seconds", str(a.seconds)))
            g = got[name][-1]
            print(f"  {rate:g} frames/s, round {r + 1}, {name}: CPU {g['cpu']:.1f} %, p99 {g['p99_ms']} ms, "
                  f"{g['logged']:,} of {g['sent']:,} logged, {g['lost']} lost", flush=True)
        for name, runs in got.items():
            cpu = [g["cpu"] for g in runs]
            p99 = [g["p99_ms"] for g in runs if g["p99_ms"] is not None]
            rows.append(f"| {rate:,.0f} frames/s + 20 Hz NMEA | {name} | {', '.join(f'{c:.1f}' for c in cpu)} "
                        f"(median {statistics.median(cpu):.1f}) | {', '.join(f'{p:.2f}' for p in p99)} "
                        f"(median {statistics.median(p99):.2f}) |")
    print(f"\n`python -m benchmarks.perf_cpu_base {' '.join(argv)}`: {a.rounds} rounds per load, the sides in turns "
          f"(reversed every other round), {a.seconds:g} s each, default read interval\n")
    print("| load | side | CPU, % of one core, per run | frame → estimate p99, ms, per run |\n|---|---|---|---|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
