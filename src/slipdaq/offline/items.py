"""A run's input as the pipeline takes it: a log's records in items (runs of CAN frames batched), and the items in
runs for Pipeline.process_all. The same cuts in every process that decodes the input (a log's process, its feed)."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from typing import Any

from slipdaq.records import CanFrame, CanFrameBatch, RawRecord

Item = RawRecord | CanFrameBatch | list[CanFrame]
Decode = Callable[[Iterable[Any]], Iterable[Item]]
"""The input's items (as Pipeline.process_all gets them) from its pieces: the same function in the run and the process."""

BATCH_FRAMES = 512
"""Consecutive CAN frames of an input go through the pipeline in batches of up to this many."""
READ_AHEAD_FRAMES = 4096
"""The pipeline gets the input in runs of about this many CAN frames (Pipeline.process_all joins consecutive ones)."""
READ_AHEAD_ITEMS = 1024


def batched(records: Iterable[RawRecord | CanFrameBatch | list[CanFrame]]
            ) -> Iterator[RawRecord | CanFrameBatch | list[CanFrame]]:
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


def items_of(decode: Callable[[Iterable[Any]], Iterable[RawRecord | CanFrameBatch]]) -> Decode:
    """The input's items from its pieces (a log's raw messages): batched(decode(pieces)), as the pipeline and a
    log's process (LogProcess) take them."""
    return lambda pieces: batched(decode(pieces))


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


def let_go(items: list[Item]) -> Iterator[Item]:
    """The items in order, each let go by the list as it is taken (a second pass over a first pass's items)."""
    items.reverse()
    while items:
        yield items.pop()
