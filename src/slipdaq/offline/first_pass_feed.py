"""A two-pass run's first pass fed by the log's process, which reads the log anyway (LogProcess with read): that
process decodes the input's items and makes the pipeline's wheel and NMEA decoder calls over them
(DecodingPipeline: Pipeline's own cuts, no estimator), and sends the run each run of items (items.read_ahead) with
those calls' tape entries (decoder_tape) before it takes the run further. The first pass then neither reads nor
decodes: it plays the entries as they come (DecoderTape(fed=True)), and the second plays them again. Both pipelines
get the same items in the same runs, and Pipeline cuts the wheel frames by the records' times alone, so the calls are
the same one for one; a played call is checked against its entry (TapeMismatch)."""

from __future__ import annotations

import pickle
import sys
from collections.abc import Callable, Iterable, Iterator
from multiprocessing.connection import Connection
from typing import Any

from slipdaq.config import Config
from slipdaq.decode.timemark import TimeMark
from slipdaq.offline.decoder_tape import DecoderTape
from slipdaq.offline.items import Item, read_ahead
from slipdaq.pipeline import Pipeline
from slipdaq.records import CanFrameBatch, GpsFix, SensorSample

FEED_RECORDS = 3 << 20
"""A log is fed to its first pass up to this many raw records (the log's process then keeps every frame it reads for
the second pass: LogProcess's AHEAD_FRAMES; the run keeps them too: read_once.KEEP_BYTES)."""


class DecodingPipeline(Pipeline):
    """A pipeline that makes only its decoders' calls (with Pipeline's cuts and diagnostics times): no estimator, no
    maneuver, no sink, no snapshot."""

    def _can_segment(self, batch: CanFrameBatch, parts: object, offset: int) -> None:
        self._segment_samples(batch)
        self.can_frames += len(batch)
        self._tick(float(batch.timestamp_s[-1]))

    def _fix(self, fix: GpsFix, log_time_s: float) -> None:
        pass

    def _sensor(self, sample: SensorSample) -> None:
        pass

    def _time_mark(self, mark: TimeMark | None) -> None:
        pass

    def emit_diagnostics(self) -> None:
        pass


class FeedSender:
    """In the log's process: the items it reads, each run decoded by a DecodingPipeline and sent to the run,
    send((run, its wheel entries, its line entries)), before the process takes it; last send((None, end())) (a
    scan's result)."""

    def __init__(self, config: Config, send: Callable[[tuple[Any, ...]], None], end: Callable[[], Any] | None) -> None:
        self._tape = DecoderTape(sys.maxsize)  # the entries go to the run: the run's tape keeps them within its budget
        self._pipeline = DecodingPipeline(config, [], maneuvers=False, fast_slip=False)
        self._tape.attach(self._pipeline)
        self._send = send
        self._end = end

    def runs(self, items: Iterable[Item]) -> Iterator[Item]:
        tape = self._tape
        for run in read_ahead(items):
            self._pipeline.process_all(run)
            self._send((run, tape.wheels, tape.lines))
            tape.wheels, tape.lines = [], []
            yield from run
        self._send((None, self._end() if self._end is not None else None))


def sending(feed: Connection) -> Callable[[tuple[Any, ...]], None]:
    """A FeedSender's send over a pipe (LogProcess.fed reads it)."""
    return lambda message: feed.send_bytes(pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL))
