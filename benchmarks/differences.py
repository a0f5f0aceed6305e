#!/usr/bin/env python3
"""Paved against sand: the report's difference of the front tires' force–slip line (`cx_line_n`, braking) between two
label groups, against the simulator's truth.

Per road and seed, the simulator's test day (0-60, 60-0, 0-33, 33-0 km/h, 40 s, the tests' config) is run through
the two passes the report runs, and summarized as the report summarizes a log; each road's brake maneuvers are one
group, and their `cx_line_n` per front wheel gives Welch's difference and its 95 % interval
(`maneuver.stats.welch_difference`, as the report's `differences`).

Two truths per wheel:
- the **line's truth**: the same line (slip on force with intercept, weighted by speed², over the maneuver's windows
  of its force sign and the cruise windows before it, |s| <= cx_slip_max) fitted to the truth's window means at the
  same windows, per maneuver, then the groups' means and their difference; this is what `cx_line_n` measures;
- the tires' **initial slopes** cx_per_fz·Fz (static loads): on a tire whose curve bends within the linear region the
  line lies below it, on the softer sand tire less so.

    python -m benchmarks.differences [--seeds 1,2,3,4,5,6]

Rows: one test day per road for each seed (the groups' sizes as a day gives them), then every seed's days pooled.
Columns: per front wheel, the difference and its interval, the line's truth difference and whether the interval
holds it, the initial slopes' difference and whether the interval holds that.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.accuracy_sensors import run, true_line_cx
from slipdaq.config import Config, load_config
from slipdaq.maneuver.figures import ManeuverSummary
from slipdaq.maneuver.stats import welch_difference
from slipdaq.report.summary import summarize_log
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.truth import truth_series
from slipdaq.sim.vehicle import ROADS, static_loads_n

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "config" / "slipdaq.toml"
FRONT = ("FL", "FR")


def _anchors(found: Sequence[ManeuverSummary], m: ManeuverSummary) -> list[dict[str, Any]]:
    """The cruise rows known when m closed: every cruise before it and the cruise that follows it."""
    out: list[dict[str, Any]] = []
    for c in found:
        if c.phase == "cruise" and c.rows[0]["time_s"] < m.rows[-1]["time_s"] + 30.0:
            if c.rows[0]["time_s"] > m.rows[-1]["time_s"]:
                out.extend(c.rows)
                break
            out.extend(c.rows)
    return out


def brakes(cfg: Config, road: str, seed: int) -> list[tuple[dict[str, float], dict[str, float]]]:
    """Per valid brake maneuver of one test day: (cx_line_n, the line's truth) per front wheel."""
    records, truth = [], []
    for ev in generate(cfg, "test-day", road, SimSettings(seed=seed), duration_s=40.0):
        if ev.record is not None:
            records.append(ev.record)
        if ev.truth is not None:
            truth.append(ev.truth)
    ts = truth_series(truth, SimSettings(seed=seed).start_utc_s)
    rows = run(cfg, records, two_pass=True)
    summary = summarize_log(rows.rows, {"config_toml": cfg.to_toml()}, None, path="x", name="x", labels={},
                            fast=rows.fast, sensors=rows.sensors)
    by_time = sorted(summary.maneuvers, key=lambda m: m.rows[0]["time_s"])
    out = []
    for rec in summary.records:
        if rec.kind != "brake" or not rec.valid:
            continue
        m = next(x for x in by_time if x.phase == "brake" and abs(x.t_start_s - rec.t_start_s) < 1e-9)
        est = {w: rec.wheels[w].cx_line_n for w in FRONT}
        tru = {w: true_line_cx(m.rows, _anchors(by_time, m), ts, w, cfg.estimator.cx_slip_max) for w in FRONT}
        if all(est[w] is not None and tru[w] is not None for w in FRONT):
            out.append(({w: float(est[w]) for w in FRONT}, {w: float(tru[w]) for w in FRONT}))  # type: ignore[arg-type]
    return out


def _row(case: str, paved: list[tuple[dict[str, float], dict[str, float]]],
         sand: list[tuple[dict[str, float], dict[str, float]]], initial: dict[str, float]) -> list[str]:
    out = []
    for w in FRONT:
        d = welch_difference([e[w] for e, _ in paved], [e[w] for e, _ in sand])
        line = float(np.mean([t[w] for _, t in paved]) - np.mean([t[w] for _, t in sand]))
        assert d is not None
        if d.ci_lo is None or d.ci_hi is None:
            out.append(f"| {case} | {w} | {len(paved)}, {len(sand)} | {d.difference / 1e3:.1f} | none | "
                       f"{line / 1e3:.1f} | | {initial[w] / 1e3:.1f} | |")
            continue
        out.append(f"| {case} | {w} | {len(paved)}, {len(sand)} | {d.difference / 1e3:.1f} | "
                   f"[{d.ci_lo / 1e3:.1f}, {d.ci_hi / 1e3:.1f}] | {line / 1e3:.1f} | "
                   f"{'yes' if d.ci_lo <= line <= d.ci_hi else 'no'} | {initial[w] / 1e3:.1f} | "
                   f"{'yes' if d.ci_lo <= initial[w] <= d.ci_hi else 'no'} |")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", default="1,2,3,4,5,6", help="seeds per road (default 1,2,3,4,5,6)")
    args = ap.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",")]
    cfg = load_config(CONFIG).with_overrides(vehicle={"rotating_mass_factor": 1.0})  # the simulator's car has none
    got = {(road, s): brakes(cfg, road, s) for road in ("paved", "sand") for s in seeds}
    loads = static_loads_n(cfg.vehicle.mass_kg)
    initial = {w: (ROADS["paved"].cx_per_fz - ROADS["sand"].cx_per_fz) * loads[w] for w in FRONT}
    print(f"`python -m benchmarks.differences --seeds {args.seeds}`: paved against sand, the brake maneuvers' "
          "`cx_line_n`, one test day per road and seed\n")
    print("| logs | wheel | n paved, sand | difference, kN | 95 % interval, kN | line's truth, kN | holds it | "
          "initial slopes, kN | holds it |")
    print("|---|---|---|---:|---|---:|---|---:|---|")
    for s in seeds:
        print("\n".join(_row(f"seed {s}", got[("paved", s)], got[("sand", s)], initial)))
    pooled = {road: [b for s in seeds for b in got[(road, s)]] for road in ("paved", "sand")}
    print("\n".join(_row("all seeds", pooled["paved"], pooled["sand"], initial)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
