#!/usr/bin/env python3
"""The garbage collector's collections and time in a slipdaq command's own process: `slipdaq ARGS` run as a child
(its __main__.main, interpreter start and exit included) with a `gc.callbacks` timer around each collection, once
with slipdaq's thresholds and once with Python's (700, 10, 10) in their place, in turns, --rounds times each; per
generation the collections and seconds, and the process's main-thread CPU. The processes the command forks are not
counted. Figures for docs/performance.md ("The garbage collector in offline runs").

    python -m benchmarks.gc_time [--rounds 2] -- replay LOG -o OUT.mcap

OUT (its -o or --output) must not exist: what each run writes there is removed before the next.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

CHILD = r"""
import gc, json, os, sys, time
spent, count, started = [0.0, 0.0, 0.0], [0, 0, 0], [0.0]
def timer(phase, info):
    if phase == "start":
        started[0] = time.perf_counter()
    else:
        spent[info["generation"]] += time.perf_counter() - started[0]
        count[info["generation"]] += 1
gc.callbacks.append(timer)
import slipdaq.__main__ as m
if sys.argv[1] == "python":
    m.OFFLINE_GC_THRESHOLD = (700, 10, 10)
out, sys.argv = sys.argv[2], ["slipdaq", *sys.argv[3:]]
try:
    code = m.main()
finally:
    with open(out, "w") as f:
        json.dump({"seconds": spent, "collections": count, "thread_s": time.thread_time()}, f)
"""
"""The child: THRESHOLDS ('slipdaq' or 'python') OUT_JSON ARGS."""


def _output_of(args: list[str]) -> Path | None:
    for flag in ("-o", "--output"):
        if flag in args and args.index(flag) + 1 < len(args):
            return Path(args[args.index(flag) + 1])
    return None


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("args", nargs=argparse.REMAINDER, help="the slipdaq command line (after --)")
    a = ap.parse_args()
    args = a.args[1:] if a.args[:1] == ["--"] else a.args
    out = _output_of(args)
    if out is not None and out.exists():
        ap.error(f"{out} exists: give an output path that does not (each run's output is removed before the next)")
    runs: dict[str, list[dict[str, object]]] = {"slipdaq": [], "python": []}
    with tempfile.TemporaryDirectory(prefix="slipdaq-gc-time-") as tmp:
        stats = Path(tmp) / "gc.json"
        for r in range(a.rounds):
            for side in (["slipdaq", "python"] if r % 2 == 0 else ["python", "slipdaq"]):
                subprocess.run([sys.executable, "-c", CHILD, side, str(stats), *args], check=True,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
                runs[side].append(json.loads(stats.read_text()))
                if out is not None and out.is_dir():
                    shutil.rmtree(out)
                elif out is not None:
                    out.unlink(missing_ok=True)
    print(f"\nThe garbage collector in `slipdaq {' '.join(args)}`'s own process, {a.rounds} rounds in turns, medians "
          f"(`python -m benchmarks.gc_time --rounds {a.rounds} -- {' '.join(args)}`)\n")
    print("| thresholds | collections (gen 0, 1, 2) | seconds (gen 0, 1, 2) | in all | main thread CPU |")
    print("|---|---:|---:|---:|---:|")
    for side, what in (("slipdaq", "slipdaq's (`__main__.OFFLINE_GC_THRESHOLD` for offline verbs)"),
                       ("python", "Python's (700, 10, 10)")):
        rs = runs[side]
        counts = [statistics.median(r["collections"][g] for r in rs) for g in range(3)]  # type: ignore[index]
        secs = [statistics.median(r["seconds"][g] for r in rs) for g in range(3)]  # type: ignore[index]
        total = statistics.median(sum(r["seconds"]) for r in rs)  # type: ignore[arg-type]
        cpu = statistics.median(r["thread_s"] for r in rs)  # type: ignore[misc]
        print(f"| {what} | {', '.join(f'{c:g}' for c in counts)} | {', '.join(f'{x:.3f}' for x in secs)} | "
              f"{total:.3f} s | {cpu:.2f} s |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
