#!/usr/bin/env python3
"""The wheels' GPS latency fit (estimator/latency.py) from all of a drive's rows and from the start from standstill's
rows alone, on the simulator at the HIL VM's rates (WPT 25 frames/s, GPS 10 Hz, true latency 0, host clock 3 s off
UTC), with and without the GPS speed noise, per seed. In the VM the start from standstill's rows alone gave −5 to
−6 ms in every run (docs/accuracy.md, "Live runs in the VM"); this shows what the simulator gives for the same rows.

Each row the estimator adds to its fit during a pipeline run is kept; the lag is then refitted over the rows of the
chosen speeds (the wheels' speed over the row, 0.9–4.8 m/s by default), without forgetting and without the estimator's
clamp at 0 (the parabolic minimum of the residual on the 1 ms grid).

    python -m benchmarks.latency_rows [--seeds 1,...,8] [--speeds 0.9,4.8] [--noise 0.02]
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

import numpy as np

import slipdaq.estimator.latency as latency
from slipdaq.config import load_config
from slipdaq.pipeline import Pipeline
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sinks import CollectingSink

ROOT = Path(__file__).resolve().parents[1]
Row = tuple[float, np.ndarray, bool]
ROW_INTERVAL_S = 0.1


def rows_of_a_drive(seed: int, noise_mps: float, wpt_rate_hz: float, duration_s: float) -> tuple[list[Row], float]:
    """The rows the estimator's wheel latency fit took over the simulated cycle, and its grid's largest lag."""
    rows: list[Row] = []
    add = latency.WheelLatency.add

    def keep(self: latency.WheelLatency, y: float, x: np.ndarray, informative: bool = False,
             accel_mps2: float = 0.0) -> None:
        rows.append((y, np.array(x), informative))
        add(self, y, x, informative, accel_mps2)

    cfg = load_config(ROOT / "config" / "slipdaq.toml")
    settings = SimSettings(wpt_rate_hz=wpt_rate_hz, gps_rate_hz=10.0, seed=seed, gps_noise_mps=noise_mps,
                           gps_latency_s=0.0, host_clock_offset_s=3.0)
    records = [e.record for e in generate(cfg, "cycle", "paved", settings, duration_s) if e.record is not None]
    latency.WheelLatency.add = keep  # type: ignore[method-assign]
    try:
        Pipeline(cfg, [CollectingSink()]).run(records)
    finally:
        latency.WheelLatency.add = add  # type: ignore[method-assign]
    return rows, cfg.estimator.max_latency_s


def lag_ms(rows: list[Row], max_latency_s: float) -> float:
    """The lag minimising the fit's residual over these rows (no forgetting, no clamp at 0)."""
    fit = latency.WheelLatency(max_latency_s, forgetting=1.0)
    for y, x, informative in rows:
        latency.WheelLatency.add(fit, y, x, informative)
    resid, _ = fit.residuals()
    j = int(np.argmin(resid))
    return 1000.0 * float(fit.taus_s[j] + latency.parabolic_minimum(resid, j, fit.step_s)[0])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="1,2,3,4,5,6,7,8")
    ap.add_argument("--speeds", default="0.9,4.8", help="the rows' wheel speeds, m/s: LOW,HIGH")
    ap.add_argument("--noise", type=float, default=0.02, help="GPS speed noise, m/s (the HIL drive's)")
    ap.add_argument("--wpt-rate-hz", type=float, default=25.0)
    ap.add_argument("--duration", type=float, default=20.0)
    args = ap.parse_args()
    low, high = (float(x) for x in args.speeds.split(","))
    zero = int(round(latency.NEGATIVE_LAG_S * 1000))  # the grid's index of lag 0

    def at_speeds(rows: list[Row]) -> list[Row]:
        return [r for r in rows if low <= r[1][zero] * latency.NOMINAL_RADIUS_M / ROW_INTERVAL_S <= high]

    print(f"WPT {args.wpt_rate_hz:g}/s, GPS 10 Hz, true latency 0; lag in ms from all rows and from the rows at "
          f"{low:g}-{high:g} m/s\n")
    print(f"| drive | all rows, GPS noise {args.noise:g} m/s | {low:g}-{high:g} m/s | all rows, no GPS noise | "
          f"{low:g}-{high:g} m/s |\n|---|---:|---:|---:|---:|")
    cells: list[list[float]] = []
    for seed in (int(s) for s in args.seeds.split(",")):
        row = []
        for noise in (args.noise, 0.0):
            rows, max_lat = rows_of_a_drive(seed, noise, args.wpt_rate_hz, args.duration)
            row += [lag_ms(rows, max_lat), lag_ms(at_speeds(rows), max_lat)]
        cells.append(row)
        print(f"| seed {seed} | " + " | ".join(f"{x:+.2f}" for x in row) + " |", flush=True)
    cols = list(zip(*cells))
    print("| mean | " + " | ".join(f"{statistics.mean(c):+.2f}" for c in cols) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
