#!/usr/bin/env python3
"""A live run in the HIL VM, judged per window by its `quality`: cold (GPS latency "auto", no calibration) and with a
stored calibration, the host clock months off the sentences' UTC. Figures for docs/accuracy.md ("Live runs").

The run is a recorded one (tests/hil/data: the daemon's log of case 1 under host load, the frames and lines the
sender put out, the drive's truth), or the artifacts of a HIL run of one's own (`--data DIR`, as
SLIPDAQ_HIL_ARTIFACTS leaves them). Its raw records go through `slipdaq replay` with the changed config: live and
replay are one estimator, bit for bit, so this is what the daemon gives live from the same records. Each wheel window
above 5 m/s that the judge can judge (tests/hil/judge.py: the sender's own sampling lag small) is compared with the
truth; per quality: windows, RMS and worst |error|; the share of windows `ok`, and the worst `ok` windows.

    python benchmarks/live_recorded.py [--data tests/hil/data] [--write]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests" / "hil"), str(ROOT / "tests")]

from hil_support import read_log, read_sent, write_config  # noqa: E402
from judge import MIN_SPEED_MPS, judged, load_truth, wheel_frames  # noqa: E402

from doc_block import write_block  # noqa: E402
from slipdaq import WHEELS  # noqa: E402
from slipdaq.cli import main as slipdaq  # noqa: E402
from slipdaq.logformat.reader import iter_estimates  # noqa: E402
from slipdaq.sim.truth import slip_errors  # noqa: E402

DOC = ROOT / "docs" / "accuracy.md"
BEGIN, END = "<!-- live runs: begin -->", "<!-- live runs: end -->"


def replay(log: Path, tmp: Path, name: str, *calibration: str) -> list[dict[str, Any]]:
    """The log's raw records through `slipdaq replay` with the HIL config, GPS latency "auto"."""
    cfg = write_config(tmp, "/tmp/unused-gps")
    text, n = re.subn(r"^latency_s = .*$", 'latency_s = "auto"', cfg.read_text(), count=1, flags=re.M)
    assert n == 1
    cfg.write_text(text)
    out = tmp / f"{name}.mcap"
    with contextlib.redirect_stderr(io.StringIO()):
        rc = slipdaq(["replay", str(log), "--config", str(cfg), "-o", str(out), *calibration])
    assert rc == 0, name
    return list(iter_estimates(out))


def judge(rows: list[dict[str, Any]], truth: dict[str, np.ndarray], wheels: list[Any]) -> str:
    fast = [r for r in rows if r["speed_mps"] is not None and r["speed_mps"] > MIN_SPEED_MPS]
    by_quality: dict[str, list[tuple[float, str, float]]] = {}
    for w, frames in zip(WHEELS, wheels):
        for r in fast:
            e = slip_errors([r], truth, MIN_SPEED_MPS, wheels=[w]) if judged(r, frames) else np.empty(0)
            if e.size:
                by_quality.setdefault(r["quality"], []).append((r["time_s"] - rows[0]["time_s"], w, 100 * float(e[0])))
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
    ap.add_argument("--data", type=Path, default=ROOT / "tests" / "hil" / "data",
                    help="case1-live.mcap, case1-sent.csv, case1-truth.json.gz (default: the recorded run)")
    ap.add_argument("--write", action="store_true", help=f"write the table into {DOC.name}")
    a = ap.parse_args()
    log = a.data / "case1-live.mcap"
    truth = load_truth(a.data / "case1-truth.json.gz")
    wheels = wheel_frames(read_log(log), read_sent(a.data / "case1-sent.csv"))
    with tempfile.TemporaryDirectory(prefix="slipdaq-live-") as d:
        tmp = Path(d)
        cal = tmp / "calibration.toml"
        rows_cold = replay(log, tmp, "cold", "--no-calibration")
        replay(log, tmp, "learn", "--calibration", str(cal))  # a first run stores what it learned
        rows_stored = replay(log, tmp, "stored", "--calibration", str(cal))
    lines = ["| run | windows by quality: count (share), RMS and worst slip error | worst `ok` windows |",
             "|---|---|---|",
             f"| cold, off UTC | {judge(rows_cold, truth, wheels)} |",
             f"| stored calibration, off UTC | {judge(rows_stored, truth, wheels)} |"]
    block = (f"`python benchmarks/live_recorded.py` on `{a.data.relative_to(ROOT) if a.data.is_relative_to(ROOT) else a.data}`"
             f" (judged wheel windows above {MIN_SPEED_MPS:g} m/s; targets: `ok` <= 0.3 pts RMS, >= 60 % `ok`, "
             "none over 5 pts)\n\n" + "\n".join(lines))
    print(block)
    if a.write:
        write_block(DOC, BEGIN, END, "Live runs in the VM", block)
        print(f"written to {DOC}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
