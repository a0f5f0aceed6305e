"""A sampling profile of the ingest path (py-spy, else cProfile), time by category."""

from __future__ import annotations

import argparse
import io
import os
import shutil
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path
from typing import Any

import slipdaq
from benchmarks.perf_common import ROOT, base_config, reader_batches, sim_items, table
from benchmarks.perf_ingest import ingest_batched

PROFILE_RULES: list[tuple[str, tuple[str, ...]]] = [
    # by module (file path in the stack), innermost match first: no names of private functions here
    ("estimator: readiness (estimator/readiness.py kernel)", ("estimator/readiness.py",)),
    ("estimator: GPS latency (estimator/latency.py)", ("estimator/latency.py",)),
    ("estimator: samples into the rings (SeriesRing)", ("estimator/ring.py",)),
    ("estimator: window maths (gps_track, windows, force, radius, stiffness, slip)", ("estimator/",)),
    ("decode: wheel frames (can_wheels, wheel_unwrap kernel, cantools)",
     ("decode/can_wheels.py", "decode/wheel_unwrap.py", "cantools")),
    ("decode: GPS (nmea, ubx, framing, pynmea2)", ("decode/", "pynmea2")),
    ("compiled kernels: numba dispatch", ("numba", "slipdaq/compiled/")),
    ("log: estimates, fixes, diagnostics to JSON", ("logformat/json_codec.py", "json/")),
    ("log: CDR batches (logformat/cdr.py)", ("logformat/cdr.py",)),
    ("log: mcap Writer.add_message, chunks, zstd", ("mcap/", "zstandard")),
    ("log: McapLogSink and the log writer", ("sinks/mcap_log.py", "logformat/")),
    ("pipeline (dispatch, counters, decode ahead)", ("slipdaq/pipeline.py",)),
    ("source: to_frames and records (can.Message -> CanFrameBatch columns)", ("sources/", "slipdaq/records.py")),
    ("benchmark driver loop", ("benchmarks/perf.py",)),
]


def categorise(stack: str) -> str:
    frames = stack.split(";")
    for f in reversed(frames):
        for name, pats in PROFILE_RULES:
            if any(p in f for p in pats):
                return name
    return "other"


def profile_target(seconds: float) -> None:
    """Child of the profile section: the ingest loop of the current design, under py-spy."""
    import slipdaq.pipeline  # noqa: F401  (imports outside the profiled loop)
    import slipdaq.sinks.mcap_log  # noqa: F401
    import slipdaq.sources.can_bus  # noqa: F401

    cfg = base_config()
    batches = reader_batches(sim_items(2000.0, 20.0, seconds))
    tmp = Path(tempfile.mkdtemp())

    def ingest_loop() -> None:
        ingest_batched(cfg, batches, tmp / "p.mcap")

    ingest_loop()
    shutil.rmtree(tmp, ignore_errors=True)


def run_profile(a: argparse.Namespace, tmp: Path) -> dict[str, Any]:
    pyspy = shutil.which("py-spy") or (str(Path(sys.executable).parent / "py-spy")
                                       if (Path(sys.executable).parent / "py-spy").exists() else None)
    seconds = a.profile_seconds
    print(f"profile: ingest loop over {seconds:g} s of 4 x 2000 Hz data, "
          f"{'py-spy (sampling, 1 kHz)' if pyspy else 'cProfile (py-spy not installed)'}...", flush=True)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(Path(slipdaq.__file__).resolve().parents[1]), str(ROOT)] +
                                        ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    if pyspy:
        raw = tmp / "pyspy.txt"
        proc = subprocess.run([pyspy, "record", "-r", "1000", "-f", "raw", "-o", str(raw), "--",
                               sys.executable, "-m", "benchmarks.perf", "_profile-target", str(seconds)],
                              capture_output=True, text=True, env=env)
        if proc.returncode == 0 and raw.exists():
            counts: Counter[str] = Counter()
            total = 0
            for line in raw.read_text().splitlines():
                stack, _, n = line.rpartition(" ")
                if "ingest_loop" not in stack or any(x in stack for x in (
                        "_find_and_load", "Pipeline.__init__", "McapLogSink.__init__")):
                    continue  # imports and construction are not the ingest path
                counts[categorise(stack)] += int(n)
                total += int(n)
            raw.unlink()
            return {"tool": "py-spy 1 kHz sampling", "total": total, "counts": counts}
        print(f"  py-spy failed ({proc.stderr.strip()[-200:]}); using cProfile", flush=True)
    import cProfile
    import pstats

    cfg = base_config()
    batches = reader_batches(sim_items(2000.0, 20.0, seconds))
    pr = cProfile.Profile()
    pr.enable()
    ingest_batched(cfg, batches, tmp / "p.mcap")
    pr.disable()
    s = io.StringIO()
    pstats.Stats(pr, stream=s).sort_stats("tottime").print_stats(15)
    return {"tool": "cProfile", "text": s.getvalue()}


def profile_table(prof: dict[str, Any]) -> str:
    if "counts" not in prof:
        return "```\n" + prof["text"][-4000:] + "\n```"
    total = prof["total"]
    rows = [[name, f"{100 * n / total:.1f} %"] for name, n in prof["counts"].most_common()]
    return (f"{prof['tool']}, {total:,} samples inside the ingest loop; each sample goes to the innermost frame that "
            f"matches a category (so numpy called by the estimator counts as estimator).\n\n" +
            table(["where the time goes (current design, ingest path)", "share"], rows))
