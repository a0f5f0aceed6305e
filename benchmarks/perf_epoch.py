#!/usr/bin/env python3
"""Per-GPS-epoch costs, a base revision against this tree, in one run (docs/performance.md, "Per-GPS-epoch costs").

An epoch is what one GPS fix costs whatever the batching of CAN frames: its NMEA lines decoded (NmeaDecoder.decode),
the fix into the estimator (SlipEstimator.add_gps, with the estimate it makes ready) and the JSON the log writes
for the fix and the estimate. A simulated drive (cycle, paved; 4 wheels x 500 Hz, 20 Hz RMC + GGA + VTG, latency
"auto") is generated once; each side then runs it in its own subprocess (the base from `git archive BASE src config`
on PYTHONPATH), alternating, and every call of those functions is timed. The table gives medians over epochs (the
median of the rounds' medians), in microseconds, and the ratio base/new. The estimates' JSON of both sides is
compared: "identical" means byte for byte.

    python benchmarks/perf_epoch.py [--base 8a93b17] [--seconds 60] [--rounds 3]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import pickle
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
ROWS = (
    ("nmea_line", "NMEA line decoded (NmeaDecoder.decode)"),
    ("add_gps", "GPS fix into the estimator (add_gps, with its estimate)"),
    ("estimate_json", "estimate to JSON (as McapLogSink.on_estimate)"),
    ("fix_json", "fix to JSON (as McapLogSink.on_fix)"),
    ("epoch", "one 20 Hz epoch: 3 lines + fix + estimate + both JSON"),
)


def make_records(seconds: float, path: Path) -> None:
    """The drive's records as plain tuples (either side's record classes rebuild them)."""
    from slipdaq.config import load_config, packaged_config_path
    from slipdaq.records import CanFrame
    from slipdaq.sim.emit import SimSettings, generate

    cfg = load_config(packaged_config_path())
    settings = SimSettings(wpt_rate_hz=500.0, gps_rate_hz=20.0, gps_latency_s=0.05)
    out: list[tuple[Any, ...]] = []
    for ev in generate(cfg, "cycle", "paved", settings, duration_s=seconds):
        r = ev.record
        if isinstance(r, CanFrame):
            out.append(("c", r.timestamp_s, r.arbitration_id, bytes(r.data), r.is_extended_id))
        elif r is not None:
            out.append(("n", r.timestamp_s, r.line))
    path.write_bytes(pickle.dumps(out))


def worker(records_path: Path) -> dict[str, Any]:
    """One timed pass over the drive with whatever slipdaq is on the path; medians in seconds."""
    from slipdaq.config import load_config, packaged_config_path
    from slipdaq.decode.can_wheels import WheelDecoder
    from slipdaq.decode.nmea import NmeaDecoder
    from slipdaq.estimator import EstimatorParams, SlipEstimator
    from slipdaq.records import CanFrame, NmeaLine
    from slipdaq.sinks import mcap_log as M

    cfg = load_config(packaged_config_path())
    wheels = WheelDecoder(cfg)
    items: list[Any] = []  # wheel samples and NMEA lines in record order (CAN decoding is not timed)
    for rec in pickle.loads(records_path.read_bytes()):
        if rec[0] == "c":
            items.extend(wheels.decode(CanFrame(rec[1], rec[2], rec[3], rec[4])))
        else:
            items.append(NmeaLine(rec[1], rec[2]))
    sink = M.McapLogSink.__new__(M.McapLogSink)  # only its encoders: _write is captured below
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
            digest.update(payloads[-1])
        if len(estimates) == 1:
            fixes.append(t2 - t1)
            est_json.append(dt_json)
            epochs.append(epoch_lines + (t1 - t0) + (t2 - t1) + dt_json)
        epoch_lines = 0.0
    med = statistics.median
    return {"nmea_line": med(lines), "add_gps": med(fixes), "estimate_json": med(est_json),
            "fix_json": med(fix_json), "epoch": med(epochs), "epochs": len(epochs), "lines": len(lines),
            "estimates_sha256": digest.hexdigest()}


def run_side(src: Path, records: Path) -> dict[str, Any]:
    env = dict(os.environ, PYTHONPATH=str(src))
    out = subprocess.run([sys.executable, __file__, "--worker", str(records)], env=env, check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", default="8a93b17", help="the revision to compare against (default 8a93b17)")
    ap.add_argument("--seconds", type=float, default=60.0, help="seconds of simulated drive (default 60)")
    ap.add_argument("--rounds", type=int, default=3, help="alternating runs per side (default 3)")
    ap.add_argument("--worker", type=Path, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.worker is not None:
        print(json.dumps(worker(a.worker)))
        return 0
    with tempfile.TemporaryDirectory(prefix="perf-epoch-") as tmp_name:
        tmp = Path(tmp_name)
        archive = tmp / "base.tar"
        subprocess.run(["git", "-C", str(ROOT), "archive", "-o", str(archive), a.base, "src", "config"], check=True)
        with tarfile.open(archive) as tar:
            tar.extractall(tmp / "base", filter="tar")
        records = tmp / "records.pkl"
        sys.path.insert(0, str(ROOT / "src"))
        make_records(a.seconds, records)
        sides = {"base": tmp / "base" / "src", "new": ROOT / "src"}
        runs: dict[str, list[dict[str, Any]]] = {k: [] for k in sides}
        for _ in range(a.rounds):
            for name, src in sides.items():
                runs[name].append(run_side(src, records))
    med = {k: {key: statistics.median(r[key] for r in v) for key, _ in ROWS} for k, v in runs.items()}
    same = {r["estimates_sha256"] for v in runs.values() for r in v}
    print(f"{a.seconds:g} s of drive, {runs['new'][0]['epochs']} epochs with one estimate, "
          f"{runs['new'][0]['lines']} NMEA lines; {a.rounds} alternating rounds; base {a.base}")
    print("estimates' JSON identical to the base: " + ("yes, byte for byte" if len(same) == 1 else "NO"))
    print()
    print(f"| per | {a.base} µs | this tree µs | ratio |")
    print("|---|---:|---:|---:|")
    for key, label in ROWS:
        b, n = med["base"][key] * 1e6, med["new"][key] * 1e6
        print(f"| {label} | {b:.1f} | {n:.1f} | {b / n:.1f}x |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
