#!/usr/bin/env python3
"""Reading a log's raw records as a replay reads them (`logformat.reader.iter_raw_batches`: every chunk scanned and
checked, the raw topics' messages decoded), in process, this tree against a base revision, each in a process of its
own (its `src` on PYTHONPATH), the trees in turns; per log, the median and least of --passes passes. Figures for
docs/performance.md ("Reading the log").

    python -m benchmarks.read_log LOG [LOG ...] [--base REV] [--passes 7] [--rounds 2] [--work DIR]

LOG: a raw-only log (benchmarks.replay_process writes one), or a log as a run records it (its --recorded log).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.base_revision import ROOT, add_base_argument, in_turns, resolve, side_json, unpack


def passes(log: Path, n: int) -> list[float]:
    """Wall seconds of n passes of iter_raw_batches over log (this process's slipdaq)."""
    from slipdaq.logformat.reader import iter_raw_batches

    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        for _batch in iter_raw_batches(log):
            pass
        out.append(time.perf_counter() - t0)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", type=Path, nargs="+", metavar="LOG")
    add_base_argument(ap)
    ap.add_argument("--passes", type=int, default=7, help="passes over each log per round (default 7)")
    ap.add_argument("--rounds", type=int, default=2, help="rounds, the trees in turns (default 2)")
    ap.add_argument("--work", type=Path, default=None, help="where the base is unpacked (default: a temporary one)")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        print(json.dumps({str(log): passes(log, a.passes) for log in a.logs}))
        return 0
    base = resolve(a.base)
    work = a.work or Path(tempfile.mkdtemp(prefix="read-log-"))
    sides = {f"base {base}": unpack(base, work / f"base-{base}"), "this tree": ROOT / "src"}
    got: dict[str, dict[str, list[float]]] = {name: {str(log): [] for log in a.logs} for name in sides}
    for r, name in in_turns(sides, a.rounds):
        out = side_json(sides[name], __file__, *map(str, a.logs), "--passes", str(a.passes), "--child")
        for log, times in out.items():
            got[name][log] += times
        print(f"  round {r + 1} {name} done", flush=True)
    print(f"\n`iter_raw_batches` over each log, in process, {a.rounds} rounds of {a.passes} passes, median (least)\n")
    print("| log | " + " | ".join(sides) + " | this tree / base |\n|---|" + "---:|" * (len(sides) + 1))
    for log in map(str, a.logs):
        med = {name: statistics.median(got[name][log]) for name in sides}
        cells = " | ".join(f"{med[n]:.3f} s ({min(got[n][log]):.3f})" for n in sides)
        print(f"| {Path(log).name} | {cells} | {med['this tree'] / med[f'base {base}']:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
