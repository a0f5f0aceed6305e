"""Offline runs (import, replay): a record stream through the pipeline into a new MCAP log, with progress."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import TextIO

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from slipdaq.config import Config
from slipdaq.pipeline import Pipeline
from slipdaq.records import CanFrame, CanFrameBatch, RawRecord
from slipdaq.sinks.mcap_log import McapLogSink


BATCH_FRAMES = 512
"""Consecutive CAN frames of an input go through the pipeline in batches of up to this many."""


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


def feed(pipeline: Pipeline, item: RawRecord | CanFrameBatch | list[CanFrame]) -> None:
    if isinstance(item, (list, CanFrameBatch)):
        pipeline.process_can_batch(item)
    else:
        pipeline.process(item)


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
    try:
        if stream.isatty():
            with Progress(
                TextColumn(description or mode), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                transient=True,
            ) as bar:
                task = bar.add_task(mode, total=total)
                for i, r in enumerate(batched(records), 1):
                    feed(pipeline, r)
                    if i % 500 == 0:
                        bar.update(task, completed=i)
        else:
            last = time.monotonic()
            for i, r in enumerate(batched(records), 1):
                feed(pipeline, r)
                if i % 2000 == 0 and time.monotonic() - last > 5:
                    last = time.monotonic()
                    done = f"{i}/{total}" if total else str(i)
                    print(f"{description or mode}: {done} messages", file=stream, flush=True)
        pipeline.finish()
    finally:
        sink.close()
    return pipeline
