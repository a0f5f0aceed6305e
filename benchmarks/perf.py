#!/usr/bin/env python3
"""Performance benchmarks: ingest, replay, latency and CPU of slipdaq, and a profile of the ingest path.
Prints markdown tables; --write also puts them in docs/performance.md (between the perf:begin/perf:end markers).
Not a test: nothing here asserts a target.

    .venv/bin/python -m benchmarks.perf [--quick] [--replay-minutes N] [--only SECTIONS] [--write]

Sections (in this order; each in its module benchmarks/perf_SECTION.py): ingest, replay, latency, cpu, profile.
- ingest:  python-can Messages built in memory first (simulator, 4 WPT messages at 2000 Hz each + 20 Hz NMEA);
           then, interleaved, `rounds` times: slipdaq's live path minus the driver (reader batches of up to 256
           frames, as CanBusSource hands them on for a bus read through python-can: to_frames(msgs) ->
           Pipeline.process_can_batch -> McapLogSink, every frame logged, NMEA lines in arrival order, file closed),
           the same frame by frame (to_frame -> Pipeline.process), and python-can's can.Logger writing the same
           frames to .blf and to .asc. Median frames/s and the ratios.
- replay:  a raw log of N minutes of 4 x 500 Hz + 20 Hz NMEA (written with McapLogSink.on_raw), then
           `slipdaq replay RAW -o OUT` in this process (slipdaq.cli.main). Frames/s and times real time.
- latency: run_daemon in this process on python-can's virtual bus, a sender thread at 4 x 1 kHz + NMEA at 20 Hz on
           a pseudo-terminal; see docs/performance.md for the definition. p50/p99.
- cpu:     `slipdaq run` (slipdaq.__main__.main in a child process) reading a loopback-UDP bus that carries SocketCAN
           frames with kernel stamps and that slipdaq reads as it reads SocketCAN (benchmarks/perf_bus.py), the
           sender in another process; the daemon's CPU time from /proc/PID/stat over the run. At 4 x 1 kHz and at
           9,000 frames/s, with the default can.read_interval_s and with 0 (every frame read as it comes); also
           its latency (same definition). --cpu-profile DIR records the daemon with py-spy.
- profile: py-spy (sampling, if installed; else cProfile) of the ingest loop, time by category.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.doc_block import without_revisions
from benchmarks.perf_common import ROOT, busy_processes, machine
from benchmarks.perf_cpu import CpuResult, cpu_table, run_cpu
from benchmarks.perf_ingest import ingest_table, run_ingest
from benchmarks.perf_latency import Latency, latency_table, run_latency_virtual
from benchmarks.perf_profile import profile_table, profile_target, run_profile
from benchmarks.perf_replay import replay_table, run_replay
from slipdaq.config import Config

SECTIONS = ("ingest", "replay", "latency", "cpu", "profile")


def write_doc(block: str) -> None:
    doc = ROOT / "docs" / "performance.md"
    begin, end = "<!-- perf:begin -->", "<!-- perf:end -->"
    text = doc.read_text() if doc.exists() else f"# Performance\n\n{begin}\n{end}\n"
    if begin not in text or end not in text:
        text += f"\n{begin}\n{end}\n"
    pre, rest = text.split(begin, 1)
    _, post = rest.split(end, 1)
    doc.write_text(f"{pre}{begin}\n{without_revisions(block)}\n{end}{post}")
    print(f"wrote the tables to {doc}")


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "_profile-target":
        profile_target(float(argv[1]))
        return 0
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small sizes, < 1 minute (a smoke run, not the figures)")
    ap.add_argument("--only", default=",".join(SECTIONS), help=f"comma-separated subset of {','.join(SECTIONS)}")
    ap.add_argument("--replay-minutes", type=float, default=None,
                    help="minutes of 4 x 500 Hz log to replay (default 60, the issue's definition; --quick 0.25)")
    ap.add_argument("--ingest-seconds", type=float, default=None, help="seconds of 4 x 2000 Hz data (default 6)")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved rounds of the ingest comparison (default 3)")
    ap.add_argument("--latency-seconds", type=float, default=None, help="default 20")
    ap.add_argument("--cpu-seconds", type=float, default=None, help="seconds per CPU run (default 20)")
    ap.add_argument("--profile-seconds", type=float, default=None, help="default 3")
    ap.add_argument("--read-intervals-ms", type=lambda v: [float(x) for x in v.split(",")], default=None,
                    metavar="MS,MS,...", help="cpu section: instead of its default loads, 4 x 1 kHz with each of these "
                                              "can.read_interval_s in turn (e.g. 20,0,20,0,20,50)")
    ap.add_argument("--cpu-profile", default=None, metavar="DIR",
                    help="with the cpu section: py-spy record the daemon over its sending window into DIR "
                         "(raw collapsed stacks, one file per run; the CPU share then includes py-spy's pauses)")
    ap.add_argument("--tmp-dir", default=None, help="where the logs are written (default: the system's temp dir)")
    ap.add_argument("--write", action="store_true", help="also write the tables into docs/performance.md")
    a = ap.parse_args(argv)
    q = a.quick
    a.replay_minutes = a.replay_minutes if a.replay_minutes is not None else (0.25 if q else 60.0)
    a.ingest_seconds = a.ingest_seconds if a.ingest_seconds is not None else (0.75 if q else 6.0)
    a.latency_seconds = a.latency_seconds if a.latency_seconds is not None else (3.0 if q else 20.0)
    a.cpu_seconds = a.cpu_seconds if a.cpu_seconds is not None else (4.0 if q else 20.0)
    a.profile_seconds = a.profile_seconds if a.profile_seconds is not None else (0.5 if q else 3.0)
    only = [s.strip() for s in a.only.split(",") if s.strip()]
    bad = [s for s in only if s not in SECTIONS]
    if bad:
        ap.error(f"unknown section(s) {bad}: choose from {SECTIONS}")
    started = time.time()
    load0 = os.getloadavg()
    busy0 = busy_processes()
    mach = machine()
    cmd = "python -m benchmarks.perf " + " ".join(argv)
    print(f"slipdaq performance benchmarks — {cmd.strip()}", flush=True)
    out: list[str] = []
    with tempfile.TemporaryDirectory(dir=a.tmp_dir, prefix="slipdaq-perf-") as td:
        tmp = Path(td)
        if "ingest" in only:
            ingest = run_ingest(a, tmp)
            out.append("### 1. Ingest (live path minus the driver)\n\n" + ingest_table(ingest))
        if "replay" in only:
            rep = run_replay(a, tmp)
            out.append("### 2. Replay\n\n" + replay_table(rep))
        lats: list[Latency] = []
        cpus: list[CpuResult] = []
        if "latency" in only:
            lats.append(run_latency_virtual(a, tmp))
        if "cpu" in only:
            loads = [(4000.0, "4 × 1 kHz + 20 Hz NMEA"), (9000.0, "9,000 frames/s (4 × 2250 Hz) + 20 Hz NMEA")]
            default_s = Config().can.read_interval_s
            if a.quick:
                loads = loads[:1]
            if a.read_intervals_ms:  # these intervals in turn at 4 x 1 kHz (repeats and alternations show the spread)
                for ms in a.read_intervals_ms:
                    cpus.append(run_cpu(a, tmp, 4000.0, f"{loads[0][1]}, read interval {ms:g} ms",
                                        read_interval_s=ms / 1e3))
            else:
                for rate, label in loads:
                    cpus.append(run_cpu(a, tmp, rate, f"{label}, read interval {default_s * 1e3:g} ms (default)"))
                if not a.quick:  # the same without pacing: every frame read as it comes
                    for rate, label in loads:
                        cpus.append(run_cpu(a, tmp, rate, f"{label}, read interval 0 (every frame)",
                                            read_interval_s=0.0))
            lats += [c.latency for c in cpus if c.latency is not None]
        if lats:
            out.append("### 3. Latency\n\n" + latency_table(lats))
        if cpus:
            out.append("### 4. CPU of `slipdaq run`\n\n" + cpu_table(cpus))
        if "profile" in only:
            out.append("### 5. Profile of the ingest path\n\n" + profile_table(run_profile(a, tmp)))
    elapsed = time.time() - started
    load1 = os.getloadavg()
    head = ("**Machine.** " + "; ".join(f"{k}: {v}" for k, v in mach.items() if v) +
            f".\n\n**Command.** `{cmd.strip()}` — {elapsed / 60:.1f} min, run "
            f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.\n\n**Load.** 1-minute load average "
            f"{load0[0]:.2f} at the start, {load1[0]:.2f} at the end, on {os.cpu_count()} CPUs" +
            (f"; other processes busy at the start: {busy0}" if busy0 else "") + ".")
    block = head + "\n\n" + "\n\n".join(out)
    print("\n" + block)
    if a.write:
        write_doc(block)
    return 0


if __name__ == "__main__":
    sys.exit(main())
