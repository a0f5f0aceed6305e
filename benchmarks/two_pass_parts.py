#!/usr/bin/env python3
"""Where a two-pass replay's CPU goes, in one process (imports and numba's kernels warm): the first pass
(offline.first_pass: the estimator over the log, then the reference speed's smoothing, also timed alone), and the
second pass with its log written, with no sink, and with no sink and no high-rate slip rows, and (a tree with
offline.decoder_tape) the first pass recording its decoders and the second with no sink playing them back, and (a
tree with offline.first_pass_feed) the first pass over its records in memory playing a fed tape; the
imports' objects frozen out of the garbage collector's reach (gc.freeze), as the CLI's offline runs hold them. This tree against a
base revision, each side in its own process (its `src` on PYTHONPATH), the sides in turn per round (the order
reversed every other round); medians of CPU time (process_time).

The log is replay_process.py's (--seconds of 4 WPT messages at --rate-hz + 20 Hz NMEA), written once by the base.

With --tile N, also the smoothing of the first pass's fixes and wheel samples repeated N times, each copy after the
one before (N = 24: a 2-hour run's fixes and samples).

    python -m benchmarks.two_pass_parts --base REV [--seconds 300] [--rate-hz 1000] [--rounds 3] [--tile 24]
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.base_revision import ROOT, add_base_argument, in_turns, resolve, side_json, unpack
from benchmarks.replay_process import MAKE_LOG, python_path

PARTS = ("first pass", "of it: smoothing", "second pass, log written", "second pass, no sink",
         "second pass, no sink, no high-rate rows", "first pass, its decoders recorded",
         "second pass, no sink, its decoders played back", "first pass, its records in memory, its decoders fed")
"""The last three: a tree with offline.decoder_tape (a dash for one without); the last, one with
offline.first_pass_feed (the fed first pass but for taking the runs from the log's process)."""


def measure(log: Path, out: Path, tile: int) -> dict[str, float]:
    """One round of every part (this process's slipdaq): CPU seconds by part; with tile > 1 also the smoothing of the
    first pass's fixes and wheel samples repeated tile times, one copy after the other (a log tile times as long)."""
    from slipdaq import compiled
    from slipdaq.logformat.reader import config_from_log, iter_raw_batches, read_metadata
    from slipdaq.offline import run

    config = config_from_log(log)
    start = run.start_calibration(read_metadata(log), log)
    compiled.prepare()
    gc.freeze()  # the imports' objects out of the collector's reach, as the CLI's offline runs hold them
    got: dict[str, float] = {}
    smoothing = run.smoothed_gps_speeds

    def timed_smoothing(*args: Any) -> list[float]:  # first_pass calls it through the module
        t0 = time.process_time()
        try:
            return smoothing(*args)
        finally:
            got[PARTS[1]] = time.process_time() - t0

    def cpu(part: str, f: Any) -> Any:
        t0 = time.process_time()
        r = f()
        got[part] = time.process_time() - t0
        return r

    fixes: list[Any] = []
    batches: list[Any] = []
    sink = run._FirstPassSink
    on_fix, on_wheel_batch = sink.on_fix, sink.on_wheel_batch

    def record_fix(self: Any, fix: Any) -> None:
        fixes.append(fix)
        on_fix(self, fix)

    def record_batch(self: Any, samples: Any) -> None:
        batches.append(samples)
        on_wheel_batch(self, samples)

    run.smoothed_gps_speeds = timed_smoothing  # type: ignore[assignment]
    sink.on_fix, sink.on_wheel_batch = record_fix, record_batch  # type: ignore[method-assign]
    try:
        first = cpu(PARTS[0], lambda: run.first_pass(config, iter_raw_batches(log), start, str(log)))
    finally:
        run.smoothed_gps_speeds = smoothing  # type: ignore[assignment]
        sink.on_fix, sink.on_wheel_batch = on_fix, on_wheel_batch  # type: ignore[method-assign]
    if tile > 1:
        long = tiled(sink(), fixes, batches, tile)
        cpu(f"smoothing, {tile} copies", lambda: run.smoothed_gps_speeds(long, first.calibration, config))
        del long
    fixes.clear()
    batches.clear()
    quiet = open("/dev/null", "w")  # noqa: SIM115  (the progress lines)
    second = first.second_pass() | {"stream": quiet}
    cpu(PARTS[2], lambda: run.process_to_log(config, iter_raw_batches(log), out, "replay", **second))
    cpu(PARTS[3], lambda: run.process(config, iter_raw_batches(log), [], **second))
    cpu(PARTS[4], lambda: run.process(config, iter_raw_batches(log), [], fast_slip=False, **second))
    try:
        from slipdaq.offline.decoder_tape import DecoderTape
    except ImportError:
        return got
    tape = DecoderTape()
    taped = cpu(PARTS[5], lambda: run.first_pass(config, iter_raw_batches(log), start, str(log), tape=tape))
    cpu(PARTS[6], lambda: run.process(config, iter_raw_batches(log), [], tape=tape,
                                      **taped.second_pass() | {"stream": quiet}))
    try:
        fed = DecoderTape(fed=True)  # a tree without the feed: TypeError
    except TypeError:
        return got
    items = list(iter_raw_batches(log))
    fed.feed(tape.wheels, tape.lines)  # what the log's process sends, all at once
    cpu(PARTS[7], lambda: run.first_pass(config, items, start, str(log), tape=fed))
    return got


def tiled(sink: Any, fixes: list[Any], batches: list[Any], copies: int) -> Any:
    """The sink given the fixes and wheel samples `copies` times, each copy later by the run's span (and its
    revolutions on by more than any wheel's over the run)."""
    span = fixes[-1].timestamp_s - fixes[0].timestamp_s + 1.0
    revs = max(float(b.revolutions.max()) for b in batches) - min(float(b.revolutions.min()) for b in batches) + 1.0
    for k in range(copies):
        for f in fixes:
            sink.on_fix(dataclasses.replace(f, timestamp_s=f.timestamp_s + k * span, fix_time_utc_s=None
                                            if f.fix_time_utc_s is None else f.fix_time_utc_s + k * span))
        for b in batches:
            sink.on_wheel_batch(dataclasses.replace(b, timestamp_s=b.timestamp_s + k * span,
                                                    revolutions=b.revolutions + k * revs))
    return sink


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_base_argument(ap)
    ap.add_argument("--seconds", type=float, default=300.0, help="seconds of log (default 300)")
    ap.add_argument("--rate-hz", type=float, default=1000.0, help="each WPT message's rate (default 1000)")
    ap.add_argument("--rounds", type=int, default=3, help="rounds (default 3)")
    ap.add_argument("--work", type=Path, default=None, help="directory for the logs (default: a temporary one)")
    ap.add_argument("--tile", type=int, default=0,
                    help="also time the smoothing of the first pass's fixes and samples repeated this many times")
    ap.add_argument("--measure", nargs=2, type=Path, help=argparse.SUPPRESS)  # LOG OUT: one side's round
    a = ap.parse_args()
    if a.measure:
        log, out = a.measure
        print(json.dumps(measure(log, out, a.tile)))
        return 0
    parts = PARTS + ((f"smoothing, {a.tile} copies",) if a.tile > 1 else ())
    base = resolve(a.base)
    work = a.work or Path(tempfile.mkdtemp(prefix="two-pass-parts-"))
    work.mkdir(parents=True, exist_ok=True)
    sides = {f"base {base}": unpack(base, work / f"base-{base}"), "this tree": ROOT / "src"}
    log = work / f"raw-{a.seconds:g}s-{a.rate_hz:g}hz.mcap"
    if not log.exists():
        subprocess.run([sys.executable, "-c", MAKE_LOG, str(log), str(a.seconds), str(a.rate_hz)], check=True,
                       env=dict(os.environ, PYTHONPATH=python_path(sides[f"base {base}"])), capture_output=True)
    got: dict[str, list[dict[str, float]]] = {name: [] for name in sides}
    for r, name in in_turns(sides, a.rounds):
        got[name].append(side_json(sides[name], __file__, "--measure", str(log), str(work / "out.mcap"), "--tile",
                                   str(a.tile), cwd=ROOT))
        print(f"  round {r + 1} {name}: " + ", ".join(f"{k} {got[name][-1][k]:.2f} s" for k in parts
                                                      if k in got[name][-1]), flush=True)
    print(f"\nCPU of a two-pass replay's parts, {a.seconds:g} s of 4 × {a.rate_hz:g} Hz + 20 Hz NMEA, in process, "
          f"{a.rounds} rounds, medians\n")
    print("| part | " + " | ".join(sides) + " |\n|---|" + "---:|" * len(sides))
    for part in parts:
        print(f"| {part} | " + " | ".join(f"{statistics.median(g[part] for g in got[name]):.2f} s"
                                          if part in got[name][0] else "—" for name in sides) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
