"""Replay: a raw log of N minutes replayed by `slipdaq replay` in this process, frames/s."""

from __future__ import annotations

import argparse
import contextlib
import io
import time
from dataclasses import dataclass, replace
from pathlib import Path

from benchmarks.perf_common import base_config, fmt_rate, table
from slipdaq.config import Config
from slipdaq.records import CanFrame
from slipdaq.sim.emit import SimSettings, generate


@dataclass
class ReplayResult:
    minutes: float
    frames: int
    nmea: int
    produce_s: float
    replay_s: float | None = None


def write_raw_log(cfg: Config, minutes: float, path: Path) -> tuple[int, int, float]:
    """A raw-only slipdaq log of `minutes` of 4 x 500 Hz + 20 Hz NMEA: (frames, NMEA lines, seconds to write)."""
    from slipdaq.sinks.mcap_log import McapLogSink

    t0 = time.perf_counter()
    sink = McapLogSink(path, cfg, mode="bench-raw")
    settings = replace(SimSettings(), wpt_rate_hz=500.0, gps_rate_hz=20.0, gps_latency_s=0.05, can_jitter_s=0.0002)
    frames = nmea = 0
    for ev in generate(cfg, "cycle", "paved", settings, duration_s=minutes * 60.0):  # type: ignore[arg-type]
        r = ev.record
        if r is None:
            continue
        sink.on_raw(r)
        if isinstance(r, CanFrame):
            frames += 1
        else:
            nmea += 1
    sink.close()
    return frames, nmea, time.perf_counter() - t0


def run_replay(a: argparse.Namespace, tmp: Path) -> ReplayResult:
    from slipdaq.cli import main as slipdaq_main

    cfg = base_config()
    raw = tmp / "replay-raw.mcap"
    print(f"replay: writing a {a.replay_minutes:g}-minute raw log (4 x 500 Hz + 20 Hz NMEA)...", flush=True)
    frames, nmea, produce_s = write_raw_log(cfg, a.replay_minutes, raw)
    res = ReplayResult(a.replay_minutes, frames, nmea, produce_s)
    print(f"  {frames:,} frames, {nmea:,} NMEA lines, {raw.stat().st_size / 1e6:.1f} MB, written in {produce_s:.0f} s;"
          f" timing `slipdaq replay`...", flush=True)
    out = tmp / "replay-out.mcap"
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        t0 = time.perf_counter()
        rc = slipdaq_main(["replay", str(raw), "-o", str(out)])
        res.replay_s = time.perf_counter() - t0
    if rc != 0:
        raise SystemExit(f"slipdaq replay failed with exit status {rc}")
    print(f"  slipdaq replay: {res.replay_s:.1f} s = {fmt_rate(frames / res.replay_s)} frames/s", flush=True)
    out.unlink()
    raw.unlink()
    return res


def replay_table(res: ReplayResult) -> str:
    real_s = res.minutes * 60.0
    rows = [["`slipdaq replay`", f"{res.minutes:g} min", f"{res.frames:,}",
             f"{res.replay_s:.1f} s", fmt_rate(res.frames / res.replay_s), f"{real_s / res.replay_s:.1f}×",
             f"{res.replay_s * 60 / res.minutes / 60:.1f} min"]]
    head = (f"Raw log: 4 WPT messages × 500 Hz + 20 Hz NMEA from the simulator's cycle (written in "
            f"{res.produce_s:.0f} s, not timed). Replay time includes reading, decode, estimator and writing the new "
            f"log. The last column is the measured rate expressed per hour of log (the 60-minute figure is only "
            f"measured when --replay-minutes 60). Target: ≥ 500,000 frames/s, an hour of 4 × 500 Hz in < 15 s.\n\n")
    t = table(["replay", "log", "frames", "wall time", "frames/s", "× real time", "time per hour of log"], rows)
    return head + t
