#!/usr/bin/env python3
"""A live run in the HIL VM, judged per window by its `quality`: cold (GPS latency "auto", no calibration) and with a
stored calibration, the host clock months off the sentences' UTC. Figures for docs/accuracy.md ("Live runs").

The runs are recorded ones (tests/hil/data and tests/hil/data/loaded: the daemon's log of case 1 under host load,
the frames the sender put out, the drive's truth), or the artifacts of HIL runs of one's own (`--data DIR ...`, as
SLIPDAQ_HIL_ARTIFACTS leaves them). Its raw records go through `slipdaq replay` with the changed config: live and
replay are one estimator, bit for bit, so this is what the daemon gives live from the same records. Each wheel window
above 5 m/s that the judge can judge (tests/hil/judge.py: the sender's own sampling lag small) is compared with the
truth; per quality: windows, RMS and worst |error|; the share of windows `ok`, and the worst `ok` windows.

    python -m benchmarks.live_recorded [--data tests/hil/data tests/hil/data/loaded] [--write]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests" / "hil"), str(ROOT / "tests")]  # the VM suite's judge (tests/hil: not a package)

from judge import MIN_SPEED_MPS  # noqa: E402
from live_quality import RecordedRun, cold_and_stored, errors_by_quality  # noqa: E402

from benchmarks.doc_block import write_block  # noqa: E402

DOC = ROOT / "docs" / "accuracy.md"
BEGIN, END = "<!-- live runs: begin -->", "<!-- live runs: end -->"
RUNS = {ROOT / "tests" / "hil" / "data": "recorded run (20 s)",
        ROOT / "tests" / "hil" / "data" / "loaded": "recorded under heavy host load (60 s)"}


def judge(rows: list[dict[str, Any]], run: RecordedRun) -> str:
    by_quality = errors_by_quality(rows, run)
    total = sum(len(v) for v in by_quality.values())
    cells = []
    for q, v in sorted(by_quality.items(), key=lambda kv: kv[0] != "ok"):
        err = np.array([x[2] for x in v])
        cells.append(f"{q}: {len(v)} ({100 * len(v) / total:.0f} %), RMS {np.sqrt(np.mean(err ** 2)):.3f}, "
                     f"worst {np.max(np.abs(err)):.2f} pts")
    worst = sorted(by_quality.get("ok", []), key=lambda x: -abs(x[2]))[:3]
    where = ", ".join(f"{w} at {t:.1f} s {e:+.2f}" for t, w, e in worst)
    return "; ".join(cells) + (f" | worst ok windows: {where}" if worst else " |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, nargs="+", default=list(RUNS),
                    help="folders of case1-live.mcap, case1-sent.csv, case1-truth.json.gz (default: the two recorded "
                         "runs)")
    ap.add_argument("--write", action="store_true", help=f"write the table into {DOC.name}")
    a = ap.parse_args()
    lines = ["| run | windows by quality: count (share), RMS and worst slip error | worst `ok` windows |",
             "|---|---|---|"]
    for folder in a.data:
        name = RUNS.get(folder.resolve(), str(folder))
        run = RecordedRun.load(folder)
        with tempfile.TemporaryDirectory(prefix="slipdaq-live-") as d:
            cold, stored = cold_and_stored(run, Path(d))
        lines += [f"| {name}: cold, off UTC | {judge(cold, run)} |",
                  f"| {name}: stored calibration, off UTC | {judge(stored, run)} |"]
    where = ", ".join(f"`{f.resolve().relative_to(ROOT) if f.resolve().is_relative_to(ROOT) else f}`" for f in a.data)
    block = (f"`python -m benchmarks.live_recorded` on {where} (judged wheel windows above {MIN_SPEED_MPS:g} m/s; "
             "targets: `ok` <= 0.3 pts RMS, >= 60 % `ok`, none over 5 pts)\n\n" + "\n".join(lines))
    print(block)
    if a.write:
        write_block(DOC, BEGIN, END, "Live runs in the VM", block)
        print(f"written to {DOC}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
