#!/usr/bin/env python3
"""Coast-down benchmark: road loads from a simulated coast-down, and the estimates of another drive that starts from
them, over several seeds.

The car (sim/road_loads.py COAST_DOWN_CAR): F0 = 150 N, F1 = 0, F2 = 0.40 N/(m/s)^2, rotating_mass_factor 1.04, a
3 m/s wind along the road; the config knows none of it (the packaged config: rotating_mass_factor 1.03, no road
loads). Per seed, through the CLI a user runs:
  1. the `coast-down` scenario (two coasts from 110 to 18 km/h, opposite GPS courses): `slipdaq import
     --calibration cal.toml`; F0 and F2 from its last coast record (`export --maneuvers-csv`) and from cal.toml;
  2. the `highway` scenario (runs to 110, 60 and 110 km/h from a stop, each held 15 s and braked to a stop; no coast)
     of the same car on a day without wind: `slipdaq import --calibration cal.toml`, then `replay --two-pass`; the
     driven (front) wheels' r0 error at the end, the front Cx error against the linear-fit truth (sim/truth.py), the
     slip RMS; and the same with cal.toml's [road_loads] removed (the force without road loads, as before the
     coast-down).

With --pitch-deg-per-g P the car also carries an IMU on CAN (100 Hz, the config reads it) and its body pitches P
degrees per g, which the config does not know either: the IMU reads a*cos(theta) + g*sin(theta), its gain and offset
learned against the GNSS speed in the first pass of each run.

    python -m benchmarks.coast_down [--seeds 3] [--pitch-deg-per-g 1.5] [--write]
"""

from __future__ import annotations

import argparse
import csv
import sys
import tempfile
import time
import tomllib
from dataclasses import replace
from pathlib import Path

import tomli_w

from benchmarks.accuracy import MIN_SPEED_MPS, ROOT, Scenario, export_rows, import_log, quiet, replay_log, sim_settings
from slipdaq import WHEELS
from slipdaq.config import Config, load_config
from slipdaq.sim.emit import generate
from slipdaq.sim.logs import write_drive_logs
from slipdaq.sim.road_loads import COAST_DOWN_CAR, RoadLoadTruth
from slipdaq.sim.truth import linear_stiffness_truth, slip_error, truth_series

CALM = replace(COAST_DOWN_CAR, wind_mps=0.0)
"""The highway drive's car: the same, on a day without wind (a wind w moves its road loads by 2*F2*w*v)."""
COAST_S = 310.0
HIGHWAY_S = 130.0
DRIVEN = ("FL", "FR")
MARK = "<!-- coast-down table -->"


PITCH_DEG_PER_G = 0.0
"""The body's pitch per g (--pitch-deg-per-g); above 0 the car has an IMU on CAN."""


def write_logs(cfg: Config, scenario: str, seed: int, duration_s: float, folder: Path,
               car: RoadLoadTruth = COAST_DOWN_CAR) -> tuple[Path, Path, list]:
    folder.mkdir(parents=True, exist_ok=True)
    settings = sim_settings(Scenario("coast"), seed)
    if PITCH_DEG_PER_G > 0:
        settings = replace(settings, imu_rate_hz=100.0, imu_noise_mps2=0.05, pitch_deg_per_g=PITCH_DEG_PER_G)
    can_path, nmea_path = folder / "drive.log", folder / "drive.nmea"
    events = generate(cfg, scenario, "paved", settings, duration_s, r0_offset_m=-0.008, road_loads=car)  # type: ignore[arg-type]
    return can_path, nmea_path, write_drive_logs(events, can_path, nmea_path)


def coast_records(log: Path) -> list[dict]:
    out = log.with_suffix(".maneuvers.csv")
    quiet("export", str(log), "--maneuvers-csv", str(out))
    with open(out, newline="") as f:
        return [r for r in csv.DictReader(f) if r["kind"] == "coast"]


def highway_figures(rows: list[dict], truth: list, start_utc_s: float) -> dict[str, float]:
    ts = truth_series(truth, start_utc_s)
    last = [r for r in rows if r.get("source") == "gps"][-1]
    r0_mm = max(abs(last[f"r0_{w}_m"] - truth[-1].wheels[w].r0_m) for w in DRIVEN) * 1000
    cx = []
    for w in DRIVEN:
        expected = linear_stiffness_truth(rows, ts, w, MIN_SPEED_MPS)
        fitted = [r[f"cx_fit_{w}_n"] for r in rows if r.get(f"cx_fit_{w}_n") is not None][-1:]
        if expected and fitted:
            cx.append(abs(fitted[0] / expected - 1) * 100)
    return {"r0_mm": r0_mm, "cx_pct": max(cx) if cx else float("nan"), "slip": slip_error(rows, ts).rms_points}


def shipped_config(base: Config, folder: Path) -> Path:
    """The config as shipped (rotating_mass_factor 1.03, no road loads) with the DBC beside it."""
    path = folder / "slipdaq.toml"
    path.write_text(base.source_text if PITCH_DEG_PER_G == 0 else base.to_toml())
    for dbc in ("wpt.dbc", "sensors.dbc"):
        (folder / dbc).write_text((ROOT / "config" / dbc).read_text())
    return path


def run_seed(base: Config, seed: int, folder: Path) -> dict[str, float]:
    cfg_path = shipped_config(base, folder)
    window_s = base.estimator.window_s
    cal = folder / "cal.toml"
    can, nmea, _ = write_logs(base, "coast-down", seed, COAST_S, folder / "coast")
    import_log(can, nmea, cfg_path, folder / "coast" / "raw.mcap", "--calibration", str(cal))
    coast = coast_records(folder / "coast" / "raw.mcap")[-1]
    stored = tomllib.loads(cal.read_text())
    loads = stored["road_loads"]
    without = folder / "cal_without.toml"
    without.write_text(tomli_w.dumps({k: v for k, v in stored.items() if k != "road_loads"}))
    out = {
        "f0_record": float(coast["road_load_f0_n"]), "f2_record": float(coast["road_load_f2_n_per_mps2"]),
        "f1_record": float(coast["road_load_f1_n_per_mps"]), "paired": float(coast["coast_runs_paired"]),
        "f0_cal": loads["road_load_f0_n"], "f2_cal": loads["road_load_f2_n_per_mps2"],
    }
    settings = sim_settings(Scenario("highway"), seed + 100)
    can, nmea, truth = write_logs(base, "highway", seed + 100, HIGHWAY_S, folder / "highway", CALM)
    for name, start in (("with", cal), ("without", without)):
        raw = folder / name / "raw.mcap"
        import_log(can, nmea, cfg_path, raw, "--calibration", str(start))
        replay_log(raw, folder / name / "two-pass.mcap", "--two-pass")
        rows = export_rows(folder / name / "two-pass.mcap", window_s)
        for k, v in highway_figures(rows, truth, settings.start_utc_s).items():
            out[f"{k}_{name}"] = v
    return out


def table(results: list[tuple[int, dict[str, float]]]) -> str:
    lines = [
        "| seed | F0 N (record / cal) | F2 N/(m/s)² (record / cal) | F1 N/(m/s) | runs paired | driven r0 err mm "
        "(road loads / none) | front Cx err % (road loads / none) | slip RMS pts (road loads / none) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for seed, r in results:
        lines.append(
            f"| {seed} | {r['f0_record']:.1f} / {r['f0_cal']:.1f} | {r['f2_record']:.3f} / {r['f2_cal']:.3f} "
            f"| {r['f1_record']:+.2f} | {r['paired']:.0f} | {r['r0_mm_with']:.3f} / {r['r0_mm_without']:.3f} "
            f"| {r['cx_pct_with']:.2f} / {r['cx_pct_without']:.2f} | {r['slip_with']:.3f} / {r['slip_without']:.3f} |")
    worst = {k: max(r[k] for _, r in results) for k in results[0][1]}
    f0 = max(max(abs(r["f0_record"] / 150 - 1), abs(r["f0_cal"] / 150 - 1)) for _, r in results) * 100
    f2 = max(max(abs(r["f2_record"] / 0.4 - 1), abs(r["f2_cal"] / 0.4 - 1)) for _, r in results) * 100
    lines.append(f"| worst | {f0:.1f} % off | {f2:.1f} % off | | | {worst['r0_mm_with']:.3f} / "
                 f"{worst['r0_mm_without']:.3f} | {worst['cx_pct_with']:.2f} / {worst['cx_pct_without']:.2f} | "
                 f"{worst['slip_with']:.3f} / {worst['slip_without']:.3f} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=3, help="seeds 1..N (default 3)")
    ap.add_argument("--pitch-deg-per-g", type=float, default=0.0,
                    help="the body's pitch per g, with an IMU on CAN the config reads (default 0: no IMU)")
    ap.add_argument("--write", action="store_true", help="write the table into docs/accuracy.md (no pitch only)")
    a = ap.parse_args()
    global PITCH_DEG_PER_G
    PITCH_DEG_PER_G = a.pitch_deg_per_g
    base = load_config(ROOT / "config" / "slipdaq.toml")
    if PITCH_DEG_PER_G > 0:
        base = base.with_overrides(can={"dbc": ["wpt.dbc", "sensors.dbc"]},
                                   imu={"message": "IMU_ACCEL", "signal": "AccelX"})
    results = []
    for seed in range(1, a.seeds + 1):
        t = time.monotonic()
        with tempfile.TemporaryDirectory() as d:
            r = run_seed(base, seed, Path(d))
        results.append((seed, r))
        print(f"seed {seed}: {r} ({time.monotonic() - t:.0f} s)", file=sys.stderr, flush=True)
    text = table(results)
    print(text)
    if a.write and PITCH_DEG_PER_G == 0:
        doc = ROOT / "docs" / "accuracy.md"
        before, _, rest = doc.read_text().partition(MARK)
        _, _, after = rest.partition(MARK)
        doc.write_text(f"{before}{MARK}\n{text}\n{MARK}{after}")
    return 0


if __name__ == "__main__":
    assert set(DRIVEN) <= set(WHEELS)
    sys.exit(main())
