#!/usr/bin/env python3
"""Per-GPS-epoch costs, a base revision against this tree, in one run (docs/performance.md, "Per GPS epoch").

An epoch is what one GPS fix costs whatever the batching of CAN frames: its NMEA lines decoded (NmeaDecoder.decode),
the fix into the estimator (SlipEstimator.add_gps, with the estimate it makes ready) and the JSON the log writes
for the fix and the estimate. A simulated drive (cycle, paved; 4 wheels x 500 Hz, 20 Hz RMC + GGA + VTG, latency
"auto") is generated once; each side then runs it in its own subprocess (the base from `git archive BASE src config`
on PYTHONPATH), alternating, and every call of those functions is timed. Per round, the median over epochs; the
table gives the lowest of the rounds' medians (the round least disturbed by other load on the machine), in
microseconds, and the ratio base/new. The estimates' JSON of both sides is compared: "identical" means every value
bit for bit (the JSON's decimals may differ: orjson writes 1e-05 as 0.00001).

    python -m benchmarks.perf_epoch [--base REV] [--seconds 30] [--rounds 5]

REV defaults to the merge base of HEAD with main.
    python -m benchmarks.perf_epoch --check    # no timing: every output of both sides on CHECK_CASES, compared

--check runs both sides on several drives (CHECK_CASES: configs, GPS lost, NMEA arrival jitter, epochs out of
order) and compares every GpsFix, decoder counter, estimate and estimator status, as repr (exact floats).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import pickle
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.base_revision import add_base_argument, resolve, under, unpack

ROOT = Path(__file__).resolve().parent.parent
ROWS = (
    ("nmea_line", "NMEA line decoded (NmeaDecoder.decode)"),
    ("add_gps", "GPS fix into the estimator (add_gps, with its estimate)"),
    ("estimate_json", "estimate to JSON (as McapLogSink.on_estimate)"),
    ("fix_json", "fix to JSON (as McapLogSink.on_fix)"),
    ("epoch", "one 20 Hz epoch: 3 lines + fix + estimate + both JSON"),
)


CHECK_CASES: list[tuple[str, dict[str, Any], dict[str, Any], str, str, float, str]] = [
    # name, config overrides, SimSettings, scenario, road, seconds, edit of the NMEA stream
    ("auto", {}, {"wpt_rate_hz": 500.0, "gps_rate_hz": 20.0, "gps_latency_s": 0.08}, "cycle", "paved", 90, ""),
    ("fixed latency", {"gps": {"latency_s": 0.05}}, {"wpt_rate_hz": 500.0, "gps_rate_hz": 20.0, "gps_latency_s": 0.05},
     "brake", "sand", 40, ""),
    ("grade, road loads, r0 not calibrated, host clock off",
     {"estimator": {"grade_from_altitude": True, "calibrate_r0": False},
      "vehicle": {"rolling_resistance_coeff": 0.012, "drag_area_m2": 0.7}},
     {"wpt_rate_hz": 200.0, "gps_rate_hz": 10.0, "gps_latency_s": 0.1, "host_clock_offset_s": 0.3},
     "accelerate", "paved", 40, ""),
    ("rear drive, UBX velocity", {"vehicle": {"driven_axle": "rear"}, "gps": {"velocity": "ubx"}},
     {"wpt_rate_hz": 500.0, "gps_rate_hz": 20.0, "gps_protocol": "both", "gps_latency_s": 0.03}, "cycle", "paved", 60,
     ""),
    ("all-wheel drive, CAN jitter", {"vehicle": {"driven_axle": "all"}},
     {"wpt_rate_hz": 250.0, "gps_rate_hz": 20.0, "can_jitter_s": 0.002}, "cycle", "sand", 60, ""),
    ("GPS lost twice", {}, {"wpt_rate_hz": 500.0, "gps_rate_hz": 20.0, "gps_latency_s": 0.08}, "cycle", "paved", 60,
     "gap"),
    ("NMEA arrival jitter 150 ms, RMC gaps (VTG fixes)", {},
     {"wpt_rate_hz": 250.0, "gps_rate_hz": 20.0, "gps_latency_s": 0.05}, "cycle", "paved", 60, "jitter"),
    ("epochs out of order", {}, {"wpt_rate_hz": 250.0, "gps_rate_hz": 20.0, "gps_latency_s": 0.05}, "cycle", "paved",
     60, "disorder"),
]


def make_records(seconds: float, path: Path, overrides: dict[str, Any] | None = None,
                 settings: dict[str, Any] | None = None, scenario: str = "cycle", road: str = "paved",
                 edit: str = "") -> None:
    """The drive's records as plain tuples (either side's record classes rebuild them)."""
    import random

    from slipdaq.config import load_config, packaged_config_path
    from slipdaq.records import CanFrame, NmeaLine, UbxFrame
    from slipdaq.sim.emit import SimSettings, generate

    cfg = load_config(packaged_config_path()).with_overrides(**(overrides or {}))
    sim = SimSettings(**(settings or {"wpt_rate_hz": 500.0, "gps_rate_hz": 20.0, "gps_latency_s": 0.05}))
    rng, last_s = random.Random(1), 0.0
    timed: list[tuple[float, tuple[Any, ...]]] = []
    for ev in generate(cfg, scenario, road, sim, duration_s=seconds):  # type: ignore[arg-type]
        r, t = ev.record, ev.time_s
        if isinstance(r, CanFrame):
            timed.append((t, ("c", r.timestamp_s, r.arbitration_id, bytes(r.data), r.is_extended_id)))
        elif isinstance(r, UbxFrame):
            timed.append((t, ("u", r.timestamp_s, bytes(r.data))))
        elif isinstance(r, NmeaLine):
            if edit == "gap" and (20 <= t < 27 or 35 <= t < 35.6):
                continue
            if edit in ("jitter", "disorder"):
                if r.line[3:6] == "RMC" and int(t) % 10 in (3, 4, 5):
                    continue
                delay = rng.uniform(0.0, 0.15)
                if edit == "jitter":
                    delay = max(delay, last_s - t)  # the serial line keeps the order
                last_s = t + delay
                t = t + delay
                timed.append((t, ("n", r.timestamp_s + delay, r.line)))
            else:
                timed.append((t, ("n", r.timestamp_s, r.line)))
    timed.sort(key=lambda x: x[0])
    path.write_bytes(pickle.dumps({"overrides": overrides or {}, "records": [rec for _, rec in timed]}))


def check_worker(paths: list[Path]) -> dict[str, str]:
    """Every output of decoding and estimating each case, hashed."""
    from slipdaq.config import load_config, packaged_config_path
    from slipdaq.decode.can_wheels import WheelDecoder
    from slipdaq.decode.nmea import NmeaDecoder
    from slipdaq.decode.ubx import UbxDecoder
    from slipdaq.estimator import EstimatorParams, SlipEstimator
    from slipdaq.records import CanFrame, NmeaLine, UbxFrame

    out = {}
    for path in paths:
        case = pickle.loads(path.read_bytes())
        cfg = load_config(packaged_config_path()).with_overrides(**case["overrides"])
        wheels, nmea, ubx = WheelDecoder(cfg), NmeaDecoder(), UbxDecoder()
        est = SlipEstimator(EstimatorParams.from_config(cfg))
        digest = hashlib.sha256()
        for rec in case["records"]:
            if rec[0] == "c":
                for sample in wheels.decode(CanFrame(rec[1], rec[2], rec[3], rec[4])):
                    for e in est.add_wheel(sample):
                        digest.update(repr(e).encode())
                continue
            record = NmeaLine(rec[1], rec[2]) if rec[0] == "n" else UbxFrame(rec[1], rec[2])
            fix = nmea.decode(record) if rec[0] == "n" else ubx.decode(record)
            if fix is None:
                continue
            digest.update(repr(fix).encode())
            if (rec[0] == "n") == (cfg.gps.velocity == "nmea"):
                for e in est.add_gps(fix):
                    digest.update(repr(e).encode())
        counters = {k: v for k, v in vars(nmea).items() if k != "_fast_path"}
        digest.update(repr(counters).encode() + repr(est.status()).encode())
        out[path.name] = digest.hexdigest()
    return out


def _exact(x: Any) -> Any:
    """A decoded JSON value with each float by its bits (the digest compares values, whatever the JSON's decimals)."""
    if isinstance(x, float):
        return x.hex()
    if isinstance(x, dict):
        return {k: _exact(v) for k, v in x.items()}
    return [_exact(v) for v in x] if isinstance(x, list) else x


def worker(records_path: Path) -> dict[str, Any]:
    """One timed pass over the drive with whatever slipdaq is on the path; medians in seconds."""
    from slipdaq.config import load_config, packaged_config_path
    from slipdaq.decode.can_wheels import WheelDecoder
    from slipdaq.decode.nmea import NmeaDecoder
    from slipdaq.estimator import EstimatorParams, SlipEstimator
    from slipdaq.records import CanFrame, NmeaLine
    from slipdaq.sinks.mcap_log import McapLogSink

    cfg = load_config(packaged_config_path())
    wheels = WheelDecoder(cfg)
    items: list[Any] = []  # wheel samples and NMEA lines in record order (CAN decoding is not timed)
    for rec in pickle.loads(records_path.read_bytes())["records"]:
        if rec[0] == "c":
            items.extend(wheels.decode(CanFrame(rec[1], rec[2], rec[3], rec[4])))
        else:
            items.append(NmeaLine(rec[1], rec[2]))
    sink = McapLogSink.__new__(McapLogSink)  # only its encoders: _write is captured below
    payloads: list[bytes] = []
    sink._write = lambda topic, t, data: payloads.append(data)  # type: ignore[method-assign]
    nmea, est = NmeaDecoder(), SlipEstimator(EstimatorParams.from_config(cfg))
    clock = time.perf_counter
    lines: list[float] = []
    fixes: list[float] = []
    est_json: list[float] = []
    fix_json: list[float] = []
    epochs: list[float] = []
    epoch_lines = 0.0
    digest = hashlib.sha256()
    for item in items:
        if not isinstance(item, NmeaLine):
            est.add_wheel(item)
            continue
        t0 = clock()
        fix = nmea.decode(item)
        dt = clock() - t0
        lines.append(dt)
        epoch_lines += dt
        if fix is None:
            continue
        t0 = clock()
        sink.on_fix(fix)
        t1 = clock()
        estimates = est.add_gps(fix)
        t2 = clock()
        fix_json.append(t1 - t0)
        dt_json = 0.0
        for e in estimates:
            t3 = clock()
            sink.on_estimate(e, fix.timestamp_s)
            dt_json += clock() - t3
            digest.update(repr(_exact(json.loads(payloads[-1]))).encode())
        if len(estimates) == 1:
            fixes.append(t2 - t1)
            est_json.append(dt_json)
            epochs.append(epoch_lines + (t1 - t0) + (t2 - t1) + dt_json)
        epoch_lines = 0.0
    med = statistics.median
    return {"nmea_line": med(lines), "add_gps": med(fixes), "estimate_json": med(est_json),
            "fix_json": med(fix_json), "epoch": med(epochs), "epochs": len(epochs), "lines": len(lines),
            "estimates_sha256": digest.hexdigest()}


def run_side(src: Path, *args: str) -> dict[str, Any]:
    cmd, env = under(src, __file__, *args)
    out = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def check(base: Path) -> int:
    """--check: both sides on CHECK_CASES."""
    tmp = base.parent
    paths = []
    for k, (_name, overrides, settings, scenario, road, seconds, edit) in enumerate(CHECK_CASES):
        paths.append(tmp / f"case-{k}.pkl")
        make_records(seconds, paths[-1], overrides, settings, scenario, road, edit)
    sides = {side: run_side(src, "--check-worker", *map(str, paths)) for side, src in
             (("base", base), ("new", ROOT / "src"))}
    same = True
    for k, case in enumerate(CHECK_CASES):
        equal = sides["base"][paths[k].name] == sides["new"][paths[k].name]
        same &= equal
        print(f"{'identical' if equal else 'DIFFERENT'}: {case[0]}")
    return 0 if same else 1


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_base_argument(ap)
    ap.add_argument("--seconds", type=float, default=30.0, help="seconds of simulated drive (default 30)")
    ap.add_argument("--rounds", type=int, default=5, help="alternating runs per side (default 5)")
    ap.add_argument("--check", action="store_true", help="compare every output on CHECK_CASES instead of timing")
    ap.add_argument("--worker", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--check-worker", type=Path, nargs="+", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker is not None:
        print(json.dumps(worker(a.worker)))
        return 0
    if a.check_worker is not None:
        print(json.dumps(check_worker(a.check_worker)))
        return 0
    with tempfile.TemporaryDirectory(prefix="perf-epoch-") as tmp_name:
        tmp = Path(tmp_name)
        a.base = resolve(a.base)
        unpack(a.base, tmp / "base")
        records = tmp / "records.pkl"
        sys.path.insert(0, str(ROOT / "src"))
        if a.check:
            return check(tmp / "base" / "src")
        make_records(a.seconds, records)
        sides = {"base": tmp / "base" / "src", "new": ROOT / "src"}
        runs: dict[str, list[dict[str, Any]]] = {k: [] for k in sides}
        for _ in range(a.rounds):
            for name, src in sides.items():
                runs[name].append(run_side(src, "--worker", str(records)))
    best = {k: {key: min(r[key] for r in v) for key, _ in ROWS} for k, v in runs.items()}
    spread = {k: {key: max(r[key] for r in v) / best[k][key] for key, _ in ROWS} for k, v in runs.items()}
    same = {r["estimates_sha256"] for v in runs.values() for r in v}
    print(f"{a.seconds:g} s of drive, {runs['new'][0]['epochs']} epochs with one estimate, "
          f"{runs['new'][0]['lines']} NMEA lines; {a.rounds} alternating rounds; base {a.base}")
    print("estimates' JSON values identical to the base: " + ("yes, bit for bit" if len(same) == 1 else "NO"))
    print()
    print(f"| per (median over epochs, best of {a.rounds} rounds) | {a.base} µs | this tree µs | ratio |")
    print("|---|---:|---:|---:|")
    for key, label in ROWS:
        b, n = best["base"][key] * 1e6, best["new"][key] * 1e6
        print(f"| {label} | {b:.1f} | {n:.1f} | {b / n:.1f}x |")
    worst = max(max(v.values()) for v in spread.values())
    print(f"\nslowest round / best round, worst row: {worst:.2f}x (other load on the machine)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
