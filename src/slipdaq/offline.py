"""Offline runs (import, replay): a record stream through the pipeline into a new MCAP log, with progress."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable
from pathlib import Path
from typing import TextIO

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

from slipdaq.config import Config
from slipdaq.pipeline import Pipeline
from slipdaq.records import RawRecord
from slipdaq.sinks.mcap_log import McapLogSink


def process_to_log(
    config: Config,
    records: Iterable[RawRecord],
    out_path: Path,
    mode: str,
    *,
    metadata: dict[str, str] | None = None,
    total: int | None = None,
    stream: TextIO | None = None,
    description: str = "",
) -> Pipeline:
    """Run every record through a fresh pipeline into out_path; shows progress on a terminal."""
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
                for i, r in enumerate(records, 1):
                    pipeline.process(r)
                    if i % 5000 == 0:
                        bar.update(task, completed=i)
        else:
            last = time.monotonic()
            for i, r in enumerate(records, 1):
                pipeline.process(r)
                if i % 20000 == 0 and time.monotonic() - last > 5:
                    last = time.monotonic()
                    done = f"{i}/{total}" if total else str(i)
                    print(f"{description or mode}: {done} records", file=stream, flush=True)
        pipeline.finish()
    finally:
        sink.close()
    return pipeline
