#!/usr/bin/env python3
"""`slipdaq batch` over the same logs with 1, 2, 4, ... workers (a local cluster), as whole processes: how it scales
with cores. Figures for docs/performance.md, measured on a machine with as many cores as the largest worker count.

The logs (cycle and brake drives on paved and sand, labelled road=...) are made once, in parallel, not timed, by the
base where one is given (its logs are what both trees read). Each
run is `python -m slipdaq batch LOGS -o DIR --workers N` from an empty DIR (interpreter start, cluster start and the
report included), after one untimed run of each tree over two logs (numba's cache filled, as on a machine in
use). From its progress lines on stderr: when the first log finished, and how long the process took after
the last log finished (the report's tables and page, the cluster's stop). With --base REV (a source tree, or a git
revision unpacked by base_revision), the same runs of that revision for the worker counts of --base-workers,
interleaved with this tree's.

    python -m benchmarks.batch_scaling [--logs 128] [--seconds 15] [--workers 1,2,4,8,16] [--base DIR|REV]
                                       [--base-workers 16] [--write]
"""

from __future__ import annotations

import argparse
import datetime as dt
import os
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import dask
import distributed

from benchmarks.doc_block import machine, write_block

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "performance.md"
DASK = (f"dask {dask.__version__}", f"distributed {distributed.__version__}")
BEGIN, END = "<!-- batch-scaling:begin -->", "<!-- batch-scaling:end -->"
KINDS = (("cycle", "paved"), ("brake", "paved"), ("cycle", "sand"), ("brake", "sand"))


def make_log(args: tuple[Path, int, float]) -> Path:
    from slipdaq.config import load_config, packaged_config_path
    from slipdaq.offline.run import process_to_log
    from slipdaq.report.labels import labels_metadata
    from slipdaq.sim.emit import SimSettings, generate

    d, i, seconds = args
    cfg = load_config(packaged_config_path())
    scenario, road = KINDS[i % len(KINDS)]
    path = d / f"drive-{i:03d}-{scenario}-{road}.mcap"
    records = (ev.record for ev in generate(cfg, scenario, road, SimSettings(seed=i + 1), duration_s=seconds)
               if ev.record is not None)
    with open(os.devnull, "w") as quiet:
        process_to_log(cfg, records, path, "import", stream=quiet, metadata=labels_metadata({"road": road}))
    return path


def run_batch(src: Path, logs: list[Path], out: Path, workers: int) -> dict[str, float]:
    """One `slipdaq batch` process: wall time, first log finished, after the last log finished (seconds)."""
    shutil.rmtree(out, ignore_errors=True)
    env = dict(os.environ, PYTHONPATH=str(src), PYTHONUNBUFFERED="1")
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "slipdaq", "batch", *map(str, logs), "-o", str(out),
                             "--workers", str(workers)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env,
                            text=True)
    assert proc.stderr is not None
    done: list[float] = []
    tail: list[str] = []
    for line in proc.stderr:
        if line.startswith("batch: ["):
            done.append(time.perf_counter() - t0)
        tail = (tail + [line])[-5:]
    rc = proc.wait()
    wall = time.perf_counter() - t0
    if rc != 0 or len(done) != len(logs):
        raise SystemExit(f"batch --workers {workers} ({src}) exit {rc}, {len(done)} of {len(logs)} logs:\n"
                         + "".join(tail))
    return {"wall": wall, "first": done[0], "after_last": wall - done[-1]}


def table(runs: dict[tuple[str, int], dict[str, float]], n: int) -> str:
    lines = ["| tree | workers | wall time | logs/s | × 1 worker (same tree) | efficiency | first log done | "
             "after the last log |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for (tree, w), r in sorted(runs.items(), key=lambda kv: (kv[0][0] != "this tree", kv[0][1])):
        one = runs.get((tree, 1))
        speedup = f"{one['wall'] / r['wall']:.2f}×" if one else "–"
        eff = f"{one['wall'] / r['wall'] / w:.2f}" if one else "–"
        lines.append(f"| {tree} | {w} | {r['wall']:.1f} s | {n / r['wall']:.2f} | {speedup} | {eff} | "
                     f"{r['first']:.1f} s | {r['after_last']:.1f} s |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--logs", type=int, default=128)
    ap.add_argument("--seconds", type=float, default=15.0, help="seconds per drive (default 15)")
    ap.add_argument("--workers", default="1,2,4,8,16", help="worker counts (default 1,2,4,8,16)")
    ap.add_argument("--base", default=None, help="a base tree's src directory, or a git revision")
    ap.add_argument("--base-workers", default="16", help="worker counts run for the base (default 16)")
    ap.add_argument("--write", action="store_true", help=f"put the table into {DOC.name}")
    ap.add_argument("--make-logs", type=Path, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.make_logs:  # the logs only, by the slipdaq on PYTHONPATH
        with ProcessPoolExecutor() as pool:
            list(pool.map(make_log, [(a.make_logs, i, a.seconds) for i in range(a.logs)]))
        return 0
    counts = [int(x) for x in a.workers.split(",")]
    base_counts = [int(x) for x in a.base_workers.split(",")] if a.base else []
    started = time.monotonic()
    work = Path(tempfile.mkdtemp(prefix="slipdaq-scaling-"))
    trees = {"this tree": ROOT / "src"}
    if a.base:
        base = Path(a.base)
        if not base.is_dir():
            from benchmarks.base_revision import unpack
            base = unpack(a.base, work / "base")
        trees["base " + (a.base if not Path(a.base).is_dir() else base.parent.name)] = base
    for tree, src in trees.items():  # each tree's slipdaq, not an installed one
        got = subprocess.run([sys.executable, "-c", "import slipdaq; print(slipdaq.__file__)"], capture_output=True,
                             text=True, env=dict(os.environ, PYTHONPATH=str(src))).stdout.strip()
        if not Path(got).resolve().is_relative_to(src.resolve()):
            raise SystemExit(f"{tree}: slipdaq comes from {got}, not {src}")
    try:
        (work / "logs").mkdir()
        t = time.perf_counter()
        oldest = list(trees.values())[-1]  # the base's logs: the newer tree reads them, not the other way round
        subprocess.run([sys.executable, __file__, "--make-logs", str(work / "logs"), "--logs", str(a.logs),
                        "--seconds", str(a.seconds)], check=True, env=dict(os.environ, PYTHONPATH=str(oldest)))
        logs = sorted((work / "logs").glob("*.mcap"))
        size = sum(p.stat().st_size for p in logs)
        print(f"{a.logs} logs of {a.seconds:g} s ({size / 1e6:.0f} MB) made in {time.perf_counter() - t:.0f} s",
              flush=True)
        for src in trees.values():  # untimed: each tree's compiled kernels into its cache, as on a used machine
            run_batch(src, logs[:2], work / "out", 1)
        runs: dict[tuple[str, int], dict[str, float]] = {}
        for w in counts:
            for tree, src in trees.items():
                if tree != "this tree" and w not in base_counts:
                    continue
                runs[(tree, w)] = r = run_batch(src, logs, work / "out", w)
                print(f"{tree}, {w} workers: {r['wall']:.1f} s (first log {r['first']:.1f} s, after the last "
                      f"{r['after_last']:.1f} s)", flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    block = (f"**Run.** `python -m benchmarks.batch_scaling --logs {a.logs} --seconds {a.seconds:g} --workers "
             f"{a.workers}" + (f" --base {a.base} --base-workers {a.base_workers}" if a.base else "")
             + f"` — {(time.monotonic() - started) / 60:.1f} min, {when}. {a.logs} logs of {a.seconds:g} s "
             f"({size / 1e6:.0f} MB); {machine(*DASK)}.\n\n" + table(runs, a.logs))
    print(block)
    if a.write:
        write_block(DOC, BEGIN, END, "Batch scaling with cores", block)
        print(f"written to {DOC}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
