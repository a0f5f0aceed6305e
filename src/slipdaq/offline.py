"""Offline runs (import, replay): a record stream through the pipeline into a new MCAP log, with progress."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TextIO

from slipdaq import compiled
from slipdaq.config import Config
from slipdaq.pipeline import Pipeline
from slipdaq.records import CanFrame, CanFrameBatch, RawRecord
from slipdaq.sinks.mcap_log import McapLogSink

BATCH_FRAMES = 512
"""Consecutive CAN frames of an input go through the pipeline in batches of up to this many."""
READ_AHEAD_FRAMES = 4096
"""The pipeline gets the input in runs of about this many CAN frames (Pipeline.process_all joins consecutive ones)."""
READ_AHEAD_ITEMS = 1024


def batched(records: Iterable[RawRecord | CanFrameBatch]) -> Iterator[RawRecord | CanFrameBatch | list[CanFrame]]:
    """Runs of consecutive CanFrames as lists (up to BATCH_FRAMES); everything else as it comes."""
    run: list[CanFrame] = []
    for r in records:
        if isinstance(r, CanFrame):
            run.append(r)
            if len(run) >= BATCH_FRAMES:
                yield run
                run = []
            continue
        if run:
            yield run
            run = []
        yield r
    if run:
        yield run


def read_ahead(items: Iterable[RawRecord | CanFrameBatch | list[CanFrame]]
               ) -> Iterator[list[RawRecord | CanFrameBatch | list[CanFrame]]]:
    """The items in runs of about READ_AHEAD_FRAMES CAN frames (or READ_AHEAD_ITEMS items), for Pipeline.process_all."""
    run: list[RawRecord | CanFrameBatch | list[CanFrame]] = []
    frames = 0
    for it in items:
        run.append(it)
        if isinstance(it, (list, CanFrameBatch)):
            frames += len(it)
        if frames >= READ_AHEAD_FRAMES or len(run) >= READ_AHEAD_ITEMS:
            yield run
            run, frames = [], 0
    if run:
        yield run


def process_to_log(
    config: Config,
    records: Iterable[RawRecord | CanFrameBatch],
    out_path: Path,
    mode: str,
    *,
    metadata: dict[str, str] | None = None,
    total: int | None = None,
    stream: TextIO | None = None,
    description: str = "",
) -> Pipeline:
    """Run every record through a fresh pipeline into out_path; shows progress on a terminal.

    records: raw records and batches of CAN frames (iter_raw_batches); runs of CanFrames are batched here. The
    estimates are the same whatever the batches (Pipeline.process_can_batch)."""
    stream = stream or sys.stderr
    sink = McapLogSink(out_path, config, mode=mode, metadata=metadata)
    pipeline = Pipeline(config, [sink])
    compiled.prepare()
    try:
        if stream.isatty():
            from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

            with Progress(
                TextColumn(description or mode), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                transient=True,
            ) as bar:
                task = bar.add_task(mode, total=total)
                i = 0
                for run in read_ahead(batched(records)):
                    pipeline.process_all(run)
                    i += len(run)
                    bar.update(task, completed=i)
        else:
            last = time.monotonic()
            i = 0
            for run in read_ahead(batched(records)):
                pipeline.process_all(run)
                i += len(run)
                if time.monotonic() - last > 5:
                    last = time.monotonic()
                    done = f"{i}/{total}" if total else str(i)
                    print(f"{description or mode}: {done} messages", file=stream, flush=True)
        pipeline.finish()
    finally:
        sink.close()
    return pipeline
