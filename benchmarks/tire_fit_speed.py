#!/usr/bin/env python3
"""The MF 6.1 fits of a long log's tire files (tire_model/fit.py's fit_mf61), this tree against a base revision, in
one run: each wheel's fit timed in its own process per side and round (CPU and wall, the order of the sides reversed
every round), and what the two sides' fits give (the largest relative change of each coefficient, the curves' largest
difference as a fraction of their peak).

The points are the report's: the log of benchmarks/report_long.py (--hours of the cycle drive, 4 × 1 kHz WPT, written
once into --work), replayed and summarized as `slipdaq report` does, each wheel's fit_mf61 arguments as build_tire
passes them (kept in --work and reused); --copies N fits each wheel's points N times over (4 copies of 0.5 h: the
point count of a 2-hour log).

--test-data: instead, the fits of tests/tire_model's data (its synthetic points, the ABS stop, the RAV4 drive of
tests/data) by both sides: the largest relative change of each coefficient, the curves' largest gap.
--tir OLD NEW: instead, the largest relative change of each coefficient between two folders' .tir files of the same
names (two reports' tires/).

    python -m benchmarks.tire_fit_speed [--hours 0.5] [--copies 4] [--rounds 5] [--base REV] [--work DIR]
    python -m benchmarks.tire_fit_speed --tir OLD_DIR NEW_DIR
    python -m benchmarks.tire_fit_speed --test-data [--base REV]
"""

from __future__ import annotations

import argparse
import io
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.base_revision import ROOT, add_base_argument, in_turns, resolve, side_env, unpack
from benchmarks.doc_block import machine
from benchmarks.report_long import make_log

CHILD = """
import json, sys, time
import numpy as np
from slipdaq.tire_model.fit import fit_mf61
inputs, copies = np.load(sys.argv[1]), int(sys.argv[2])
kwargs = json.loads(sys.argv[3])
got = {}
for wheel, kw in kwargs.items():
    args = [np.tile(inputs[f"{wheel}_{a}"], copies) for a in ("slip", "fx", "fz")]
    t, c = time.perf_counter(), time.process_time()
    fit = fit_mf61(*args, **kw)
    wall, cpu = time.perf_counter() - t, time.process_time() - c
    got[wheel] = {"wall_s": wall, "cpu_s": cpu, "points": int(args[0].size),
                  "values": fit.model.values() if fit else None, "stderr": fit.stderr if fit else None}
print(json.dumps(got))
"""

TEST_DATA = """
import dataclasses, json, sys, tempfile
from pathlib import Path
import numpy as np
from slipdaq.cli import main
from slipdaq.live.demo import demo_config, demo_settings
from slipdaq.offline.run import Rows
from slipdaq.pipeline import Pipeline
from slipdaq.report.build import read_log
from slipdaq.report.summary import detect_maneuvers, summarize_log
from slipdaq.report.tires import tire_jobs
from slipdaq.sim.emit import generate
from slipdaq.sim.scenarios import limiting_axle
from slipdaq.sim.vehicle import ROADS, TireModel
from slipdaq.tire_model.files import build_tire
from slipdaq.tire_model.fit import fit_mf61
from slipdaq.tire_model.mf61 import LongitudinalMF61
root = Path(sys.argv[1])
got = {}
for seed, load in ((1, True), (2, False), (3, True)):  # tests/tire_model: _points
    truth = LongitudinalMF61(fnomin=4000.0, pcx1=1.65, pdx1=1.17, pkx1=16.0, pdx2=-0.1 if load else 0.0,
                             pkx2=-3.0 if load else 0.0)
    rng = np.random.default_rng(seed)
    k = -rng.uniform(0.0, 0.3, 3000)
    fz = truth.fnomin * (1.0 + 0.6 * rng.uniform(-0.5, 0.5, 3000))
    fx = truth.fx0(k, fz) + 0.02 * fz * rng.standard_normal(3000)
    got[f"synthetic {seed}"] = (fit_mf61(k, fx, fz, 4000.0).model.values(), 4000.0)
truth = TireModel.with_peak(1.17, 0.17, TireModel.C)  # tests/tire_model: abs_stop
ROADS["tire 1.17 at 17 %"] = truth
cfg = demo_config("/dev/null", "chan", "brake-abs")
share = next(x for x in (0.85, 0.9, 0.95)
             if limiting_axle(truth.mu, cfg.with_overrides(vehicle={"brake_front_share": x}).vehicle) == "front")
cfg = cfg.with_overrides(vehicle={"brake_front_share": share})
rows = Rows()
Pipeline(cfg, [rows]).run(e.record for e in generate(cfg, "brake-abs", "tire 1.17 at 17 %", demo_settings("brake-abs"),
                                                     14.0) if e.record is not None)
(stop,) = [m for m in detect_maneuvers(rows.rows, cfg, fast=rows.fast, sensors=rows.sensors) if m.phase == "brake"]
for w in ("FL", "FR"):
    fit = build_tire(w, [("abs.mcap", stop)], cfg.vehicle, cfg.tire).fit
    got[f"ABS stop {w}"] = (fit.model.values(), fit.model.fnomin)
with tempfile.TemporaryDirectory() as tmp:  # tests/tire_model: rav4
    log, data_dir = Path(tmp) / "rav4.mcap", root / "tests" / "data" / "rav4-comma2k19"
    assert main(["import", "--can", str(data_dir / "rav4_bus0.candump.log"), "--nmea", str(data_dir / "rav4_ublox.nmea"),
                 "--config", str(root / "config" / "examples" / "rav4-comma2k19.toml"), "-o", str(log)]) == 0
    data = read_log(log)
    s = summarize_log(data.rows, data.metadata, data.diagnostics, path=str(log), name="rav4", labels={},
                      fast=data.fast, sensors=data.sensors)
    for job in (j for _, _, group in tire_jobs([s]) for j in group):
        fit = job.fit().fit
        got[f"RAV4 {job.wheel}"] = (fit.model.values(), fit.model.fnomin)
print(json.dumps(got))
"""


def fit_inputs(work: Path, hours: float) -> tuple[Path, dict[str, dict[str, Any]]]:
    """Each wheel's fit_mf61 arguments for the report of the log (written once into work): the points (.npz) and the
    keywords."""
    npz, meta = work / f"fit-points-{hours:g}h.npz", work / f"fit-points-{hours:g}h.json"
    if not (npz.exists() and meta.exists()):
        from slipdaq.report.build import read_log
        from slipdaq.report.labels import labels_of
        from slipdaq.report.summary import summarize_log
        from slipdaq.report.tires import tire_jobs
        from slipdaq.tire_model import files

        log, _ = make_log(work, hours, 1000.0)
        data = read_log(log, two_pass=True, progress=io.StringIO())
        s = summarize_log(data.rows, data.metadata, data.diagnostics, path=str(log), name=log.stem,
                          labels=labels_of(data.metadata), fast=data.fast, sensors=data.sensors)
        arrays: dict[str, np.ndarray] = {}
        kwargs: dict[str, dict[str, Any]] = {}
        fit_mf61 = files.fit_mf61

        def recording(slip: Any, fx: Any, fz: Any, fnomin: float, **kw: Any) -> Any:  # build_tire's arguments
            arrays.update({f"{wheel}_slip": np.asarray(slip), f"{wheel}_fx": np.asarray(fx),
                           f"{wheel}_fz": np.asarray(fz)})
            kwargs[wheel] = {"fnomin_n": fnomin, **kw}
            return fit_mf61(slip, fx, fz, fnomin, **kw)

        files.fit_mf61 = recording
        try:
            for _, _, jobs in tire_jobs([s]):
                for job in jobs:
                    wheel = job.wheel
                    job.fit()
        finally:
            files.fit_mf61 = fit_mf61
        np.savez(npz, **arrays)
        meta.write_text(json.dumps(kwargs))
    return npz, json.loads(meta.read_text())


def curve_gap(a: dict[str, float], b: dict[str, float], fnomin: float) -> float:
    """The largest |Fx0 of a − Fx0 of b| over slip ±60 % at 0.7, 1 and 1.3 FNOMIN, over b's peak |Fx0| there."""
    from slipdaq.tire_model.mf61 import LongitudinalMF61

    ma, mb = LongitudinalMF61.from_values(fnomin, a), LongitudinalMF61.from_values(fnomin, b)
    k = np.linspace(-0.6, 0.6, 1201)
    return max(float(np.max(np.abs(ma.fx0(k, f * fnomin) - mb.fx0(k, f * fnomin)))
                     / np.max(np.abs(mb.fx0(k, f * fnomin)))) for f in (0.7, 1.0, 1.3))


def relative_changes(pairs: list[tuple[dict[str, float], dict[str, float]]]) -> dict[str, float]:
    """Per coefficient, the largest |new − old| / |old| over the pairs (old, new) (0 where both are 0)."""
    out: dict[str, float] = {}
    for old, new in pairs:
        for name, v in old.items():
            change = abs(new[name] - v) / abs(v) if v != 0 else abs(new[name])
            out[name] = max(out.get(name, 0.0), change)
    return {n: c for n, c in out.items() if any(old[n] != 0 for old, _ in pairs)}


def compare_tir(old_dir: Path, new_dir: Path) -> int:
    from slipdaq.tire_model.tir_file import read_tir

    pairs, names = [], []
    for old in sorted(old_dir.rglob("*.tir")):
        new = new_dir / old.relative_to(old_dir)
        a, b = read_tir(old)["LONGITUDINAL_COEFFICIENTS"], read_tir(new)["LONGITUDINAL_COEFFICIENTS"]
        pairs.append(({k: float(v) for k, v in a.items()}, {k: float(v) for k, v in b.items()}))
        names.append(f"{old.relative_to(old_dir)}: {'same bytes' if old.read_bytes() == new.read_bytes() else 'differ'}")
    print("; ".join(names))
    print("| coefficient | largest relative change |\n|---|---:|")
    for n, c in relative_changes(pairs).items():
        print(f"| {n} | {c:.1e} |")
    return 0


def _child(args: list[str], env: dict[str, str]) -> str:
    """The last line `python -c ARGS` prints (its error's end where it fails)."""
    p = subprocess.run([sys.executable, "-c", *args], env=env, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"a side's process failed ({p.returncode}): {p.stderr[-2000:]}")
    return p.stdout.strip().splitlines()[-1]


def compare_test_data(work: Path, base: str) -> int:
    """The fits of tests/tire_model's points (three synthetic draws, the ABS stop's front tires, the RAV4 drive's
    four), this tree against the base: the largest relative change per coefficient, the curves' largest gap."""
    got = {}
    for name, src in (("this tree", ROOT / "src"), ("base", unpack(base, work / f"base-{base}"))):
        got[name] = json.loads(_child([TEST_DATA, str(ROOT)], side_env(src)))
    print(f"`python -m benchmarks.tire_fit_speed {' '.join(sys.argv[1:])}`: the fits of tests/tire_model's points, "
          f"this tree against base {base}\n\n| fit | largest relative change (coefficient) | curves apart, of the peak |"
          "\n|---|---:|---:|")
    for fit, (new, fnomin) in got["this tree"].items():
        old = got["base"][fit][0]
        changes = relative_changes([(old, new)])
        worst = max(changes, key=lambda n: changes[n])
        print(f"| {fit} | {changes[worst]:.1e} ({worst}) | {curve_gap(new, old, fnomin):.1e} |")
    print("\nper coefficient, over all: " + ", ".join(
        f"{n} {c:.1e}" for n, c in relative_changes([(got["base"][f][0], v) for f, (v, _) in got["this tree"].items()])
        .items()))
    return 0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--hours", type=float, default=0.5, help="hours of log whose points are fitted (default 0.5)")
    ap.add_argument("--copies", type=int, default=4, help="each wheel's points this many times over (default 4)")
    ap.add_argument("--rounds", type=int, default=5, help="timed rounds (default 5)")
    ap.add_argument("--work", type=Path, default=None, help="directory for the log and the points (kept, reused)")
    ap.add_argument("--tir", type=Path, nargs=2, metavar=("OLD", "NEW"), help="compare two folders' .tir files")
    ap.add_argument("--test-data", action="store_true",
                    help="instead, the fits of tests/tire_model's data by both sides: what they give")
    add_base_argument(ap)
    a = ap.parse_args()
    if a.tir:
        return compare_tir(*a.tir)
    if a.test_data:
        return compare_test_data(a.work or Path(tempfile.mkdtemp(prefix="slipdaq-tire-fit-")), resolve(a.base))
    work = a.work or Path(tempfile.mkdtemp(prefix="slipdaq-tire-fit-"))
    work.mkdir(parents=True, exist_ok=True)
    base = resolve(a.base)
    npz, kwargs = fit_inputs(work, a.hours)
    sides = {"this tree": ROOT / "src", f"base {base}": unpack(base, work / f"base-{base}")}
    got: dict[str, list[dict[str, Any]]] = {name: [] for name in sides}
    for r, name in in_turns(sides, a.rounds):
        got[name].append(json.loads(_child([CHILD, str(npz), str(a.copies), json.dumps(kwargs)], side_env(sides[name]))))
        print(f"round {r + 1} {name}: " + ", ".join(f"{w} {v['cpu_s']:.2f} s" for w, v in got[name][-1].items()),
              flush=True)
    this, old = list(sides)
    load = os.getloadavg()
    print(f"\n`python -m benchmarks.tire_fit_speed {' '.join(sys.argv[1:])}`: fit_mf61 of each wheel's points of "
          f"{a.hours:g} h of the cycle drive × {a.copies}; medians of {a.rounds} rounds; {machine()}; load average "
          f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f} at the end\n")
    print(f"| wheel | points | {old} CPU | this tree CPU | ratio | {old} wall | this tree wall |\n"
          "|---|---:|---:|---:|---:|---:|---:|")
    totals = {n: [sum(v["cpu_s"] for v in rnd.values()) for rnd in got[n]] for n in sides}
    for w in kwargs:
        c = {n: statistics.median(rnd[w]["cpu_s"] for rnd in got[n]) for n in sides}
        wall = {n: statistics.median(rnd[w]["wall_s"] for rnd in got[n]) for n in sides}
        print(f"| {w} | {got[this][0][w]['points']:,} | {c[old]:.2f} s | {c[this]:.2f} s | {c[old] / c[this]:.1f}× | "
              f"{wall[old]:.2f} s | {wall[this]:.2f} s |")
    t_old, t_new = statistics.median(totals[old]), statistics.median(totals[this])
    print(f"| all | | {t_old:.2f} s | {t_new:.2f} s | {t_old / t_new:.1f}× | | |")
    fits = [(got[old][0][w]["values"], got[this][0][w]["values"], kwargs[w]["fnomin_n"]) for w in kwargs
            if got[old][0][w]["values"] is not None]
    print("\nthe fits, this tree against the base: largest relative change per coefficient "
          + ", ".join(f"{n} {c:.1e}" for n, c in relative_changes([(o, n) for o, n, _ in fits]).items())
          + "; curves apart by at most " + f"{max(curve_gap(n, o, f) for o, n, f in fits):.1e} of their peak")
    print("\n" + json.dumps({"rounds": got, "load_average": load}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
