#!/usr/bin/env python3
"""`slipdaq batch` over the same logs with 1, 2, 4, ... workers (a local cluster), as whole processes: how it scales
with cores, and its serial part. Figures for docs/performance.md.

The logs (cycle and brake drives on paved and sand, labelled road=...) are made once, in parallel, not timed, by the
base where one is given (its logs are what both trees read). Each
run is `python -m slipdaq batch LOGS -o DIR --workers N` from an empty DIR (interpreter start, cluster start and the
report included), after one untimed run of each tree over two logs (numba's cache filled, as on a machine in
use). From its progress lines on stderr: when the first log finished, and how long the process took after
the last log finished (the report's tables and page, the cluster's stop); from its last line (BatchResult.client):
the tasks' own times summed, and what the process did outside waiting on them: its start (interpreter, imports, the
exit: the process's wall time less run_batch's), the cluster's start (workers warm), planning, taking the results,
the report, the cluster's stop. The serial part is all of that; its share of the 1-worker run (serial / (serial +
tasks)) gives Amdahl's speed-up at 16 and 64 workers, a projection. With --base REV (a source tree, or a git
revision unpacked by base_revision), the same runs of that revision for the worker counts of --base-workers,
interleaved with this tree's (a base without that last line has no serial columns). With --scheduler, each count
also as `slipdaq batch LOGS -o DIR --scheduler ADDRESS` against a `dask scheduler` and N `dask worker` processes (one
thread each) started before it and warmed by a batch over two logs, neither timed: the rows of a cluster kept running
(its workers' start is not the batch's; the batch process writes each log's Parquet and cache files from the bytes
its task returned).

    python -m benchmarks.batch_scaling [--logs 128] [--seconds 15] [--workers 1,2,4,8,16] [--base DIR|REV]
                                       [--base-workers 16] [--scheduler] [--write]
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
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


CLIENT = re.compile(r"batch: ([\d.]+) s in the tasks \(summed\), ([\d.]+) s in all; outside the tasks ([\d.]+) s: "
                    r"cluster start ([\d.]+) s, planning ([\d.]+) s, results ([\d.]+) s, report ([\d.]+) s, "
                    r"cluster stop ([\d.]+) s")
"""The batch's last stderr line (fleet.ClientTime.line)."""
PARTS = ("start", "cluster start", "planning", "results", "report", "cluster stop")
"""The serial part's parts, in the table's order."""


def python_path(src: Path) -> str:
    """PYTHONPATH for a tree: its src first, then what PYTHONPATH held (packages installed elsewhere)."""
    return os.pathsep.join([str(src), *filter(None, [os.environ.get("PYTHONPATH")])])


def run_batch(src: Path, logs: list[Path], out: Path, workers: int, scheduler: str | None = None) -> dict[str, float]:
    """One `slipdaq batch` process (`--workers N`, or `--scheduler ADDRESS`): wall time, first log finished, after the
    last log finished (seconds); with the client's line: the tasks summed, the serial part and its parts (PARTS)."""
    shutil.rmtree(out, ignore_errors=True)
    env = dict(os.environ, PYTHONPATH=python_path(src), PYTHONUNBUFFERED="1")
    where = ["--scheduler", scheduler] if scheduler else ["--workers", str(workers)]
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "slipdaq", "batch", *map(str, logs), "-o", str(out), *where],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, text=True)
    assert proc.stderr is not None
    done: list[float] = []
    tail: list[str] = []
    client = None
    for line in proc.stderr:
        if line.startswith("batch: ["):
            done.append(time.perf_counter() - t0)
        client = CLIENT.match(line) or client
        tail = (tail + [line])[-5:]
    rc = proc.wait()
    wall = time.perf_counter() - t0
    if rc != 0 or len(done) != len(logs):
        raise SystemExit(f"batch {' '.join(where)} ({src}) exit {rc}, {len(done)} of {len(logs)} logs:\n"
                         + "".join(tail))
    r = {"wall": wall, "first": done[0], "after_last": wall - done[-1]}
    if client:
        tasks, total, outside, *parts = map(float, client.groups())
        r |= {"tasks": tasks, "serial": wall - total + outside, "start": wall - total} | dict(zip(PARTS[1:], parts))
    return r


def amdahl(serial_share: float, workers: int) -> float:
    """Amdahl's law: the speed-up over one worker at `workers` when serial_share of the 1-worker run is serial."""
    return 1.0 / (serial_share + (1.0 - serial_share) / workers)


def table(runs: dict[tuple[str, int], dict[str, float]], n: int) -> str:
    lines = ["| tree | workers | wall time | logs/s | × 1 worker (same tree) | efficiency | first log done | "
             "after the last log | tasks summed | serial part | serial / tasks | "
             + " | ".join(PARTS) + " |", "|---|" + "---:|" * (11 + len(PARTS))]
    for (tree, w), r in sorted(runs.items(), key=lambda kv: (not kv[0][0].startswith("this tree"), kv[0])):
        one = runs.get((tree, 1))
        speedup = f"{one['wall'] / r['wall']:.2f}×" if one else "–"
        eff = f"{one['wall'] / r['wall'] / w:.2f}" if one else "–"
        serial = (f"{r['tasks']:.1f} s | {r['serial']:.2f} s | {100 * r['serial'] / r['tasks']:.1f} % | "
                  + " | ".join(f"{r[p]:.2f} s" for p in PARTS)) if "tasks" in r else " | ".join(["–"] * (3 + len(PARTS)))
        lines.append(f"| {tree} | {w} | {r['wall']:.1f} s | {n / r['wall']:.2f} | {speedup} | {eff} | "
                     f"{r['first']:.1f} s | {r['after_last']:.1f} s | {serial} |")
    return "\n".join(lines)


def projection(runs: dict[tuple[str, int], dict[str, float]]) -> str:
    """Amdahl's speed-up at 16 and 64 workers from each tree's 1-worker run: serial share = serial / (serial +
    tasks)."""
    out = []
    for (tree, w), r in sorted(runs.items(), key=lambda kv: (not kv[0][0].startswith("this tree"), kv[0])):
        if w != 1 or "tasks" not in r:
            continue
        f = r["serial"] / (r["serial"] + r["tasks"])
        out.append(f"{tree}, 1 worker: serial part {r['serial']:.2f} s against {r['tasks']:.1f} s of tasks, a serial "
                   f"share of {100 * f:.2f} %; Amdahl's law allows (a projection, not a measurement) "
                   f"{amdahl(f, 16):.1f}× at 16 workers and {amdahl(f, 64):.1f}× at 64.")
    return "\n".join(out)


def say(tree: str, w: int, r: dict[str, float]) -> dict[str, float]:
    print(f"{tree}, {w} workers: {r['wall']:.1f} s (first log {r['first']:.1f} s, after the last "
          f"{r['after_last']:.1f} s" + (f", tasks {r['tasks']:.1f} s, serial {r['serial']:.2f} s: "
          + ", ".join(f"{p} {r[p]:.2f} s" for p in PARTS) if "tasks" in r else "") + ")", flush=True)
    return r


@contextlib.contextmanager
def warm_cluster(src: Path, warm_logs: list[Path], work: Path, workers: int) -> Iterator[str]:
    """A `dask scheduler` and `workers` `dask worker` processes of the tree at src (benchmarks.batch.cluster), warmed
    by one batch over warm_logs (the workers' imports and kernels loaded); its address."""
    from benchmarks.batch import cluster

    with cluster(workers, work, dict(os.environ, PYTHONPATH=python_path(src))) as address:
        run_batch(src, warm_logs, work / "out", workers, address)
        yield address


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--logs", type=int, default=128)
    ap.add_argument("--seconds", type=float, default=15.0, help="seconds per drive (default 15)")
    ap.add_argument("--workers", default="1,2,4,8,16", help="worker counts (default 1,2,4,8,16)")
    ap.add_argument("--base", default=None, help="a base tree's src directory, or a git revision")
    ap.add_argument("--base-workers", default="16", help="worker counts run for the base (default 16)")
    ap.add_argument("--scheduler", action="store_true",
                    help="also each count as `batch --scheduler` against a `dask scheduler` and N `dask worker` "
                         "processes started first and warmed by one batch over two logs (neither timed)")
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
                             text=True, env=dict(os.environ, PYTHONPATH=python_path(src))).stdout.strip()
        if not Path(got).resolve().is_relative_to(src.resolve()):
            raise SystemExit(f"{tree}: slipdaq comes from {got}, not {src}")
    try:
        (work / "logs").mkdir()
        t = time.perf_counter()
        oldest = list(trees.values())[-1]  # the base's logs: the newer tree reads them, not the other way round
        subprocess.run([sys.executable, "-m", "benchmarks.batch_scaling", "--make-logs", str(work / "logs"), "--logs",
                        str(a.logs), "--seconds", str(a.seconds)], check=True, cwd=ROOT,
                       env=dict(os.environ, PYTHONPATH=python_path(oldest)))
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
                runs[(tree, w)] = say(tree, w, run_batch(src, logs, work / "out", w))
                if a.scheduler:
                    with warm_cluster(src, logs[:2], work, w) as address:
                        runs[(f"{tree}, --scheduler", w)] = say(f"{tree}, --scheduler", w,
                                                                run_batch(src, logs, work / "out", w, address))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    block = (f"**Run.** `python -m benchmarks.batch_scaling --logs {a.logs} --seconds {a.seconds:g} --workers "
             f"{a.workers}" + (f" --base {a.base} --base-workers {a.base_workers}" if a.base else "")
             + (" --scheduler" if a.scheduler else "")
             + f"` — {(time.monotonic() - started) / 60:.1f} min, {when}. {a.logs} logs of {a.seconds:g} s "
             f"({size / 1e6:.0f} MB); {machine(*DASK)}.\n\n" + table(runs, a.logs) + "\n\n" + projection(runs))
    print(block)
    if a.write:
        write_block(DOC, BEGIN, END, "Batch scaling with cores", block)
        print(f"written to {DOC}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
