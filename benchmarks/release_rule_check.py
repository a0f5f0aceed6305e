#!/usr/bin/env python3
"""What the estimate release rule of this tree changes against a base revision (default 31a7796, before the rule),
on a drive whose NMEA lines are read with a serial port's jitter (docs/performance.md, "This round").

A 60 s simulated drive (cycle, paved; 4 wheels x 1 kHz, 20 Hz RMC + GGA + VTG, receiver latency 0) is logged raw by
the base's code (a log written by a newer slipdaq has config keys an older one refuses), each NMEA line stamped
0.2-4 ms after its time (uniform, seed 7), as a pty read would; then both sides replay it (`python -m slipdaq
replay`, the base from `git archive BASE src config` on PYTHONPATH) and their GPS-mode estimates are compared by
centre time: how much earlier this tree releases them (log time) and how much their slip differs.

    python benchmarks/release_rule_check.py [--base 31a7796] [--seconds 60]
"""

from __future__ import annotations

import argparse
import io
import json
import os
import random
import statistics
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def write_jittered_log(path: Path, seconds: float) -> None:
    """(Runs under the base's slipdaq.) The drive, raw, NMEA stamped late by a read delay."""
    from dataclasses import replace

    from slipdaq.config import load_config, packaged_config_path
    from slipdaq.records import NmeaLine
    from slipdaq.sim.emit import SimSettings, generate
    from slipdaq.sinks.mcap_log import McapLogSink

    cfg = load_config(packaged_config_path())
    rng = random.Random(7)
    sink = McapLogSink(path, cfg, mode="bench-raw")
    settings = replace(SimSettings(), wpt_rate_hz=1000.0, gps_rate_hz=20.0, gps_latency_s=0.0, can_jitter_s=0.0002)
    for ev in generate(cfg, "cycle", "paved", settings, duration_s=seconds):  # type: ignore[arg-type]
        r = ev.record
        if r is None:
            continue
        if isinstance(r, NmeaLine):
            r = replace(r, timestamp_s=r.timestamp_s + rng.uniform(0.0002, 0.004))
        sink.on_raw(r)
    sink.close()


def gps_estimates(path: Path) -> dict[float, tuple[int, dict]]:
    from mcap.reader import make_reader

    out = {}
    with open(path, "rb") as f:
        for _s, _c, m in make_reader(f).iter_messages(topics=["/estimate"], log_time_order=False):
            d = json.loads(m.data)
            if d.get("source") == "gps":
                out[d["time_s"]] = (m.log_time, d)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", default="31a7796")
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--write-log", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.write_log:
        write_jittered_log(Path(a.write_log), a.seconds)
        return 0
    with tempfile.TemporaryDirectory(prefix="slipdaq-release-") as td:
        work = Path(td)
        archive = subprocess.run(["git", "-C", str(ROOT), "archive", a.base, "src", "config"], check=True,
                                 capture_output=True).stdout
        with tarfile.open(fileobj=io.BytesIO(archive)) as tar:
            tar.extractall(work / "base")
        env_base = dict(os.environ, PYTHONPATH=str(work / "base" / "src"))
        env_new = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
        raw = work / "raw.mcap"
        subprocess.run([sys.executable, __file__, "--write-log", str(raw), "--seconds", str(a.seconds)], env=env_base,
                       check=True)
        for side, env in (("base", env_base), ("new", env_new)):
            subprocess.run([sys.executable, "-m", "slipdaq", "replay", str(raw), "-o", str(work / f"{side}.mcap")],
                           env=env, check=True, capture_output=True)
        base, new = gps_estimates(work / "base.mcap"), gps_estimates(work / "new.mcap")
    common = sorted(set(base) & set(new))
    earlier_ms = [(base[t][0] - new[t][0]) / 1e6 for t in common]
    dslip = sorted(abs(base[t][1][k] - new[t][1][k]) * 100 for t in common for k in base[t][1]
                   if k.startswith("slip_") and base[t][1][k] is not None and new[t][1].get(k) is not None)
    print(f"base {a.base}: {len(base)} GPS estimates, this tree {len(new)}; {len(common)} with the same centre time "
          f"(the others moved with the GPS latency estimate)")
    print(f"released earlier: median {statistics.median(earlier_ms):.1f} ms, max {max(earlier_ms):.1f} ms; "
          f"{sum(e > 1 for e in earlier_ms) / len(earlier_ms):.0%} more than 1 ms earlier")
    print(f"|slip difference| over {len(dslip)} wheel values: median {statistics.median(dslip):.2e}, "
          f"max {max(dslip):.2e} percentage points")
    return 0


if __name__ == "__main__":
    sys.exit(main())
