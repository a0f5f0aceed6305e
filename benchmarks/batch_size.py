#!/usr/bin/env python3
"""What a batch of one costs: CAN frames through Pipeline.process_can_batch in batches of 1, 4, 16, 64 frames, by
the per-frame path (below scalar_max_frames, today's default) and forced through the batch path (numpy decode,
unwrap and estimator readiness). The figure that decides whether the per-frame twin can go: docs/architecture.md.

    python benchmarks/batch_size.py [--seconds 10] [--rounds 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

from slipdaq.config import load_config, packaged_config_path
from slipdaq.pipeline import SCALAR_MAX_FRAMES, Pipeline
from slipdaq.records import CanFrame
from slipdaq.sim.emit import SimSettings, generate


def frames_per_s(cfg, records, scalar_max: int, batch: int) -> float:  # type: ignore[no-untyped-def]
    p = Pipeline(cfg, [])
    p.scalar_max_frames = scalar_max
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


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=10.0, help="seconds of 4 x 500 Hz + 20 Hz GPS (default 10)")
    ap.add_argument("--rounds", type=int, default=3)
    a = ap.parse_args()
    cfg = load_config(packaged_config_path())
    records = [ev.record for ev in generate(cfg, "cycle", "paved", SimSettings(wpt_rate_hz=500.0, gps_rate_hz=20.0),
                                            duration_s=a.seconds) if ev.record is not None]
    print("| frames per call | per-frame path, frames/s | batch path, frames/s | batch / per-frame |")
    print("|---:|---:|---:|---:|")
    for batch in (1, 4, 16, 64):
        per_frame = statistics.median(frames_per_s(cfg, records, SCALAR_MAX_FRAMES, batch) for _ in range(a.rounds))
        batched = statistics.median(frames_per_s(cfg, records, 0, batch) for _ in range(a.rounds))
        print(f"| {batch} | {per_frame:,.0f} | {batched:,.0f} | {batched / per_frame:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
