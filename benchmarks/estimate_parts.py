#!/usr/bin/env python3
"""Where a GPS fix's CPU goes in the estimator: `offline.process` of a raw log in process (no sink, kernels warm, the
collector's objects frozen), a CPU timer (time.thread_time) around each call of the estimate's parts; per part, the
seconds in all, the calls, and the microseconds a call and a fix. With --base REV, the same for that revision (its
`src` on PYTHONPATH, in a process of its own), the trees in turns, --rounds times each. Figures for
docs/performance.md ("Per GPS epoch").

    python -m benchmarks.estimate_parts RAW [--base REV] [--rounds 2]

RAW: a raw-only log, as benchmarks/replay_process.py writes one (its --work keeps it: raw-300s-1000hz.mcap).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.base_revision import ROOT, add_base_argument, under, unpack

PARTS = (
    ("slipdaq.estimator.slip", "SlipEstimator.add_gps", "a fix into the estimator (add_gps)"),
    ("slipdaq.estimator.slip", "SlipEstimator._estimate", "an estimate"),
    ("slipdaq.estimator.slip", "measure_window", "the window (measure_window)"),
    ("slipdaq.estimator.latency", "WheelLatencyRows.observe", "the latency rows"),
    ("slipdaq.estimator.slip", "wheel_estimate", "a wheel's estimate"),
    ("slipdaq.estimator.stiffness", "StiffnessFit.add", "a stiffness fit's window"),
    ("slipdaq.estimator.slip", "SlipEstimator._fast_fix", "the high-rate rows"),
)
"""(module, name in it, label): each is wrapped where the estimator calls it."""


def measure(raw: Path) -> dict[str, Any]:
    """This process's slipdaq: the parts' CPU over one offline.process of raw."""
    import gc
    import importlib

    from slipdaq import compiled
    from slipdaq.logformat.reader import config_from_log, iter_raw_batches, read_metadata
    from slipdaq.offline import run

    seconds: dict[str, float] = {}
    calls: dict[str, int] = {}
    for module, name, label in PARTS:
        owner: Any = importlib.import_module(module)
        *path, attr = name.split(".")
        for part in path:
            owner = getattr(owner, part)
        original = getattr(owner, attr)

        def timed(*args: Any, _original: Any = original, _label: str = label, **kwargs: Any) -> Any:
            t = time.thread_time()
            try:
                return _original(*args, **kwargs)
            finally:
                seconds[_label] = seconds.get(_label, 0.0) + time.thread_time() - t
                calls[_label] = calls.get(_label, 0) + 1

        setattr(owner, attr, timed)
    config = config_from_log(raw)
    start = run.start_calibration(read_metadata(raw), raw)
    compiled.prepare()
    gc.freeze()
    items = list(iter_raw_batches(raw))
    t = time.thread_time()
    with open(os.devnull, "w") as quiet:
        run.process(config, items, [], stream=quiet, calibration=start)
    return {"total_s": time.thread_time() - t, "seconds": seconds, "calls": calls}


def table(name: str, got: dict[str, Any]) -> str:
    fixes = got["calls"]["a fix into the estimator (add_gps)"]
    lines = [f"{name}: offline.process, no sink, {got['total_s']:.2f} s of CPU, {fixes} fixes", "",
             "| part | CPU | calls | µs a call | µs a fix |", "|---|---:|---:|---:|---:|"]
    for _module, _name, label in PARTS:
        s, n = got["seconds"].get(label, 0.0), got["calls"].get(label, 0)
        lines.append(f"| {label} | {s:.3f} s | {n:,} | {s / max(n, 1) * 1e6:.1f} | {s / max(fixes, 1) * 1e6:.1f} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("raw", type=Path, help="a raw-only log")
    add_base_argument(ap)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--side", action="store_true", help=argparse.SUPPRESS)  # one measurement, as JSON (a child's)
    a = ap.parse_args()
    if a.side:
        print(json.dumps(measure(a.raw)))
        return
    with tempfile.TemporaryDirectory(prefix="estimate-parts-") as tmp:
        sides = {"this tree": ROOT / "src"}
        if a.base:
            sides[f"base {a.base}"] = unpack(a.base, Path(tmp) / "base")
        for r in range(a.rounds):
            for name, src in (sides.items() if r % 2 == 0 else reversed(sides.items())):
                cmd, env = under(src, __file__, str(a.raw), "--side")
                out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True).stdout
                print(table(f"round {r + 1}, {name}", json.loads(out.splitlines()[-1])), "\n", flush=True)


if __name__ == "__main__":
    main()
