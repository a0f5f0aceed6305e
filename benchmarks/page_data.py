#!/usr/bin/env python3
"""What a log's page data costs (`report.page_data.log_page`: each maneuver's figures and the overview, encoded into
the log's plots.js) and whether two trees write the same bytes: each log replayed two-pass and summarized in
process, as `slipdaq report` does, then `log_page` timed by a CPU timer (`time.process_time`), the least of
--repeat calls; the SHA-256 of each log's plots.js and of the comparison's compare.js. With --base REV the same in a
process of that revision's slipdaq, the two sides in turns, --rounds times each. Figures for docs/performance.md
("The report of a long log").

    python -m benchmarks.page_data LOG [LOG ...] [--rounds 2] [--repeat 3] [--base REV]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.base_revision import add_base_argument, in_turns, side_json, unpack


def _one(logs: list[Path], repeat: int) -> dict[str, Any]:
    """One side's round: log_page's least CPU per log and in all, and the scripts' hashes."""
    from slipdaq.report.build import read_log
    from slipdaq.report.labels import labels_of
    from slipdaq.report.page_data import compare_script, log_page
    from slipdaq.report.summary import compare, summarize_log

    summaries, fasts = [], []
    for i, p in enumerate(logs):
        d = read_log(p, True, maneuvers=True)
        summaries.append(summarize_log(d.rows, d.metadata, d.diagnostics, path=str(p), name=f"log{i}",
                                       labels=labels_of(d.metadata), fast=d.fast, sensors=d.sensors,
                                       found=d.maneuvers))
        fasts.append(d.fast)
    cpu, hashes = [], []
    for log, fast in zip(summaries, fasts):
        best = float("inf")
        for _ in range(repeat):
            t0 = time.process_time()
            script = log_page(log, fast).script
            best = min(best, time.process_time() - t0)
        cpu.append(best)
        hashes.append(hashlib.sha256(script).hexdigest()[:16])
    comparisons = compare(summaries) if len(summaries) > 1 else []
    both = compare_script(comparisons, summaries) if comparisons else b""
    return {"cpu_s": cpu, "plots_js": hashes, "compare_js": hashlib.sha256(both).hexdigest()[:16],
            "maneuvers": [len(s.maneuvers) for s in summaries]}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("logs", type=Path, nargs="+")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3, help="log_page calls per log and round (the least counts)")
    add_base_argument(ap)
    ap.add_argument("--one", action="store_true", help=argparse.SUPPRESS)  # a side's single round, as JSON
    a = ap.parse_args()
    if a.one:
        print(json.dumps(_one(a.logs, a.repeat)))
        return 0
    sides = {"this tree": Path(__file__).resolve().parents[1] / "src"}
    if a.base:
        sides[f"base {a.base}"] = unpack(a.base, Path(tempfile.gettempdir()) / f"slipdaq-base-{a.base}")
    got: dict[str, list[dict[str, Any]]] = {side: [] for side in sides}
    for r, side in in_turns(sides, a.rounds):
        one = side_json(sides[side], __file__, *map(str, a.logs), "--repeat", str(a.repeat), "--one")
        got[side].append(one)
        print(f"  round {r + 1} {side}: log_page " + ", ".join(f"{c:.3f} s" for c in one["cpu_s"]),
              file=sys.stderr)
    print(f"\nlog_page of each log, CPU, the least over {a.rounds} rounds of {a.repeat} calls "
          f"(`python -m benchmarks.page_data LOG ... --rounds {a.rounds} --repeat {a.repeat}"
          f"{' --base ' + a.base if a.base else ''}`)\n")
    names = list(sides)
    print("| log | maneuvers | " + " | ".join(f"{n}, CPU" for n in names) + " | plots.js the same bytes |")
    print("|---|---:|" + "---:|" * len(names) + "---|")
    first = got[names[0]][0]
    for i, log in enumerate(a.logs):
        cells = [f"{min(one['cpu_s'][i] for one in got[n]):.3f} s" for n in names]
        same = len({one["plots_js"][i] for n in names for one in got[n]}) == 1
        print(f"| {log.name} | {first['maneuvers'][i]} | " + " | ".join(cells) + f" | {'yes' if same else 'NO'} |")
    same_compare = len({one["compare_js"] for n in names for one in got[n]}) == 1
    print(f"\ncompare.js the same bytes on every side and round: {'yes' if same_compare else 'NO'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
