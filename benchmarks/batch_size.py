#!/usr/bin/env python3
"""What a small batch costs: CAN frames through Pipeline.process_can_batch (the one path) in batches of 1, 4, 16,
64 and 256 frames (GPS lines between them one by one), with the per-sample kernels compiled by numba and run as
plain Python (SLIPDAQ_JIT=0). Figures for docs/architecture.md.

    python -m benchmarks.batch_size [--seconds 10] [--rounds 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

from slipdaq import compiled
from slipdaq.config import load_config, packaged_config_path
from slipdaq.pipeline import Pipeline
from slipdaq.records import CanFrame
from slipdaq.sim.emit import SimSettings, generate


def frames_per_s(cfg, records, batch: int) -> float:  # type: ignore[no-untyped-def]
    p = Pipeline(cfg, [])
    compiled.prepare()
    run: list[CanFrame] = []
    t0 = time.perf_counter()
    for r in records:
        if isinstance(r, CanFrame):
            run.append(r)
            if len(run) >= batch:
                p.process_can_batch(run)
                run = []
        else:
            if run:
                p.process_can_batch(run)
                run = []
            p.process(r)
    if run:
        p.process_can_batch(run)
    return sum(isinstance(r, CanFrame) for r in records) / (time.perf_counter() - t0)


def measure(cfg, records, batch: int, jit: bool, rounds: int) -> float:  # type: ignore[no-untyped-def]
    os.environ["SLIPDAQ_JIT"] = "1" if jit else "0"
    compiled.reset()
    return statistics.median(frames_per_s(cfg, records, batch) for _ in range(rounds))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=10.0, help="seconds of 4 x 500 Hz + 20 Hz GPS (default 10)")
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args()
    cfg = load_config(packaged_config_path())
    records = [ev.record for ev in generate(cfg, "cycle", "paved", SimSettings(wpt_rate_hz=500.0, gps_rate_hz=20.0),
                                            duration_s=a.seconds) if ev.record is not None]
    print("| frames per call | kernels compiled, frames/s | kernels as Python, frames/s | compiled / Python |")
    print("|---:|---:|---:|---:|")
    for batch in (1, 4, 16, 64, 256):
        jit = measure(cfg, records, batch, True, a.rounds)
        py = measure(cfg, records, batch, False, a.rounds)
        print(f"| {batch} | {jit:,.0f} | {py:,.0f} | {jit / py:.2f} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
