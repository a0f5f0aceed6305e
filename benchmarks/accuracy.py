#!/usr/bin/env python3
"""Accuracy benchmark: slipdaq's online estimator against the simulator's truth, over a table of scenarios.

Each scenario runs the full path a user runs: simulated drive -> candump -L CAN log + timestamped NMEA log ->
`slipdaq import` -> `slipdaq replay` -> `slipdaq export` (CSV), once with the config as shipped (latency "auto",
r0 calibrated) and once with the study's uncompensated method (GPS speed at its arrival time, tire-size radius),
on the same data; both with `--no-calibration` (every run starts cold, whatever an earlier one stored). Three rows
run other paths: a calibration stored by an earlier drive of the same car (`--calibration`), `replay --two-pass`,
and a CAN reader stall. Prints a markdown table; --write also puts it in docs/accuracy.md.

    python -m benchmarks.accuracy [--quick] [--rows NAME,...] [--write]

Figures (speed above 5 m/s): slip RMS error in percentage points over all windows and over the windows whose r0
was calibrated; the GPS-noise floor of that RMS and the ratio to it; r0 error in mm (worst wheel, at the end); front
Cx error in % against the linear-fit truth (sim/truth.py); GPS latency error in ms; figures of the row's own
(largest window error, windows before the latency is known, `quality` of the windows).

A row whose CLI flags this slipdaq does not have is not run (said on stderr and in its table line). Without
`--no-calibration` the CLI stores no calibration either, so the cold rows run without it. Without a `quality`
column in the export every window counts as not disturbed, and the figures that need it are "n/a".
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import math
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from slipdaq import WHEELS
from slipdaq.cli import build_parser
from slipdaq.cli import main as slipdaq
from slipdaq.config import Config, load_config, parse_config
from slipdaq.estimator.gps_track import integrate_speed_m
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.logs import write_drive_logs
from slipdaq.sim.truth import linear_stiffness_truth, slip_error, truth_series

ROOT = Path(__file__).resolve().parents[1]
MIN_SPEED_MPS = 5.0
"""Windows below this speed are left out of every slip figure (as slip_error does)."""
SEED = 7
"""The measured drive's seed; the earlier drive of the stored-calibration row uses EARLIER_SEED."""
EARLIER_SEED = 3
EARLIER_BY_S = 3600.0
"""The earlier drive starts this long before the measured one."""


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
    can_stall: tuple[float, float] | None = None
    driven_axle: str = "front"
    mode: str = "cold"
    """cold: import and replay with --no-calibration (and the uncompensated method); stored: an earlier drive of the
    same car stores its calibration, the measured drive is imported from it and replayed; two-pass: a cold import,
    then replay --no-calibration --two-pass."""
    figures: str = ""
    """The row's own figures: "cold" (largest window error, windows before the latency is known, the ok windows) or
    "stall" (windows not disturbed, largest window error, disturbed windows)."""


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
    Scenario("host clock off UTC, cold", clock_offset_s=3.0, figures="cold"),
    Scenario("off UTC, stored calibration", clock_offset_s=3.0, mode="stored"),
    Scenario("off UTC, two-pass", clock_offset_s=3.0, mode="two-pass"),
    Scenario("2 s reader stall", can_stall=(20.0, 2.0), figures="stall"),
    Scenario("off UTC, all-wheel drive, cold", clock_offset_s=3.0, driven_axle="all", figures="cold"),
    Scenario("off UTC, all-wheel drive, two-pass", clock_offset_s=3.0, driven_axle="all", mode="two-pass"),
]
QUICK = [sc for sc in SCENARIOS if sc.name in ("paved cycle (target)", "sand cycle", "host clock off UTC, cold")]


# ---- the CLI's flags -------------------------------------------------------------------------------------------

def cli_accepts(*argv: str) -> bool:
    """slipdaq's argument parser accepts argv (nothing is run)."""
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        try:
            build_parser().parse_args(list(argv))
        except SystemExit:
            return False
    return True


@dataclass(frozen=True)
class CliFeatures:
    no_calibration: bool
    """import and replay take --no-calibration."""
    calibration: bool
    """import takes --calibration PATH."""
    two_pass: bool
    """replay takes --two-pass."""

    @classmethod
    def probe(cls) -> CliFeatures:
        imp, rep = ("import", "--can", "c.log", "--nmea", "n.nmea", "-o", "o.mcap"), ("replay", "r.mcap", "-o", "o.mcap")
        return cls(no_calibration=cli_accepts(*imp, "--no-calibration") and cli_accepts(*rep, "--no-calibration"),
                   calibration=cli_accepts(*imp, "--calibration", "cal.toml"),
                   two_pass=cli_accepts(*rep, "--two-pass"))

    def cold(self) -> list[str]:
        """The flags that make import and replay start without a stored calibration and store none."""
        return ["--no-calibration"] if self.no_calibration else []

    def missing(self, sc: Scenario) -> str | None:
        """Why sc cannot run with this CLI, or None."""
        if sc.mode == "stored" and not self.calibration:
            return "this slipdaq has no `import --calibration PATH`"
        if sc.mode == "two-pass" and not (self.two_pass and self.no_calibration):
            return "this slipdaq has no `replay --two-pass` / `--no-calibration`"
        return None


# ---- runs --------------------------------------------------------------------------------------------------------

def sim_settings(sc: Scenario, seed: int = SEED) -> SimSettings:
    return SimSettings(gps_latency_s=sc.latency_s, gps_noise_mps=sc.noise_mps, gps_rate_hz=sc.gps_rate_hz,
                       can_jitter_s=sc.jitter_s, host_clock_offset_s=sc.clock_offset_s, can_stall=sc.can_stall, seed=seed)


def write_logs(cfg: Config, sc: Scenario, settings: SimSettings, folder: Path) -> tuple[Path, Path, list]:
    folder.mkdir(parents=True, exist_ok=True)
    can_path, nmea_path = folder / "drive.log", folder / "drive.nmea"
    events = generate(cfg, sc.scenario, sc.road, settings, sc.duration_s, r0_offset_m=sc.r0_offset_m)
    return can_path, nmea_path, write_drive_logs(events, can_path, nmea_path)


def read_csv(path: Path, window_s: float) -> list[dict]:
    def cell(v: str):
        if v == "":
            return None
        try:
            return float(v)
        except ValueError:
            return v

    with open(path, newline="") as f:
        return [{k: cell(v) for k, v in row.items()} | {"window_s": window_s} for row in csv.DictReader(f)]


def quiet(*argv: str) -> None:
    with contextlib.redirect_stdout(io.StringIO()):
        assert slipdaq(list(argv)) == 0, argv


NO_ROTATING_MASSES = ("# rotating_mass_factor = 1.03", "rotating_mass_factor = 1.0")
"""The simulated car has no rotating masses (the simulator's default): its config says so (as shipped it assumes
SAE J2263's 1.03, which would put 3 % more force on this car's tires than they carry)."""


def config_file(base: Config, folder: Path, method: str) -> Path:
    """The method's config (slipdaq: as shipped but for NO_ROTATING_MASSES; uncompensated: latency 0, tire-size
    radius) with the DBC beside it."""
    assert NO_ROTATING_MASSES[0] in base.source_text
    text = base.source_text.replace(*NO_ROTATING_MASSES)
    if method == "uncompensated":
        text = text.replace('latency_s = "auto"', "latency_s = 0.0").replace("# calibrate_r0 = true", "calibrate_r0 = false")
    path = folder / f"{method}.toml"
    path.write_text(text)
    (folder / "wpt.dbc").write_text((ROOT / "config" / "wpt.dbc").read_text())
    return path


def import_log(can_path: Path, nmea_path: Path, cfg_path: Path, raw: Path, *flags: str) -> None:
    raw.parent.mkdir(parents=True, exist_ok=True)
    quiet("import", "--can", str(can_path), "--nmea", str(nmea_path), "--config", str(cfg_path), "-o", str(raw), *flags)


def replay_log(raw: Path, out: Path, *flags: str) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    quiet("replay", str(raw), "-o", str(out), *flags)


def export_rows(log: Path, window_s: float) -> list[dict]:
    csv_path = log.with_suffix(".csv")
    quiet("export", str(log), "--csv", str(csv_path))
    return read_csv(csv_path, window_s)


# ---- figures -----------------------------------------------------------------------------------------------------

def has_quality(rows: list[dict]) -> bool:
    return bool(rows) and "quality" in rows[0]


def not_disturbed(rows: list[dict]) -> list[dict]:
    """The windows not marked disturbed (all of them without a quality column)."""
    return [r for r in rows if r.get("quality") != "disturbed"]


def used_windows(rows: list[dict]) -> list[tuple[float, int]]:
    """(window centre, wheels with a slip) of the windows slip_error counts: GPS windows above MIN_SPEED_MPS."""
    out = []
    for r in rows:
        if r["speed_mps"] is None or r["speed_mps"] < MIN_SPEED_MPS or r.get("source", "gps") != "gps":
            continue
        wheels = sum(r.get(f"slip_{w}") is not None for w in WHEELS)
        if wheels:
            out.append((float(r["time_s"]), wheels))
    return out


def trapezoid_weights(fix_t: np.ndarray, t0: float, t1: float) -> tuple[slice, np.ndarray]:
    """The fixes whose speeds enter the integral of the piecewise-linear GPS speed over [t0, t1], and their weights:
    integral = sum(w_i * v_i) (the window's ends are interpolated between the fixes either side of them)."""
    lo = max(int(np.searchsorted(fix_t, t0, side="right")) - 1, 0)
    hi = min(int(np.searchsorted(fix_t, t1, side="left")) + 1, len(fix_t))
    t = fix_t[lo:hi]
    return slice(lo, hi), np.array([integrate_speed_m(t, unit, t0, t1) for unit in np.eye(len(t))])


def noise_floor_points(rows: list[dict], truth_ts: dict, sc: Scenario, settings: SimSettings, window_s: float) -> float:
    """The slip RMS (points) that GPS speed noise alone gives with the estimator's method, over the windows the row's
    slip RMS uses: per window sigma * sqrt(sum w_i^2) / d_gps, w_i the trapezoid weights of its fixes and d_gps the
    window's distance from the true speeds at the fixes; RMS over the wheel windows."""
    n_fix = math.ceil(sc.duration_s * sc.gps_rate_hz)
    fix_t = settings.start_utc_s + settings.host_clock_offset_s + np.arange(n_fix) / sc.gps_rate_hz
    fix_v = np.interp(fix_t, truth_ts["time_s"], truth_ts["speed_mps"])  # the truth has a sample at every epoch
    sq, count = 0.0, 0
    for t_c, wheels in used_windows(rows):
        idx, w = trapezoid_weights(fix_t, t_c - 0.5 * window_s, t_c + 0.5 * window_s)
        sigma_slip = sc.noise_mps * math.sqrt(float(np.sum(w**2))) / float(w @ fix_v[idx])
        sq, count = sq + wheels * sigma_slip**2, count + wheels
    return math.sqrt(sq / count) * 100.0 if count else float("nan")


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
        "lat_src": last.get("latency_source") or "", "n": all_err.samples, "max_pts": all_err.max_abs_points,
    }


def headline(sc: Scenario, rows: list[dict]) -> list[dict]:
    """The windows of the row's headline slip RMS (the one the noise floor is computed for)."""
    return not_disturbed(rows) if sc.figures == "stall" else rows


def row_figures(sc: Scenario, rows: list[dict], truth_ts: dict) -> tuple[str, dict]:
    """The row's own figures: text for the table and values for stderr."""
    q = has_quality(rows)
    na = "n/a (no quality column)"
    if sc.figures == "cold":
        worst = slip_error(rows, truth_ts).max_abs_points
        before = [r for r in rows if r.get("latency_source") == "none"]
        share = 100.0 * sum(r.get("quality") != "ok" for r in before) / len(before) if before and q else float("nan")
        ok = slip_error([r for r in rows if r.get("quality") == "ok"], truth_ts) if q else None
        text = (f"max window err {worst:.2f} pts; before latency known: "
                + (f"{share:.0f} % of {len(before)} not ok" if q else na)
                + "; ok windows: " + (f"{ok.rms_points:.3f} pts RMS ({ok.samples})" if ok else na))
        return text, {"max_pts": worst, "before_latency_n": len(before), "before_not_ok_pct": share,
                      "ok_rms": ok.rms_points if ok else float("nan")}
    if sc.figures == "stall":
        calm = slip_error(not_disturbed(rows), truth_ts)
        worst = slip_error(rows, truth_ts).max_abs_points
        disturbed = sum(r.get("quality") == "disturbed" for r in rows)
        text = (f"not disturbed: {calm.rms_points:.3f} pts RMS ({calm.samples}); max window err {worst:.2f} pts; "
                + (f"{disturbed} windows disturbed" if q else f"disturbed: {na}, all windows counted"))
        return text, {"calm_rms": calm.rms_points, "max_pts": worst, "disturbed": disturbed if q else None}
    return "", {}


def run(sc: Scenario, base: Config, folder: Path, cli: CliFeatures) -> dict[str, Any]:
    """The row's figures: slipdaq's (and the uncompensated method's on cold rows), the floor, the row's own."""
    if sc.driven_axle != base.vehicle.driven_axle:
        axle = f'driven_axle = "{base.vehicle.driven_axle}"'
        assert axle in base.source_text
        base = parse_config(base.source_text.replace(axle, f'driven_axle = "{sc.driven_axle}"'), base.source_path)
    window_s = base.estimator.window_s
    settings = sim_settings(sc)
    can_path, nmea_path, truth = write_logs(base, sc, settings, folder / "measured")
    ts = truth_series(truth, settings.start_utc_s + settings.host_clock_offset_s)
    true_r0 = {w: truth[-1].wheels[w].r0_m for w in WHEELS}
    cfg_path = config_file(base, folder, "slipdaq")
    extra = ""
    uncompensated = None
    if sc.mode == "cold":
        import_log(can_path, nmea_path, cfg_path, folder / "slipdaq" / "raw.mcap", *cli.cold())
        replay_log(folder / "slipdaq" / "raw.mcap", folder / "slipdaq" / "replayed.mcap", *cli.cold())
        rows = export_rows(folder / "slipdaq" / "replayed.mcap", window_s)
        unc_cfg = config_file(base, folder, "uncompensated")
        import_log(can_path, nmea_path, unc_cfg, folder / "uncompensated" / "raw.mcap", *cli.cold())
        replay_log(folder / "uncompensated" / "raw.mcap", folder / "uncompensated" / "replayed.mcap", *cli.cold())
        uncompensated = metrics(export_rows(folder / "uncompensated" / "replayed.mcap", window_s), ts, sc, true_r0,
                                fitted_cx=False)
    elif sc.mode == "stored":
        cal = folder / "cal.toml"
        earlier = replace(settings, seed=EARLIER_SEED, start_utc_s=settings.start_utc_s - EARLIER_BY_S)
        early_can, early_nmea, _ = write_logs(base, sc, earlier, folder / "earlier")
        import_log(early_can, early_nmea, cfg_path, folder / "earlier" / "raw.mcap", "--calibration", str(cal))
        import_log(can_path, nmea_path, cfg_path, folder / "stored" / "raw.mcap", "--calibration", str(cal))
        imported = slip_error(export_rows(folder / "stored" / "raw.mcap", window_s), ts)
        # replay without flags: from the calibration stored in the log (a fresh folder: no calibration.toml there)
        replay_log(folder / "stored" / "raw.mcap", folder / "replay" / "replayed.mcap")
        rows = export_rows(folder / "replay" / "replayed.mcap", window_s)
        extra = f"import: {imported.rms_points:.3f} pts RMS ({imported.samples}); the rest: replay"
    elif sc.mode == "two-pass":
        import_log(can_path, nmea_path, cfg_path, folder / "two-pass" / "raw.mcap", "--no-calibration")
        replay_log(folder / "two-pass" / "raw.mcap", folder / "two-pass" / "replayed.mcap", "--no-calibration",
                   "--two-pass")
        rows = export_rows(folder / "two-pass" / "replayed.mcap", window_s)
    else:
        raise ValueError(f"unknown mode {sc.mode!r}")
    result = metrics(rows, ts, sc, true_r0, fitted_cx=True)
    main_rows = headline(sc, rows)
    result["rms"] = slip_error(main_rows, ts).rms_points
    result["floor"] = noise_floor_points(main_rows, ts, sc, settings, window_s)
    text, values = row_figures(sc, rows, ts)
    result["figures"] = "; ".join(x for x in (text, extra) if x)
    result["values"] = values
    result["quality"] = has_quality(rows)
    return {"slipdaq": result, "uncompensated": uncompensated}


# ---- the table ---------------------------------------------------------------------------------------------------

HEADER = [
    "| scenario | slip RMS pts (all / r0 calibrated) | noise floor pts | RMS / floor | r0 err mm | front Cx err % "
    "| latency err ms (source) | uncompensated: slip RMS pts | r0 err mm | Cx err % | row figures |",
    "|---|---|---|---|---|---|---|---|---|---|---|",
]


def table(rows: list[tuple[Scenario, dict[str, Any] | None, str | None]]) -> str:
    out = list(HEADER)
    for sc, r, skipped in rows:
        if r is None:
            out.append(f"| {sc.name} | not run: {skipped} |" + " |" * 9)
            continue
        a, u = r["slipdaq"], r["uncompensated"]
        unc = (f"{u['slip_rms']:.3f} | {u['r0_mm']:.2f} | {u['cx_pct']:.1f}" if u else "— | — | —")
        out.append(
            f"| {sc.name} | {a['slip_rms']:.3f} / {a['slip_rms_cal']:.3f} | {a['floor']:.3f} | {a['rms'] / a['floor']:.2f} "
            f"| {a['r0_mm']:.2f} | {a['cx_pct']:.1f} | {a['lat_ms']:.1f} ({a['lat_src']}) | {unc} | {a['figures']} |"
        )
    return "\n".join(out)


def select(names: str | None, quick: bool) -> list[Scenario]:
    chosen = QUICK if quick else SCENARIOS
    if names is None:
        return chosen
    wanted = [n.strip().lower() for n in names.split(",") if n.strip()]
    unknown = [n for n in wanted if not any(n in sc.name.lower() for sc in SCENARIOS)]
    if unknown:
        raise SystemExit(f"--rows: no scenario matches {unknown}; scenarios: {[sc.name for sc in SCENARIOS]}")
    return [sc for sc in chosen if any(n in sc.name.lower() for n in wanted)]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="three scenarios only")
    ap.add_argument("--rows", metavar="NAME,...", help="only the scenarios whose name contains one of these (any case)")
    ap.add_argument("--write", action="store_true", help="write the table into docs/accuracy.md")
    a = ap.parse_args()
    base = load_config(ROOT / "config" / "slipdaq.toml")
    cli = CliFeatures.probe()
    if not cli.no_calibration:
        print("note: this slipdaq has no --no-calibration (and stores no calibration): cold rows run without it",
              file=sys.stderr)
    results: list[tuple[Scenario, dict[str, Any] | None, str | None]] = []
    started = time.monotonic()
    for sc in select(a.rows, a.quick):
        if (why := cli.missing(sc)) is not None:
            print(f"{sc.name}: not run: {why}", file=sys.stderr, flush=True)
            results.append((sc, None, why))
            continue
        t = time.monotonic()
        with tempfile.TemporaryDirectory() as d:
            r = run(sc, base, Path(d), cli)
        results.append((sc, r, None))
        s, u = r["slipdaq"], r["uncompensated"]
        print(f"{sc.name}: slip RMS {s['slip_rms']:.3f} pts"
              + (f" (uncompensated {u['slip_rms']:.3f})" if u else "")
              + f", floor {s['floor']:.3f} pts, {time.monotonic() - t:.1f} s"
              + ("" if s["quality"] else " [no quality column in the export]"), file=sys.stderr, flush=True)
        if s["values"]:
            print(f"  {s['values']}", file=sys.stderr, flush=True)
    text = table(results)
    print(text)
    print(f"\n({len(results)} scenarios in {time.monotonic() - started:.0f} s)", file=sys.stderr)
    if a.write:
        doc = ROOT / "docs" / "accuracy.md"
        head = doc.read_text().split("<!-- table -->")[0] if doc.exists() else ""
        doc.write_text(head + "<!-- table -->\n" + text + "\n")
        if len(results) < len(SCENARIOS):
            print(f"note: the table in {doc} now has {len(results)} of {len(SCENARIOS)} rows", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
