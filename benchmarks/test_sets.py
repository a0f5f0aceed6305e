#!/usr/bin/env python3
"""A brake test set against the simulator's truth. Per seed: six ABS stops (brake-abs, the brake
switch at 50 Hz, the IMU at 100 Hz, WPT at 500 Hz) from about 100 km/h, five within 2 km/h and one from 92 km/h, each
run through slipdaq's pipeline in process as `run` and `import` do, their /maneuver records fed in order to the test
set of `[[test.procedure]] brake 100-0` (runs 5, mfdd_window_kmh [80, 20]) as the report feeds a group's logs.

    python -m benchmarks.test_sets [--seeds 1,2,3] [--write]

Truth per counted stop: the simulator's stopping distance from its brake onset corrected to 100 km/h,
d·(100/v0)², and its MFDD between 80 and 20 km/h. Columns: runs counted and the 92 km/h stop excluded; the set's
mean corrected distance against the truth's mean; its CV against the truth's CV (points); whether the truth's mean
lies inside [F_ci_lo, F_ci_hi]; the set's mean MFDD against the truth's mean. Targets: 5 runs, complete, 0.2 m,
0.3 points, inside, 1 %.
The simulator's brake-abs starts braking from its module's BRAKE_TEST_SPEED_MPS, set here per stop.
--write puts the table into docs/accuracy.md between its test-sets markers.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
from pathlib import Path

import numpy as np

from slipdaq.config import ProcedureConfig
from slipdaq.live.demo import demo_config, demo_settings
from slipdaq.maneuver.record import Maneuver
from slipdaq.maneuver.test_set import TestSets
from slipdaq.pipeline import Pipeline
from slipdaq.sim import scenarios
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.truth import speed_at_onset_mps, stopping_distance_m, truth_series
from slipdaq.sinks import CollectingSink

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "accuracy.md"
BEGIN, END = "<!-- test sets table: begin -->", "<!-- test sets table: end -->"
STOPS_KMH = (100.4, 99.1, 92.0, 101.2, 99.8, 100.6)
PROCEDURE = ProcedureConfig(name="brake 100-0", kind="brake", target_speed_kmh=100.0, speed_tolerance_kmh=2.0,
                            runs=5, mfdd_window_kmh=[80, 20])
WINDOW_MPS = (80.0 / 3.6, 20.0 / 3.6)


def _mfdd_window_truth(truth: dict[str, np.ndarray], onset_s: float) -> float:
    """(vb² − ve²)/(2·(se − sb)) with the truth's distances where its speed falls to 80 and 20 km/h after the onset."""
    after = truth["time_s"] >= onset_s
    v, x = truth["speed_mps"][after], truth["distance_m"][after]
    falling = np.flatnonzero(np.diff(v) < 0)
    v, x = v[falling[0]:], x[falling[0]:]
    vb, ve = WINDOW_MPS
    sb, se = (float(np.interp(-s, -v, x)) for s in (vb, ve))  # v falls monotonically while braking
    return (vb * vb - ve * ve) / (2.0 * (se - sb))


def _stop(speed_kmh: float, seed: int, index: int) -> tuple[Maneuver | None, float, float]:
    """One stop's /maneuver record (reindexed as the set's index-th) and the truth's corrected distance and MFDD."""
    scenarios.BRAKE_TEST_SPEED_MPS = speed_kmh / 3.6
    cfg = demo_config("/dev/null", "chan", "brake-abs").with_overrides(test={"procedure": [PROCEDURE]})
    settings = SimSettings(**{**demo_settings("brake-abs").__dict__, "seed": 100 * seed + index})
    events = list(generate(cfg, "brake-abs", "paved", settings, 16.0))
    sink = CollectingSink()
    Pipeline(cfg, [sink]).run([e.record for e in events if e.record is not None])
    truth = truth_series([e.truth for e in events if e.truth is not None], 0.0)
    v0, d = speed_at_onset_mps(truth), stopping_distance_m(truth)
    assert v0 is not None and d is not None
    onset = float(truth["time_s"][np.flatnonzero(truth["brake_pressed"])[0]])
    brakes = [m for m in sink.maneuvers if m.kind == "brake"]
    m = dataclasses.replace(brakes[0], index=index) if len(brakes) == 1 else None
    return m, d * (100.0 / (v0 * 3.6)) ** 2, _mfdd_window_truth(truth, onset)


def seed_row(seed: int) -> str:
    sets = TestSets(demo_config("/dev/null", "chan", "brake-abs").with_overrides(test={"procedure": [PROCEDURE]}).test)
    truth_d: list[float] = []
    truth_mfdd: list[float] = []
    rec = None
    for k, v in enumerate(STOPS_KMH, start=1):
        m, d, mfdd = _stop(v, seed, k)
        if m is None:
            return f"| {seed} | stop from {v} km/h: not one brake maneuver | | | | |"
        rec = sets.add(m)
        if abs(v - 100.0) <= 2.0:
            truth_d.append(d)
            truth_mfdd.append(mfdd)
    assert rec is not None
    t_mean, t_cv = statistics.fmean(truth_d), 100 * statistics.stdev(truth_d) / statistics.fmean(truth_d)
    mean, cv = rec["stopping_distance_corrected_m_mean"], rec["stopping_distance_corrected_m_cv_percent"]
    lo, hi = rec["stopping_distance_corrected_m_ci_lo"], rec["stopping_distance_corrected_m_ci_hi"]
    excluded = "; ".join(f"{e['index']}: {e['reason']}" for e in rec["excluded"])
    return (f"| {seed} | {rec['runs_valid']} of {rec['runs_required']}, {'complete' if rec['complete'] else 'NOT complete'}"
            f"; excluded {excluded} | {mean:.2f} m vs {t_mean:.2f} m ({mean - t_mean:+.2f} m) | "
            f"{cv:.2f} % vs {t_cv:.2f} % ({cv - t_cv:+.2f} points) | [{lo:.2f}, {hi:.2f}] "
            f"{'holds' if lo <= t_mean <= hi else 'DOES NOT hold'} the truth | "
            f"{rec['mfdd_mps2_mean']:.3f} vs {statistics.fmean(truth_mfdd):.3f} m/s² "
            f"({100 * (rec['mfdd_mps2_mean'] / statistics.fmean(truth_mfdd) - 1):+.2f} %) |")


HEAD = ("| seed | runs | mean corrected distance (set vs truth) | CV | 95 % interval | MFDD 80-20 km/h |\n"
        "|---|---|---|---|---|---|")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", default="1,2,3")
    p.add_argument("--write", action="store_true")
    a = p.parse_args(argv)
    rows = [seed_row(int(s)) for s in a.seeds.split(",")]
    table = "\n".join([HEAD, *rows])
    print(table)
    if a.write:
        text = DOC.read_text(encoding="utf-8")
        if BEGIN not in text:
            text += f"\n{BEGIN}\n{END}\n"
        head, rest = text.split(BEGIN, 1)
        _, tail = rest.split(END, 1)
        DOC.write_text(f"{head}{BEGIN}\n{table}\n{END}{tail}", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
