#!/usr/bin/env python3
"""`slipdaq batch` over many logs against the one-by-one loop, on this machine. Figures for docs/performance.md.

The logs (cycle and brake drives on paved and sand, labelled road=...) are made once into a temporary directory,
not timed. Then, in each round:
  (a) loop:       per log `slipdaq replay LOG -o OUT --two-pass` then `slipdaq report OUT --live -o DIR`, both
                  through slipdaq.cli.main in this process (no interpreter start per command: the stricter baseline;
                  the report takes the replayed log's two-pass estimates, so that both do the same estimator work);
  (b) local:      `slipdaq batch LOGS -o DIR --workers N` (through cli.main: the local cluster's start included);
  (c) scheduler:  `slipdaq batch LOGS -o DIR --scheduler ADDRESS` against a `dask scheduler` and N `dask worker`
                  processes (one thread each) started here before the round (their start not timed, the workers'
                  first imports are);
  (d) re-run:     (b) again over its own output: every log up to date.
Each batch starts from an empty DIR. The table shows the median over the rounds.

    python -m benchmarks.batch [--logs 100] [--seconds 15] [--workers 2] [--rounds 1] [--write]
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import dask
import distributed

from benchmarks.doc_block import machine, write_block
from slipdaq.cli import main as slipdaq
from slipdaq.config import load_config, packaged_config_path
from slipdaq.offline.run import process_to_log
from slipdaq.report.labels import labels_metadata
from slipdaq.sim.emit import SimSettings, generate

DOC = Path(__file__).resolve().parents[1] / "docs" / "performance.md"
DASK = (f"dask {dask.__version__}", f"distributed {distributed.__version__}")
BEGIN, END = "<!-- batch:begin -->", "<!-- batch:end -->"


def make_logs(d: Path, n: int, seconds: float) -> list[Path]:
    cfg = load_config(packaged_config_path())
    out = []
    kinds = (("cycle", "paved"), ("brake", "paved"), ("cycle", "sand"), ("brake", "sand"))
    for i in range(n):
        scenario, road = kinds[i % len(kinds)]
        path = d / f"drive-{i:03d}-{scenario}-{road}.mcap"
        records = (ev.record for ev in generate(cfg, scenario, road, SimSettings(seed=i + 1), duration_s=seconds)
                   if ev.record is not None)
        with open(os.devnull, "w") as quiet:
            process_to_log(cfg, records, path, "import", stream=quiet, metadata=labels_metadata({"road": road}))
        out.append(path)
    return out


@contextlib.contextmanager
def quiet() -> Iterator[None]:
    with open(os.devnull, "w") as null, contextlib.redirect_stdout(null), contextlib.redirect_stderr(null):
        yield


def timed(fn: Callable[[], None]) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def loop(logs: list[Path], work: Path) -> None:
    for log in logs:
        replayed = work / "replayed" / log.name
        with quiet():
            rc = slipdaq(["replay", str(log), "-o", str(replayed), "--two-pass"])
            rc |= slipdaq(["report", str(replayed), "--live", "-o", str(work / "reports" / log.stem)])
        assert rc == 0, log


def batch(logs: list[Path], out: Path, *extra: str) -> None:
    with quiet():
        rc = slipdaq(["batch", *map(str, logs), "-o", str(out), *extra])
    assert rc == 0, out


@contextlib.contextmanager
def cluster(workers: int, work: Path, env: dict[str, str] | None = None) -> Iterator[str]:
    """A `dask scheduler` and `workers` `dask worker` processes on localhost (env: theirs, default this process's);
    its address; all stopped at the end."""
    info = work / "scheduler.json"
    info.unlink(missing_ok=True)
    dask_cli = [sys.executable, "-m", "dask"]
    procs = [subprocess.Popen([*dask_cli, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(info)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)]
    try:
        deadline = time.monotonic() + 60
        while not info.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        address = json.loads(info.read_text())["address"]
        procs += [subprocess.Popen([*dask_cli, "worker", address, "--nthreads", "1", "--no-dashboard"],
                                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env)
                  for _ in range(workers)]
        with distributed.Client(address) as c:
            c.wait_for_workers(workers, timeout=60)
        yield address
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


def table(times: dict[str, list[float]], n: int, workers: int) -> str:
    names = {
        "loop": "one by one: `replay --two-pass` + `report --live`, per log, in process",
        "local": f"`slipdaq batch --workers {workers}` (local cluster, its start included)",
        "scheduler": f"`slipdaq batch --scheduler` (local `dask scheduler` + {workers} `dask worker` processes)",
        "rerun": f"`slipdaq batch --workers {workers}` again: every log up to date",
    }
    base = statistics.median(times["loop"])
    lines = ["| run | wall time (median) | range | logs/s | × the loop |", "|---|---:|---:|---:|---:|"]
    for key, label in names.items():
        t = times[key]
        m = statistics.median(t)
        lines.append(f"| {label} | {m:.1f} s | {min(t):.1f}–{max(t):.1f} s | {n / m:.2f} | {base / m:.2f}× |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--logs", type=int, default=100)
    ap.add_argument("--seconds", type=float, default=15.0, help="seconds per drive (default 15)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--write", action="store_true", help=f"put the table into {DOC.name}")
    a = ap.parse_args()
    started = time.monotonic()
    work = Path(tempfile.mkdtemp(prefix="slipdaq-batch-bench-"))
    try:
        logs: list[Path] = []
        t = timed(lambda: logs.extend(make_logs(work / "logs", a.logs, a.seconds)))
        size = sum(p.stat().st_size for p in logs)
        print(f"{a.logs} logs of {a.seconds:g} s ({size / 1e6:.0f} MB) made in {t:.0f} s", flush=True)
        times: dict[str, list[float]] = {"loop": [], "local": [], "scheduler": [], "rerun": []}
        address = ""
        runs: dict[str, Callable[[], None]] = {
            "loop": lambda: loop(logs, work / "out-loop"),
            "local": lambda: batch(logs, work / "out-local", "--workers", str(a.workers)),
            "scheduler": lambda: batch(logs, work / "out-scheduler", "--scheduler", address),
            "rerun": lambda: batch(logs, work / "out-local", "--workers", str(a.workers)),
        }
        for r in range(a.rounds):
            for key, run in runs.items():
                if key != "rerun":
                    shutil.rmtree(work / f"out-{key}", ignore_errors=True)
                if key == "scheduler":
                    with cluster(a.workers, work) as address:
                        times[key].append(timed(run))
                else:
                    times[key].append(timed(run))
                print(f"round {r + 1}: {key}: {times[key][-1]:.1f} s", flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    when = dt.datetime.now(dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
    block = (f"**Run.** `python -m benchmarks.batch --logs {a.logs} --seconds {a.seconds:g} --workers {a.workers} "
             f"--rounds {a.rounds} --write` — {(time.monotonic() - started) / 60:.1f} min, {when}. {a.logs} logs of "
             f"{a.seconds:g} s ({size / 1e6:.0f} MB); {machine(*DASK)}.\n\n" + table(times, a.logs, a.workers))
    print(block)
    if a.write:
        write_block(DOC, BEGIN, END, "Batch over many logs", block)
        print(f"written to {DOC}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
