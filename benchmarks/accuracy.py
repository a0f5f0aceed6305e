#!/usr/bin/env python3
"""Accuracy benchmark: slipdaq's online estimator against the simulator's truth, over a table of scenarios.

Each scenario runs the full path a user runs: simulated drive -> candump -L CAN log + timestamped NMEA log ->
`slipdaq import` -> `slipdaq replay` -> `slipdaq export` (CSV), once with the config as shipped (latency "auto",
r0 calibrated) and once with the study's uncompensated method (GPS speed at its arrival time, tire-size radius),
on the same data. Prints a markdown table; --write also puts it in docs/accuracy.md.

    python benchmarks/accuracy.py [--quick] [--write]

Figures (speed above 5 m/s): slip RMS error in percentage points over all windows and over the windows whose r0
was calibrated; r0 error in mm (worst wheel, at the end); front Cx error in % against the linear-fit truth
(sim/truth.py); GPS latency error in ms.
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from slipdaq import WHEELS
from slipdaq.cli import main as slipdaq
from slipdaq.config import Config, load_config
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.logs import write_drive_logs
from slipdaq.sim.truth import linear_stiffness_truth, slip_error, truth_series

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Scenario:
    name: str
    scenario: str = "cycle"
    road: str = "paved"
    duration_s: float = 45.0
    latency_s: float = 0.085
    noise_mps: float = 0.03
    gps_rate_hz: float = 10.0
    jitter_s: float = 0.0005
    clock_offset_s: float = 0.0
    r0_offset_m: float = -0.008


SCENARIOS = [
    Scenario("paved cycle (target)"),
    Scenario("sand cycle", road="sand"),
    Scenario("paved accelerate 0-90", scenario="accelerate", duration_s=20.0),
    Scenario("paved brake 90-0", scenario="brake", duration_s=15.0),
    Scenario("sand accelerate 0-90", scenario="accelerate", road="sand", duration_s=25.0),
    Scenario("sand brake 90-0", scenario="brake", road="sand", duration_s=15.0),
    Scenario("latency 0 ms", latency_s=0.0),
    Scenario("latency 150 ms", latency_s=0.150),
    Scenario("noise 0.01 m/s", noise_mps=0.01),
    Scenario("noise 0.10 m/s", noise_mps=0.10),
    Scenario("CAN jitter 2 ms", jitter_s=0.002),
    Scenario("host clock off by 3 s", clock_offset_s=3.0),
]
QUICK = [SCENARIOS[0], SCENARIOS[1], SCENARIOS[11]]


def write_logs(cfg: Config, sc: Scenario, settings: SimSettings, folder: Path) -> tuple[Path, Path, list]:
    can_path, nmea_path = folder / "drive.log", folder / "drive.nmea"
    events = generate(cfg, sc.scenario, sc.road, settings, sc.duration_s, r0_offset_m=sc.r0_offset_m)
    return can_path, nmea_path, write_drive_logs(events, can_path, nmea_path)


def read_csv(path: Path) -> list[dict]:
    def cell(v: str):
        if v == "":
            return None
        try:
            return float(v)
        except ValueError:
            return v

    with open(path, newline="") as f:
        return [{k: cell(v) for k, v in row.items()} | {"window_s": 0.5} for row in csv.DictReader(f)]


def quiet(*argv: str) -> None:
    import contextlib
    import io

    with contextlib.redirect_stdout(io.StringIO()):
        assert slipdaq(list(argv)) == 0, argv


def metrics(rows: list[dict], truth_ts: dict, sc: Scenario, true_r0: dict[str, float], fitted_cx: bool) -> dict:
    all_err = slip_error(rows, truth_ts)
    cal_err = slip_error(rows, truth_ts, only_calibrated=True)
    last = [r for r in rows if r.get("source") == "gps"][-1]
    r0_err = max(abs(last[f"r0_{w}_m"] - true_r0[w]) for w in WHEELS) * 1000
    cx_errs = []
    for w in ("FL", "FR"):
        truth_cx = linear_stiffness_truth(rows, truth_ts, w)
        if fitted_cx:  # slipdaq: the fitted Cx at the end of the run
            values = [r[f"cx_fit_{w}_n"] for r in rows if r.get(f"cx_fit_{w}_n") is not None][-1:]
        else:  # the study's method: Cx = Fx/s per window, its median
            per_window = [r[f"cx_{w}_n"] for r in rows if r.get(f"cx_{w}_n") is not None]
            values = [float(np.median(per_window))] if per_window else []
        if truth_cx and values:
            cx_errs.append(abs(values[0] / truth_cx - 1) * 100)
    lat = float(last.get("gps_latency_s") or 0.0)
    return {
        "slip_rms": all_err.rms_points, "slip_rms_cal": cal_err.rms_points, "r0_mm": r0_err,
        "cx_pct": max(cx_errs) if cx_errs else float("nan"), "lat_ms": abs(lat - sc.latency_s) * 1000,
        "lat_src": last.get("latency_source") or "", "n": all_err.samples,
    }


def run(sc: Scenario, base: Config, folder: Path) -> tuple[dict, dict]:
    settings = SimSettings(gps_latency_s=sc.latency_s, gps_noise_mps=sc.noise_mps, gps_rate_hz=sc.gps_rate_hz,
                           can_jitter_s=sc.jitter_s, host_clock_offset_s=sc.clock_offset_s, seed=7)
    can_path, nmea_path, truth = write_logs(base, sc, settings, folder)
    ts = truth_series(truth, settings.start_utc_s + settings.host_clock_offset_s)
    true_r0 = {w: truth[-1].wheels[w].r0_m for w in WHEELS}
    results = {}
    for method, text in (
        ("slipdaq", base.source_text),
        ("uncompensated", base.source_text.replace('latency_s = "auto"', "latency_s = 0.0")
         .replace("# calibrate_r0 = true", "calibrate_r0 = false")),
    ):
        cfg_path = folder / f"{method}.toml"
        cfg_path.write_text(text)
        (folder / "wpt.dbc").write_text((ROOT / "config" / "wpt.dbc").read_text())
        raw, out, csv_path = folder / f"{method}-raw.mcap", folder / f"{method}-replayed.mcap", folder / f"{method}.csv"
        quiet("import", "--can", str(can_path), "--nmea", str(nmea_path), "--config", str(cfg_path), "-o", str(raw))
        quiet("replay", str(raw), "-o", str(out))
        quiet("export", str(out), "--csv", str(csv_path))
        results[method] = metrics(read_csv(csv_path), ts, sc, true_r0, fitted_cx=method == "slipdaq")
    return results["slipdaq"], results["uncompensated"]


def table(rows: list[tuple[Scenario, dict, dict]]) -> str:
    out = [
        "| scenario | slip RMS pts (all / r0 calibrated) | r0 err mm | front Cx err % | latency err ms (source) "
        "| uncompensated: slip RMS pts | r0 err mm | Cx err % |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for sc, a, u in rows:
        out.append(
            f"| {sc.name} | {a['slip_rms']:.3f} / {a['slip_rms_cal']:.3f} | {a['r0_mm']:.2f} | {a['cx_pct']:.1f} "
            f"| {a['lat_ms']:.1f} ({a['lat_src']}) | {u['slip_rms']:.3f} | {u['r0_mm']:.2f} | {u['cx_pct']:.1f} |"
        )
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="three scenarios only")
    ap.add_argument("--write", action="store_true", help="write the table into docs/accuracy.md")
    a = ap.parse_args()
    base = load_config(ROOT / "config" / "slipdaq.toml")
    results = []
    started = time.monotonic()
    for sc in QUICK if a.quick else SCENARIOS:
        t = time.monotonic()
        with tempfile.TemporaryDirectory() as d:
            comp, unc = run(sc, base, Path(d))
        results.append((sc, comp, unc))
        print(f"{sc.name}: slip RMS {comp['slip_rms']:.3f} pts (uncompensated {unc['slip_rms']:.3f}), "
              f"{time.monotonic() - t:.1f} s", file=sys.stderr, flush=True)
    text = table(results)
    print(text)
    print(f"\n({len(results)} scenarios in {time.monotonic() - started:.0f} s)", file=sys.stderr)
    if a.write:
        doc = ROOT / "docs" / "accuracy.md"
        head = doc.read_text().split("<!-- table -->")[0] if doc.exists() else ""
        doc.write_text(head + "<!-- table -->\n" + text + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
