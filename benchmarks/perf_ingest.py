"""Ingest: slipdaq's live path minus the driver against python-can's loggers (BLF, ASC), frames/s."""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can

from benchmarks.perf_common import base_config, fmt_rate, median, reader_batches, sim_items, table
from slipdaq.config import Config


def ingest_slipdaq(cfg: Config, items: list[Any], path: Path, *, status_sink: bool = False) -> float:
    """Seconds for: to_frame + Pipeline.process for every item, finish, close (construction not timed)."""
    from slipdaq.pipeline import Pipeline
    from slipdaq.sinks.mcap_log import McapLogSink
    from slipdaq.sources.can_bus import to_frame

    sink = McapLogSink(path, cfg, mode="bench")
    sinks: list[Any] = [sink]
    if status_sink:
        from slipdaq.sinks.status import StatusSink

        sinks.append(StatusSink())
    pipeline = Pipeline(cfg, sinks)
    Message = can.Message
    process = pipeline.process
    t0 = time.perf_counter()
    for it in items:
        if type(it) is Message:
            process(to_frame(it))
        else:
            process(it)
    pipeline.finish()
    sink.close()
    return time.perf_counter() - t0


def ingest_batched(cfg: Config, batches: list[Any], path: Path) -> float:
    """Seconds for what the live source and pipeline do per reader wake-up: to_frames(msgs) (a CanFrameBatch from
    48 frames on, else CanFrames) -> Pipeline.process_can_batch, NMEA lines through Pipeline.process; finish, close."""
    from slipdaq.pipeline import Pipeline
    from slipdaq.sinks.mcap_log import McapLogSink
    from slipdaq.sources.can_bus import to_frames

    sink = McapLogSink(path, cfg, mode="bench")
    pipeline = Pipeline(cfg, [sink])
    process, process_can_batch = pipeline.process, pipeline.process_can_batch
    t0 = time.perf_counter()
    for b in batches:
        if type(b) is list:
            process_can_batch(to_frames(b))
        else:
            process(b)
    pipeline.finish()
    sink.close()
    return time.perf_counter() - t0


def ingest_logger(msgs: list[can.Message], path: Path) -> float:
    logger = can.Logger(str(path))
    t0 = time.perf_counter()
    for m in msgs:
        logger.on_message_received(m)
    logger.stop()
    return time.perf_counter() - t0


@dataclass
class IngestResult:
    frames: int
    nmea: int
    seconds_of_data: float
    rates: dict[str, list[float]] = field(default_factory=dict)
    sizes: dict[str, int] = field(default_factory=dict)


def run_ingest(a: argparse.Namespace, tmp: Path) -> IngestResult:
    cfg = base_config()
    items = sim_items(2000.0, 20.0, a.ingest_seconds)
    msgs = [m for m in items if isinstance(m, can.Message)]
    batches = reader_batches(items)
    res = IngestResult(len(msgs), len(items) - len(msgs), a.ingest_seconds)
    variants: list[tuple[str, Any]] = [
        ("slipdaq, reader batches of up to 256 (to_frames -> Pipeline.process_can_batch -> McapLogSink)",
         lambda p: ingest_batched(cfg, batches, p)),
        ("slipdaq, frame by frame (to_frame -> Pipeline.process -> McapLogSink)",
         lambda p: ingest_slipdaq(cfg, items, p)),
        ("python-can can.Logger -> .blf", lambda p: ingest_logger(msgs, p)),
        ("python-can can.Logger -> .asc", lambda p: ingest_logger(msgs, p)),
    ]
    exts = ["mcap", "mcap", "blf", "asc"]
    print(f"ingest: {len(msgs):,} frames + {res.nmea} NMEA lines ({a.ingest_seconds:g} s of 4 x 2000 Hz + 20 Hz), "
          f"{a.rounds} interleaved rounds", flush=True)
    for r in range(a.rounds):
        for (name, fn), ext in zip(variants, exts):
            path = tmp / f"ingest-{r}-{len(res.rates.get(name, []))}-{abs(hash(name)) % 10000}.{ext}"
            dt = fn(path)
            res.rates.setdefault(name, []).append(len(msgs) / dt)
            res.sizes[name] = path.stat().st_size
            path.unlink()
            print(f"  round {r + 1}: {name}: {fmt_rate(len(msgs) / dt)} frames/s", flush=True)
    return res


def ingest_table(res: IngestResult) -> str:
    names = list(res.rates)
    slip = median(res.rates[names[0]])
    blf = median(res.rates[next(n for n in names if n.endswith(".blf"))])
    asc = median(res.rates[next(n for n in names if n.endswith(".asc"))])
    rows = []
    for n in names:
        m = median(res.rates[n])
        rows.append([n, fmt_rate(m), f"{min(res.rates[n]):,.0f}–{max(res.rates[n]):,.0f}", f"{m / 9000:.2f}×",
                     f"{m / blf:.3f}", f"{m / asc:.3f}", f"{res.sizes[n] / res.frames:.1f}"])
    head = (f"{res.frames:,} CAN frames ({res.seconds_of_data:g} s of 4 WPT messages × 2000 Hz) + {res.nmea} NMEA "
            f"lines (20 Hz RMC+GGA+VTG), median of {len(res.rates[names[0]])} interleaved rounds; frames/s counts CAN "
            f"frames only (python-can's loggers get no NMEA). Targets: ≥ 150,000 frames/s and ≥ the BLF logger.\n\n")
    t = table(["path", "frames/s (median)", "range", "× saturated bus (9,000/s)", "ratio to BLF", "ratio to ASC",
               "file bytes/frame"], rows)
    verdict = (f"\n\nslipdaq / BLF = {slip / blf:.3f}, slipdaq / ASC = {slip / asc:.3f}; slipdaq "
               f"{'meets' if slip >= 150000 and slip >= blf else 'misses'} the ingest target.")
    return head + t + verdict
