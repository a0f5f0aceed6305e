#!/usr/bin/env python3
"""`slipdaq import` of a candump -L log against python-can's candump -> BLF on the same log, whole processes
(interpreter start and imports included in both), interleaved rounds. Figures for docs/performance.md ("Import").

The simulator's `cycle` drive (4 WPT messages at --wpt-rate-hz each, 10 Hz NMEA, CAN jitter 0.2 ms) is written once
as a candump -L log and a timestamped NMEA log (sim/logs.py, python-can's candump writer). Then per round, in an order
that turns every round: (a) `python -m slipdaq import --can LOG --nmea NMEA --config CFG -o OUT --no-calibration`
with this tree's src (and with --base REV's, `git archive`d, side by side); (b) python-can in a python process:
`can.LogReader(LOG)` (its CanutilsLogReader) into `can.BLFWriter`. One untimed warm-up run of each first (page cache,
numba's kernel cache). Frames/s = CAN frames / median wall time; the ratio to BLF per round, and its median.
--profile also runs this tree's import once under cProfile and splits its time by part (where the floor is).

    python -m benchmarks.import_speed [--seconds 120] [--short-seconds 1] [--wpt-rate-hz 1000] [--rounds 5]
                                      [--base REV] [--profile] [--write]
"""

from __future__ import annotations

import argparse
import os
import platform
import pstats
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.base_revision import ROOT, unpack
from benchmarks.doc_block import write_block

DOC = ROOT / "docs" / "performance.md"
BEGIN, END = "<!-- import:begin -->", "<!-- import:end -->"

MAKE_LOGS = """
import sys
from dataclasses import replace
from pathlib import Path
from slipdaq.config import load_config, packaged_config_path
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.logs import write_drive_logs
cfg = load_config(packaged_config_path())
s = replace(SimSettings(), wpt_rate_hz=float(sys.argv[3]), gps_rate_hz=10.0, gps_latency_s=0.05, can_jitter_s=0.0002)
write_drive_logs(generate(cfg, "cycle", "paved", s, duration_s=float(sys.argv[4])), Path(sys.argv[1]), Path(sys.argv[2]))
"""

BLF = """
import sys, can
with can.LogReader(sys.argv[1]) as reader, can.BLFWriter(sys.argv[2]) as writer:
    for msg in reader:
        writer.on_message_received(msg)
"""

PARTS = (  # (label, path fragments of the functions whose own time counts), first match wins
    ("candump parse (sources/candump)", ("slipdaq/sources/candump.py",)),
    ("merge, batching (sources/files, offline)", ("slipdaq/sources/", "slipdaq/offline.py")),
    ("MCAP library (mcap, zstd)", ("site-packages/mcap/", "zstandard", "ZstdCompressor")),
    ("log writer, codecs (logformat, sinks)", ("slipdaq/logformat/", "slipdaq/sinks/")),
    ("decode (CAN, NMEA)", ("slipdaq/decode/",)),
    ("estimator", ("slipdaq/estimator/",)),
    ("maneuvers", ("slipdaq/maneuver/",)),
    ("pipeline", ("slipdaq/pipeline.py", "slipdaq/records.py", "slipdaq/columns.py")),
    ("numba kernels (load, run)", ("numba", "llvmlite", "slipdaq/compiled/")),
    ("imports (modules' code, loading)", ("<frozen", "marshal", "_imp.", "builtins.compile", "__build_class__",
                                          "_abc_init")),
)


def run_timed(cmd: list[str], env: dict[str, str]) -> tuple[float, float]:
    """(wall seconds, CPU seconds: the child's user + system time) of one run of cmd."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({p.returncode}): {p.stderr[-2000:]}")
    return wall, after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime


def frame_count(log: Path) -> int:
    with open(log, "rb") as f:
        return sum(block.count(b"\n") for block in iter(lambda: f.read(1 << 20), b""))


def _part(file: str, name: str) -> str | None:
    where = f"{file}:{name}"
    return next((label for label, frags in PARTS if any(f in where for f in frags)), None)


def profile_split(env: dict[str, str], cmd: list[str], tmp: Path) -> tuple[float, list[tuple[str, float]]]:
    """This tree's import once under cProfile: total seconds and each part's own time (PARTS; a built-in function's
    time goes to the part of the function that called it; the rest: other)."""
    prof = tmp / "import.prof"
    subprocess.run([sys.executable, "-m", "cProfile", "-o", str(prof), *cmd[1:]], env=env, check=True,
                   capture_output=True)
    stats = pstats.Stats(str(prof)).stats  # type: ignore[attr-defined]
    split = dict.fromkeys([label for label, _ in PARTS] + ["other"], 0.0)
    for (file, _line, name), (_cc, _nc, tottime, _ct, callers) in stats.items():
        label = _part(file, name)
        if label is None and file == "~" and callers:  # a built-in: its callers' parts, by the time from each
            for (cfile, _cline, cname), (_c, _n, tt, _ct2) in callers.items():
                split[_part(cfile, cname) or "other"] += tt
            continue
        split[label or "other"] += tottime
    total = sum(split.values())
    return total, sorted(split.items(), key=lambda kv: -kv[1])


def table(headers: list[str], rows: list[list[str]]) -> str:
    out = ["| " + " | ".join(headers) + " |", "|---|" + "---:|" * (len(headers) - 1)]
    return "\n".join(out + ["| " + " | ".join(r) + " |" for r in rows])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", default=None, metavar="REV", help="also time this revision's import, side by side")
    ap.add_argument("--seconds", type=float, default=120.0, help="the drive's length (default 120)")
    ap.add_argument("--short-seconds", type=float, default=1.0,
                    help="a short drive timed the same way: the fixed costs (default 1; 0: none)")
    ap.add_argument("--wpt-rate-hz", type=float, default=1000.0, help="frames per second per wheel (default 1000)")
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds (default 5)")
    ap.add_argument("--profile", action="store_true", help="split this tree's import by part (cProfile)")
    ap.add_argument("--tmp-dir", default=None, help="where the logs are written (default: the system's temp dir)")
    ap.add_argument("--write", action="store_true", help="also write the table into docs/performance.md")
    a = ap.parse_args()
    started = time.time()
    load0 = os.getloadavg()[0]
    tmp = Path(tempfile.mkdtemp(prefix="slipdaq-import-", dir=a.tmp_dir))
    try:
        # bytecode cached (as an installed package has it), in the temp dir, not beside the sources
        common = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        common["PYTHONPYCACHEPREFIX"] = str(tmp / "pycache")
        env = dict(common, PYTHONPATH=str(ROOT / "src"))
        cfg = tmp / "slipdaq.toml"
        for f in ("slipdaq.toml", "wpt.dbc", "sensors.dbc"):
            shutil.copy(ROOT / "config" / f, tmp / f)
        inputs = {"long": a.seconds} | ({"short": a.short_seconds} if a.short_seconds > 0 else {})
        frames: dict[str, int] = {}
        for key, seconds in inputs.items():
            print(f"writing {seconds:g} s of 4 x {a.wpt_rate_hz:g} Hz + 10 Hz NMEA ...", flush=True)
            subprocess.run([sys.executable, "-c", MAKE_LOGS, str(tmp / f"{key}.log"), str(tmp / f"{key}.nmea"),
                            str(a.wpt_rate_hz), str(seconds)], env=env, check=True)
            frames[key] = frame_count(tmp / f"{key}.log")
        envs = {"python-can candump -> BLF": env, "`slipdaq import`, this tree": env}
        if a.base:
            envs[f"`slipdaq import`, {a.base}"] = dict(common, PYTHONPATH=str(unpack(a.base, tmp / f"base-{a.base}")))
        names = list(envs)

        def command(name: str, key: str) -> list[str]:
            if name == names[0]:
                return [sys.executable, "-c", BLF, str(tmp / f"{key}.log"), str(tmp / "out.blf")]
            return [sys.executable, "-m", "slipdaq", "import", "--can", str(tmp / f"{key}.log"), "--nmea",
                    str(tmp / f"{key}.nmea"), "--config", str(cfg), "-o", str(tmp / f"{names.index(name)}-{key}.mcap"),
                    "--no-calibration", "--allow-empty"]

        runs = [(n, k) for k in inputs for n in names]
        for n, k in runs:  # warm-up: page cache, numba's kernel cache, .pyc files
            run_timed(command(n, k), envs[n])
        identical = ""
        if a.base:
            from benchmarks.replay_check import compare

            diff = compare(tmp / "2-long.mcap", tmp / "1-long.mcap")
            identical = "identical to the base's (but `created_utc`)" if not diff else f"DIFFERENT from the base's: {diff}"
            print(f"this tree's output is {identical}", flush=True)
        wall: dict[tuple[str, str], list[float]] = {r: [] for r in runs}
        cpu: dict[tuple[str, str], list[float]] = {r: [] for r in runs}
        for r in range(a.rounds):
            order = runs[r % len(runs):] + runs[: r % len(runs)]
            for run in order if r % 2 == 0 else order[::-1]:
                w, c = run_timed(command(*run), envs[run[0]])
                wall[run].append(w)
                cpu[run].append(c)
            print(f"round {r + 1}: " + ", ".join(f"{n} {k} {wall[n, k][-1]:.2f} s" for n, k in runs), flush=True)
        med = statistics.median
        rows = []
        for k in inputs:
            blf_w, blf_c = wall[names[0], k], cpu[names[0], k]
            for n in names:
                w, c = wall[n, k], cpu[n, k]
                per_round = [b / t for b, t in zip(blf_w, w)]
                rows.append([f"{n}, {inputs[k]:g} s", f"{med(w):.2f} s ({min(w):.2f}–{max(w):.2f})",
                             f"{frames[k] / med(w):,.0f}", f"{med(blf_w) / med(w):.3f}",
                             f"{med(per_round):.3f} ({min(per_round):.2f}–{max(per_round):.2f})",
                             f"{med(c):.2f} s", f"{med(blf_c) / med(c):.3f}"])
        cmd = "python -m benchmarks.import_speed " + " ".join(sys.argv[1:])
        head = (f"**Run.** `{cmd.strip()}` — {(time.time() - started) / 60:.1f} min, "
                f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {platform.processor() or platform.machine()}, "
                f"{os.cpu_count()} CPUs, 1-minute load {load0:.2f} at the start, {os.getloadavg()[0]:.2f} at the end. "
                f"Input: the simulator's cycle, 4 WPT messages × {a.wpt_rate_hz:g} Hz + 10 Hz NMEA, as a candump -L "
                f"log: {a.seconds:g} s ({frames['long']:,} frames, {(tmp / 'long.log').stat().st_size / 1e6:.1f} MB)"
                + (f" and {a.short_seconds:g} s ({frames['short']:,} frames: the fixed costs)" if "short" in inputs
                   else "") + f". Whole processes, interpreter start included; medians of {a.rounds} interleaved "
                "rounds; CPU = the process's user + system time." + (f" This tree's log is {identical}."
                                                                     if identical else "") + "\n\n")
        block = head + table(["run", "wall time (range)", "CAN frames/s", "× BLF, wall (medians)",
                              "× BLF per round (range)", "CPU time", "× BLF, CPU"], rows)
        if a.profile:
            total, split = profile_split(env, command(names[1], "long"), tmp)
            block += (f"\n\nThis tree's import of the {a.seconds:g} s log under cProfile ({total:.2f} s with the "
                      "profiler's overhead), own time by part:\n\n"
                      + table(["part", "seconds", "share"], [[lb, f"{s:.2f}", f"{s / total:.0%}"] for lb, s in split]))
        print("\n" + block)
        if a.write:
            write_block(DOC, BEGIN, END, "Import", block)
            print(f"wrote the table to {DOC}")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
