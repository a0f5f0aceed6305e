#!/usr/bin/env python3
"""The Magic Formula tire file (.tir, MF 6.1) of an ABS stop's front tire against the simulator's tire. Each row
simulates brake-abs from 80 km/h with the front axle at its limit (benchmarks/maneuvers.py's front-limited stop) on
a tire of peak mu 1.17 at 17 % slip, summarizes it as the report does, writes each front tire's .tir
(tire_model/files.py), reads it back and evaluates it with the MF 6.1 evaluator at the stop's mean front load: the
largest |Fx| error from 2 % to 25 % slip, the peak force and its slip, the slip stiffness Kxk against the truth's
Cx; whether the peak counted as passed, the range written (KPUMIN, KPUMAX).

    python -m benchmarks.tire_file [--seeds 1,2,3] [--write]

Targets: Fx within 5 %, the peak within 5 % and 2 points, Kxk within 5 %.
--write puts the table into docs/accuracy.md between its tire-file markers.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

from slipdaq.live.demo import demo_config, demo_settings
from slipdaq.offline.run import Rows
from slipdaq.pipeline import Pipeline
from slipdaq.report.summary import detect_maneuvers
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.scenarios import limiting_axle
from slipdaq.sim.vehicle import ROADS, TireModel
from slipdaq.tire_model.files import build_tire
from slipdaq.tire_model.tir_file import longitudinal_model, read_tir, write_tir

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "accuracy.md"
BEGIN, END = "<!-- tire file table: begin -->", "<!-- tire file table: end -->"
TRUTH = TireModel.with_peak(1.17, 0.17, TireModel.C)
ROAD = "tire 1.17 at 17 %"


def row(seed: int, out: Path) -> list[str]:
    ROADS[ROAD] = TRUTH
    cfg = demo_config("/dev/null", "chan", "brake-abs")
    share = next(x for x in (0.85, 0.9, 0.95)
                 if limiting_axle(TRUTH.mu, cfg.with_overrides(vehicle={"brake_front_share": x}).vehicle) == "front")
    cfg = cfg.with_overrides(vehicle={"brake_front_share": share})
    settings = SimSettings(**{**demo_settings("brake-abs").__dict__, "seed": seed})
    rows = Rows()
    Pipeline(cfg, [rows]).run(e.record for e in generate(cfg, "brake-abs", ROAD, settings, 14.0)  # type: ignore[arg-type]
                              if e.record is not None)
    stops = [m for m in detect_maneuvers(rows.rows, cfg, fast=rows.fast, sensors=rows.sensors) if m.phase == "brake"]
    if len(stops) != 1:
        return [f"| {seed} | stops found: {len(stops)} | | | | | |"]
    stop = stops[0]
    lines = []
    for w in ("FL", "FR"):
        got = build_tire(w, [("abs", stop)], cfg.vehicle, cfg.tire)
        if got.file is None:
            lines.append(f"| {seed} | {w}: no file ({got.reason}) | | | | | |")
            continue
        model = longitudinal_model(read_tir(write_tir(out / f"{seed}-{w}.tir", got.file)))
        fz = float(np.mean(stop.mu_loads[w]))
        k = -np.linspace(0.02, 0.25, 47)
        truth = np.array([TRUTH.force_n(x, fz) for x in k])
        err = float(np.max(np.abs(model.fx0(k, fz) / truth - 1.0)))
        peak_n, peak_slip = model.peak(fz, -1.0)
        kx = float(model.slip_stiffness(fz)) / TRUTH.stiffness_n(fz) - 1.0
        passed = "passed" if got.fit is not None and got.fit.peak_passed else "NOT passed"
        lines.append(f"| {seed} | {w} at {fz:.0f} N | {100 * err:.2f} % | {100 * (peak_n / (TRUTH.mu * fz) - 1):+.2f} %, "
                     f"{100 * (peak_slip - TRUTH.peak_slip):+.2f} pts | {100 * kx:+.2f} % | {passed} | "
                     f"{got.file.slip_min:.3f} … {got.file.slip_max:.3f} |")
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args()
    head = ["| seed | tire at the stop's mean load | max Fx error 2-25 % | peak (force, slip) | Kxk vs Cx | peak | "
            "KPUMIN … KPUMAX |", "|---|---|---|---|---|---|---|"]
    body: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in (int(s) for s in args.seeds.split(",")):
            lines = row(seed, Path(tmp))
            print("\n".join(lines), flush=True)
            body += lines
    table = "\n".join(head + body)
    print(table)
    if args.write:
        text = DOC.read_text()
        if BEGIN not in text:
            text += (f"\n## Magic Formula tire file\n\n`python -m benchmarks.tire_file --seeds "
                     f"{args.seeds} --write`: brake-abs from 80 km/h, the front axle at its limit, tire mu 1.17 at "
                     f"17 %; each front tire's .tir evaluated at the stop's mean front load against the tire.\n\n"
                     f"{BEGIN}\n{END}\n")
        a, b = text.index(BEGIN) + len(BEGIN), text.index(END)
        DOC.write_text(text[:a] + "\n" + table + "\n" + text[b:])
    return 0


if __name__ == "__main__":
    sys.exit(main())
