#!/usr/bin/env python3
"""Does a process pipeline pay on this machine? The replay's run (offline.process_to_log's: the pipeline, the log
written by McapLogSink, the maneuvers' summaries in their forked process) against the same run with the log's sink in
a forked process of its own (its calls pickled in runs through a pipe), against the same run with the log written by
offline.log_process.LogProcess (a forked process sent the input's raw messages as read, and the derived records),
and against the same run with the log read in a forked process (its records pickled in runs); and the first pass of a
two-pass run (the second core idle) with the log read here and read in a forked process. Each variant runs in a
fresh process per round (imports and numba's kernels loaded before the clock starts, as gc.freeze()s them), the
variants in turn, the order reversed every other round; medians of the run's wall time, the main thread's CPU and the
whole process tree's CPU (the forked processes' included). Also the cost of pickling what each pipe would carry, in
process.

The variants live here, not in src/: they are measured alternatives. The log is replay_process.py's (--seconds of 4
WPT messages at --rate-hz + 20 Hz NMEA).

    python -m benchmarks.process_pipeline [--seconds 300] [--rate-hz 1000] [--rounds 5] [--work DIR]
"""

from __future__ import annotations

import argparse
import functools
import gc
import json
import os
import pickle
import resource
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from multiprocessing import get_context
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

from benchmarks.base_revision import ROOT
from benchmarks.replay_process import MAKE_LOG, python_path

VARIANTS = ("replay", "replay, log's sink forked", "replay, log written apart", "replay, log read forked", "first pass",
            "first pass, log read forked")
RUN_ITEMS = 64
"""Calls or records pickled and sent together."""


# ---- a sink in a forked process ----------------------------------------------------------------------------------

def _sink_process(make: Callable[[], Any], calls: Connection, done: Connection) -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    gc.freeze()
    sink = make()
    while (run := pickle.loads(calls.recv_bytes())) is not None:
        for name, args in run:
            getattr(sink, name)(*args)
    sink.close()
    done.send("closed")


def forked_sink(make: Callable[[], Any]) -> Any:
    """A Sink whose calls go, pickled in runs of RUN_ITEMS by this process and written by a thread, to make()'s sink
    in a forked process; close() waits for it to close."""
    import queue

    from slipdaq.sinks import SINK_CALLS, Sink

    ctx = get_context("fork")
    calls_in, calls_out = ctx.Pipe(duplex=False)
    done_in, done_out = ctx.Pipe(duplex=False)
    process = ctx.Process(target=_sink_process, args=(make, calls_in, done_out), daemon=True)
    process.start()
    calls_in.close()
    done_out.close()
    outbox: queue.Queue[bytes | None] = queue.Queue(32)

    def send() -> None:
        while (data := outbox.get()) is not None:
            calls_out.send_bytes(data)

    sender = threading.Thread(target=send, daemon=True)
    sender.start()

    class Forked(Sink):
        def __init__(self) -> None:
            self.run: list[tuple[str, tuple[Any, ...]]] = []

        def call(self, name: str, args: tuple[Any, ...]) -> None:
            self.run.append((name, args))
            if len(self.run) >= RUN_ITEMS:
                outbox.put(pickle.dumps(self.run, protocol=pickle.HIGHEST_PROTOCOL))
                self.run = []

        def close(self) -> None:
            outbox.put(pickle.dumps(self.run, protocol=pickle.HIGHEST_PROTOCOL))
            outbox.put(pickle.dumps(None))
            outbox.put(None)
            sender.join()
            assert done_in.recv() == "closed"
            process.join()

    for name in SINK_CALLS:
        setattr(Forked, name, (lambda n: lambda self, *args: self.call(n, args))(name))
    return Forked()


# ---- a log read in a forked process ------------------------------------------------------------------------------

def _reader_process(path: Path, out: Connection) -> None:
    from slipdaq.logformat.reader import iter_raw_batches

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    gc.freeze()
    run: list[Any] = []
    for item in iter_raw_batches(path):
        run.append(item)
        if len(run) >= RUN_ITEMS:
            out.send_bytes(pickle.dumps(run, protocol=pickle.HIGHEST_PROTOCOL))
            run = []
    out.send_bytes(pickle.dumps(run, protocol=pickle.HIGHEST_PROTOCOL))
    out.send_bytes(pickle.dumps(None))


def forked_reader(path: Path) -> Iterator[Any]:
    """iter_raw_batches(path) read in a process forked now, its records pickled in runs of RUN_ITEMS."""
    ctx = get_context("fork")
    out, into = ctx.Pipe(duplex=False)
    process = ctx.Process(target=_reader_process, args=(path, into), daemon=True)
    process.start()
    into.close()

    def records() -> Iterator[Any]:
        while (run := pickle.loads(out.recv_bytes())) is not None:
            yield from run
        process.join()

    return records()


# ---- one round of one variant (in a fresh process) ---------------------------------------------------------------

def one(variant: str, log: Path, out: Path) -> dict[str, float]:
    from slipdaq import compiled
    from slipdaq.logformat.reader import (
        config_from_log,
        iter_raw_batches,
        iter_raw_messages,
        raw_batches,
        raw_record_count,
        read_metadata,
    )
    from slipdaq.offline import run
    from slipdaq.offline.log_process import LogProcess
    from slipdaq.offline.summaries import SummaryProcess
    from slipdaq.sinks.mcap_log import McapLogSink

    config = config_from_log(log)
    start = run.start_calibration(read_metadata(log), log)
    total = raw_record_count(log)
    compiled.prepare()
    gc.freeze()
    quiet = open(os.devnull, "w")
    children0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    self0 = resource.getrusage(resource.RUSAGE_SELF)
    wall0, main0 = time.perf_counter(), time.thread_time()
    make = functools.partial(McapLogSink, out, config, mode="replay", metadata={})
    apart = LogProcess(make, lambda messages: run.batched(raw_batches(messages)), config) \
        if variant.endswith("written apart") else None
    if apart is not None and hasattr(apart, "begin"):  # a tree whose log's process makes its sink at the first call
        apart.begin()
    records = forked_reader(log) if variant.endswith("log read forked") else \
        apart.input(iter_raw_messages(log)) if apart is not None else iter_raw_batches(log)
    if variant.startswith("first pass"):
        run.first_pass(config, records, start, str(log), total=total, stream=quiet)
    else:
        sink = forked_sink(make) if variant.endswith("sink forked") else apart or make()
        try:
            with SummaryProcess() as summaries:
                run.process(config, records, [sink], calibration=start, stream=quiet, summaries=summaries,
                            total=total)
        finally:
            sink.close()
    wall, main = time.perf_counter() - wall0, time.thread_time() - main0
    self1, children1 = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = sum(getattr(b, f) - getattr(a, f) for a, b in ((self0, self1), (children0, children1))
              for f in ("ru_utime", "ru_stime"))
    return {"wall": wall, "main": main, "cpu": cpu}


def pickling(log: Path) -> dict[str, float]:
    """CPU seconds and MB of pickling the sink's calls (the replay's, in runs) and the reader's records, and of
    unpickling the records."""
    from slipdaq import compiled
    from slipdaq.logformat.reader import config_from_log, iter_raw_batches, read_metadata
    from slipdaq.offline import run
    from slipdaq.sinks import SINK_CALLS, Sink

    config = config_from_log(log)
    start = run.start_calibration(read_metadata(log), log)
    compiled.prepare()
    calls: list[tuple[str, tuple[Any, ...]]] = []

    class Recorder(Sink):
        pass

    for name in SINK_CALLS:
        setattr(Recorder, name, (lambda n: lambda self, *args: calls.append((n, args)))(name))
    run.process(config, iter_raw_batches(log), [Recorder()], calibration=start, stream=open(os.devnull, "w"))
    items = list(iter_raw_batches(log))
    t = time.process_time()
    sink_bytes = sum(len(pickle.dumps(calls[i:i + RUN_ITEMS], protocol=pickle.HIGHEST_PROTOCOL))
                     for i in range(0, len(calls), RUN_ITEMS))
    sink_s = time.process_time() - t
    t = time.process_time()
    data = [pickle.dumps(items[i:i + RUN_ITEMS], protocol=pickle.HIGHEST_PROTOCOL) for i in range(0, len(items), RUN_ITEMS)]
    reader_s = time.process_time() - t
    t = time.process_time()
    for d in data:
        pickle.loads(d)
    unpickle_s = time.process_time() - t
    t = time.process_time()
    for _ in iter_raw_batches(log):
        pass
    read_s = time.process_time() - t
    return {"sink calls": len(calls), "sink pickle s": sink_s, "sink MB": sink_bytes / 1e6,
            "records": len(items), "records read s": read_s, "records pickle s": reader_s,
            "records unpickle s": unpickle_s, "records MB": sum(map(len, data)) / 1e6}


def child(argv: list[str]) -> None:
    if argv[0] == "pickling":
        print(json.dumps(pickling(Path(argv[1]))))
    else:
        print(json.dumps(one(argv[0], Path(argv[1]), Path(argv[2]))))


def run_child(*args: str) -> dict[str, float]:
    done = subprocess.run([sys.executable, "-m", "benchmarks.process_pipeline", "--child", *args], check=True,
                          capture_output=True, text=True, cwd=ROOT,
                          env=dict(os.environ, PYTHONPATH=python_path(ROOT / "src")))
    return dict(json.loads(done.stdout.strip().splitlines()[-1]))


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--child":
        child(sys.argv[2:])
        return 0
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=300.0, help="seconds of log (default 300)")
    ap.add_argument("--rate-hz", type=float, default=1000.0, help="each WPT message's rate (default 1000)")
    ap.add_argument("--rounds", type=int, default=5, help="rounds (default 5)")
    ap.add_argument("--work", type=Path, default=None, help="directory for the logs (default: a temporary one)")
    a = ap.parse_args()
    work = a.work or Path(tempfile.mkdtemp(prefix="process-pipeline-"))
    work.mkdir(parents=True, exist_ok=True)
    log = work / f"raw-{a.seconds:g}s-{a.rate_hz:g}hz.mcap"
    if not log.exists():
        subprocess.run([sys.executable, "-c", MAKE_LOG, str(log), str(a.seconds), str(a.rate_hz)], check=True,
                       env=dict(os.environ, PYTHONPATH=python_path(ROOT / "src")), stdout=subprocess.DEVNULL)
    t_start = time.perf_counter()
    got: dict[str, list[dict[str, float]]] = {v: [] for v in VARIANTS}
    for r in range(a.rounds):
        for v in (VARIANTS if r % 2 == 0 else VARIANTS[::-1]):
            got[v].append(m := run_child(v, str(log), str(work / "out.mcap")))
            print(f"  round {r + 1} {v}: {m['wall']:.2f} s wall, main thread {m['main']:.2f} s, "
                  f"CPU {m['cpu']:.2f} s", flush=True)
    cost = run_child("pickling", str(log))
    minutes = (time.perf_counter() - t_start) / 60
    print(f"\n**Run.** `python -m benchmarks.process_pipeline --seconds {a.seconds:g} --rate-hz {a.rate_hz:g} "
          f"--rounds {a.rounds}`: {minutes:.1f} min, {a.rounds} rounds, medians; load average at the end "
          f"{os.getloadavg()[0]:.1f}.\n")
    print("| run | wall | × its base | main thread CPU | CPU, all processes | × its base |")
    print("|---|---:|---:|---:|---:|---:|")
    for v in VARIANTS:
        base = "replay" if v.startswith("replay") else "first pass"
        med = {k: statistics.median(m[k] for m in got[v]) for k in ("wall", "main", "cpu")}
        ref = {k: statistics.median(m[k] for m in got[base]) for k in ("wall", "cpu")}
        print(f"| {v} | {med['wall']:.2f} s | {med['wall'] / ref['wall']:.2f} | {med['main']:.2f} s | "
              f"{med['cpu']:.2f} s | {med['cpu'] / ref['cpu']:.2f} |")
    print(f"\nWhat the pipes would carry: the sink's {cost['sink calls']:.0f} calls pickle in {cost['sink pickle s']:.2f} s "
          f"({cost['sink MB']:.0f} MB); the log's {cost['records']:.0f} records are read in {cost['records read s']:.2f} s, "
          f"pickle in {cost['records pickle s']:.2f} s and unpickle in {cost['records unpickle s']:.2f} s "
          f"({cost['records MB']:.0f} MB).")
    return 0


if __name__ == "__main__":
    sys.exit(main())
