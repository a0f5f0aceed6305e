#!/usr/bin/env python3
"""The live /maneuver records against the simulator's truth. Each row simulates a drive and runs
it through slipdaq's pipeline in process, as `run`, `import` and `replay` do: the records are those a live run logs.

    python -m benchmarks.maneuvers [--seeds 1,2,3] [--tires 1.17:0.17,...] [--write]

Rows (per road and seed):
  ABS stop 80       brake-abs from 80 km/h with the brake switch (50 Hz) and the IMU (100 Hz), WPT at 500 Hz: brake
                    speed, stopping distance and MFDD against the truth; valid against a target of 80 +- 2; how long
                    after the stop the record was decided (its log time)
  test day          test-day (0-60, 60-0, 0-33, 33-0 km/h; WPT 100 Hz, GPS 10 Hz, no brake switch): maneuvers found,
                    the largest speed error (from/to against 0, 60, 33), MFDD of each stop against the truth; valid
                    against 60 and 33 +- 3; each stop invalid against 50 +- 2 with its reason
  mu-slip           each tire's mu peak (% of the tire's) and slip at the peak (points) on brake-abs-all (every wheel
                    at its limit), brake-abs (the rear axle at its limit: brake_front_share 0.7), brake-abs front
                    (the front axle at its limit: 0.85, or 0.9 or 0.95 where a high mu needs it) and launch-spin;
                    the method that gave them, or why none (mu_flag); on the paved and sand tires and on each of
                    --tires (peak mu : slip at the peak [: the curve's shape C], a curve of the simulator's form)
Targets: MFDD within 1 % (ABS) and 3 % (test day), stopping distance within 0.5 m and brake speed within 1 km/h (ABS),
exactly 2 + 2 maneuvers with speeds within 3 km/h (test day); mu peak within 5 % and slip at peak within 2 points,
no unflagged mu above the tire's (ABS).
--write puts the table into docs/accuracy.md between its maneuver-table markers.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from slipdaq.config import Config, load_config
from slipdaq.live.demo import demo_config, demo_settings
from slipdaq.maneuver.record import Maneuver
from slipdaq.pipeline import Pipeline
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.scenarios import limiting_axle
from slipdaq.sim.truth import mfdd_mps2, speed_at_onset_mps, stopping_distance_m, tire_peak, truth_series
from slipdaq.sim.vehicle import ROADS, TireModel
from slipdaq.sinks import CollectingSink

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "accuracy.md"
BEGIN, END = "<!-- maneuvers table: begin -->", "<!-- maneuvers table: end -->"


class _Timed(CollectingSink):
    """Keeps each maneuver with the log time it was decided at."""

    def __init__(self) -> None:
        super().__init__()
        self.decided_s: list[float] = []

    def on_maneuver(self, maneuver: Maneuver, log_time_s: float) -> None:
        super().on_maneuver(maneuver, log_time_s)
        self.decided_s.append(log_time_s)


def run(cfg: Config, scenario: str, road: str, settings: SimSettings, duration_s: float):  # type: ignore[no-untyped-def]
    events = list(generate(cfg, scenario, road, settings, duration_s))  # type: ignore[arg-type]
    sink = _Timed()
    Pipeline(cfg, [sink]).run([e.record for e in events if e.record is not None])
    truth = truth_series([e.truth for e in events if e.truth is not None], 0.0)
    t0 = next(e.record.timestamp_s for e in events if e.record is not None)
    return sink, truth, t0


def targets(cfg: Config, speeds: list[float], tol: float) -> Config:
    return cfg.with_overrides(test={"target_speeds_kmh": speeds, "speed_tolerance_kmh": tol})


def abs_row(road: str, seed: int) -> str:
    cfg = targets(demo_config("/dev/null", "chan", "brake-abs"), [80.0], 2.0)
    settings = SimSettings(**{**demo_settings("brake-abs").__dict__, "seed": seed})
    sink, truth, t0 = run(cfg, "brake-abs", road, settings, 14.0)
    ms = sink.maneuvers
    if [m.kind for m in ms] != ["brake"]:
        return f"| ABS stop 80 | {road} | {seed} | maneuvers {[m.kind for m in ms]} | | | | |"
    m = ms[0]
    v0, d, mfdd = speed_at_onset_mps(truth), stopping_distance_m(truth), mfdd_mps2(truth)
    stop = float(truth["time_s"][np.flatnonzero(truth["speed_mps"] <= 0.0)[0]])
    return (f"| ABS stop 80 | {road} | {seed} | brake speed {m.brake_speed_kmh - v0 * 3.6:+.2f} km/h | "  # type: ignore[operator]
            f"stopping distance {m.stopping_distance_m - d:+.2f} m | MFDD {100 * (m.mfdd_mps2 / mfdd - 1):+.2f} % | "  # type: ignore[operator]
            f"{'valid' if m.valid else 'INVALID: ' + '; '.join(m.invalid_reasons)} | "
            f"decided {sink.decided_s[0] - t0 - stop:.1f} s after the stop |")


def _truth_stop(truth: dict, t_from: float, t_to: float) -> float | None:
    keep = (truth["time_s"] >= t_from) & (truth["time_s"] < t_to)
    part = {k: v[keep] for k, v in truth.items()}
    part["brake_pressed"] = part["accel_mps2"] < -1e-9
    return mfdd_mps2(part)


def test_day_row(road: str, seed: int) -> str:
    cfg = targets(load_config(ROOT / "config" / "slipdaq.toml"), [60.0, 33.0], 3.0)
    settings = SimSettings(gps_latency_s=0.0, gps_noise_mps=0.02, can_jitter_s=0.0005, seed=seed)
    sink, truth, _t0 = run(cfg, "test-day", road, settings, 40.0)
    ms = sink.maneuvers
    kinds = [m.kind for m in ms]
    if kinds != ["accelerate", "brake", "accelerate", "brake"]:
        return f"| test day | {road} | {seed} | maneuvers {kinds} | | | | |"
    expected = [(0.0, 60.0), (60.0, 0.0), (0.0, 33.0), (33.0, 0.0)]
    speed_err = max(max(abs(m.speed_from_kmh - a), abs(m.speed_to_kmh - b)) for m, (a, b) in zip(ms, expected))
    # the stops in sim time: after the first top speed, after the second (the profile's own timing, any road)
    t_top = [float(truth["time_s"][i]) for i in (np.argmax(truth["speed_mps"]),)]
    second = truth["time_s"] > t_top[0] + 8.0
    t2 = float(truth["time_s"][second][np.argmax(truth["speed_mps"][second])])
    mfdds = [_truth_stop(truth, t_top[0], t2 - 5.0), _truth_stop(truth, t2, t2 + 15.0)]
    mfdd_err = [100 * (m.mfdd_mps2 / t - 1) for m, t in zip((ms[1], ms[3]), mfdds)]  # type: ignore[operator]
    valid = all(m.valid for m in ms)
    sink50 = CollectingSink()
    events = generate(targets(cfg, [50.0], 2.0), "test-day", road, settings, 40.0)  # type: ignore[arg-type]
    Pipeline(targets(cfg, [50.0], 2.0), [sink50]).run(e.record for e in events if e.record is not None)
    stops50 = [m for m in sink50.maneuvers if m.kind == "brake"]
    invalid50 = all(not m.valid and any("brake speed" in r for r in m.invalid_reasons) for m in stops50)
    return (f"| test day | {road} | {seed} | 2 + 2 maneuvers, speeds within {speed_err:.2f} km/h | "
            f"MFDD {mfdd_err[0]:+.2f} %, {mfdd_err[1]:+.2f} % | against 60, 33 +- 3: "
            f"{'all valid' if valid else 'NOT all valid'} | against 50 +- 2: "
            f"{'both stops invalid (brake speed)' if invalid50 and len(stops50) == 2 else 'NOT as expected'} | |")


FRONT_LIMITED_SHARES = (0.85, 0.9, 0.95)
"""brake_front_share of the "brake-abs front" row: the first of these with which the front axle reaches its peak first
(sim/scenarios.py's limiting_axle; a higher mu transfers more load forward), the rear staying on its hydraulic share
(the issue's front-only ABS stop)."""


def add_tire(spec: str) -> str:
    """A simulator road whose tire peaks at mu at slip_peak (TireModel, shape C): "MU:SLIP_PEAK[:C]"; its name."""
    mu, peak, *shape = (float(x) for x in spec.split(":"))
    c = shape[0] if shape else TireModel.C
    name = f"tire {mu:g} at {100 * peak:g} %" + (f" C {c:g}" if shape else "")
    ROADS[name] = TireModel.with_peak(mu, peak, c)
    return name


def mu_row(scenario: str, road: str, seed: int) -> str:
    """Each tire's mu peak and slip at peak (live /maneuver) against the simulator's tire; the method and flags.
    "brake-abs front": brake-abs with the front axle at its limit (FRONT_LIMITED_SHARES)."""
    front = scenario == "brake-abs front"
    scenario = "brake-abs" if front else scenario
    cfg = demo_config("/dev/null", "chan", scenario)
    if front:
        shares = [x for x in FRONT_LIMITED_SHARES
                  if limiting_axle(ROADS[road].mu, cfg.with_overrides(vehicle={"brake_front_share": x}).vehicle)
                  == "front"]
        if not shares:
            return f"| mu-slip brake-abs front | {road} | {seed} | no brake_front_share up to 0.95 limits the front | | | | |"
        cfg = cfg.with_overrides(vehicle={"brake_front_share": shares[0]})
    settings = SimSettings(**{**demo_settings(scenario).__dict__, "seed": seed})
    sink, _truth, _t0 = run(cfg, scenario, road, settings, 14.0)
    ms = [m for m in sink.maneuvers if m.kind == ("accelerate" if scenario == "launch-spin" else "brake")]
    if not ms:
        return f"| mu-slip {scenario}{' front' if front else ''} | {road} | {seed} | no maneuver | | | | |"
    m, truth = ms[0], tire_peak(road)
    cells = []
    for w in ("FL", "FR", "RL", "RR"):
        mw = m.wheels[w]
        if mw.mu_peak is None:
            cells.append(f"{w} none ({mw.mu_flag or 'no curve'})")
        else:
            cells.append(f"{w} {100 * (mw.mu_peak / truth.mu_peak - 1):+.1f} %, "
                         f"{100 * (mw.slip_at_mu_peak - truth.slip_at_mu_peak):+.1f} pts")  # type: ignore[operator]
    methods = sorted({m.wheels[w].mu_slip_method or "-" for w in ("FL", "FR", "RL", "RR")})
    scenario += " front" if front else ""
    return (f"| mu-slip {scenario} | {road} | {seed} | {'; '.join(cells[:2])} | {'; '.join(cells[2:])} | "
            f"{', '.join(methods)} | tire {truth.mu_peak:.2f} at {100 * truth.slip_at_mu_peak:.1f} % | |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", default="1,2,3", help="simulator seeds (default 1,2,3)")
    ap.add_argument("--tires", default="", metavar="MU:SLIP[:C],...",
                    help="mu-slip rows also on these tires (peak mu at peak slip, a fraction; C the curve's shape, "
                         f"default {TireModel.C}), e.g. 1.17:0.17")
    ap.add_argument("--write", action="store_true", help="write the table into docs/accuracy.md")
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    tires = [add_tire(spec) for spec in args.tires.split(",") if spec]
    lines = ["| row | road | seed | | | | | |", "|---|---|---|---|---|---|---|---|"]
    for road in ("paved", "sand"):
        for seed in seeds:
            for make in (abs_row, test_day_row):
                line = make(road, seed)
                print(line, flush=True)
                lines.append(line)
    for scenario in ("brake-abs-all", "brake-abs", "brake-abs front", "launch-spin"):
        for road in ("paved", "sand", *tires):
            for seed in seeds:
                line = mu_row(scenario, road, seed)
                print(line, flush=True)
                lines.append(line)
    text = "\n".join(lines)
    if args.write:
        doc = DOC.read_text()
        tires_arg = f" --tires {args.tires}" if args.tires else ""
        block = f"{BEGIN}\n`python -m benchmarks.maneuvers --seeds {args.seeds}{tires_arg} --write`\n\n{text}\n{END}"
        if BEGIN in doc and END in doc:
            doc = doc[: doc.index(BEGIN)] + block + doc[doc.index(END) + len(END):]
        else:
            doc += f"\n## Maneuvers, live (/maneuver against the simulator's truth)\n\n{block}\n"
        DOC.write_text(doc)
    return 0


if __name__ == "__main__":
    sys.exit(main())
