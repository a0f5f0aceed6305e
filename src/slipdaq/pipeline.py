"""Raw records in -> decoded -> estimator -> sinks. Live, replay and import all call Pipeline.process, or
Pipeline.process_can_batch for consecutive CAN frames.

Records are processed in the order given; the estimates depend on nothing else, so a log replayed in
the order it was recorded gives the same estimates, bit for bit. How CAN frames are grouped into batches does not
change anything either: a batch gives the same samples, estimates (released by the same frames, with the same log
times), counters and diagnostics snapshots as its frames one by one.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np

from slipdaq.config import Config
from slipdaq.decode.can_wheels import WheelDecoder
from slipdaq.decode.nmea import NmeaDecoder
from slipdaq.decode.ubx import UbxDecoder
from slipdaq.estimator import EstimatorParams, SlipEstimator
from slipdaq.records import (
    FLAG_ERROR,
    CanFrame,
    CanFrameBatch,
    Diagnostics,
    Estimate,
    GpsFix,
    NmeaLine,
    RawRecord,
    UbxFrame,
    WheelSampleBatch,
)
from slipdaq.sinks import Sink

DIAGNOSTICS_PERIOD_S = 1.0
SCALAR_MAX_FRAMES = 48
"""process_can_batch takes frames one by one below this batch size (numpy's fixed cost per call dominates)."""
AHEAD_MAX_FRAMES = 8192
"""process_all decodes at most this many frames ahead at once."""


class _Ahead:
    """Wheel frames decoded ahead (Pipeline.process_all): frames [first, stop) of the run, counted as can_frames."""

    __slots__ = ("first", "stop", "which", "samples", "sample_frame")

    def __init__(self, first: int, which: np.ndarray, samples: WheelSampleBatch) -> None:
        self.first = first
        self.stop = first + len(which)
        self.which = which
        self.samples = samples
        self.sample_frame = samples.frame  # index in the decoded run; in frame order

    def take(self, first: int, n: int) -> tuple[np.ndarray, WheelSampleBatch]:
        """wheel_frames and decode_batch of the n frames from `first` on, as if decoded alone."""
        k = first - self.first
        sf = self.sample_frame
        i0, i1 = int(sf.searchsorted(k)), int(sf.searchsorted(k + n))
        return self.which[k : k + n], self.samples.slice(i0, i1, frame_offset=-k)


class Pipeline:
    def __init__(self, config: Config, sinks: Sequence[Sink]) -> None:
        self.config = config
        self.sinks = list(sinks)
        self.wheels = WheelDecoder(config)
        self.nmea = NmeaDecoder()
        self.ubx = UbxDecoder()
        self._velocity_from = NmeaLine if config.gps.velocity == "nmea" else UbxFrame
        self.estimator = SlipEstimator(EstimatorParams.from_config(config))
        self.can_frames = 0
        self.unknown_frames = 0
        self.error_frames = 0
        self.estimates = 0
        self.last_time_s: float | None = None
        self._next_diag_s: float | None = None
        self.scalar_max_frames = SCALAR_MAX_FRAMES
        self._queue: list[RawRecord | CanFrameBatch | Sequence[CanFrame]] | None = None  # process_all's items
        self._queue_pos = 0
        self._item_first = 0  # can_frames before the item being processed
        self._ahead: _Ahead | None = None

    def waiting_for_wheels(self) -> bool:
        """An estimate waits only for wheel frames (a live CAN reader that pauses between reads should read now)."""
        return self.estimator.waiting_for_wheels()

    def process(self, record: RawRecord) -> None:
        """One raw record through decode and estimator to every sink."""
        sinks = self.sinks
        for s in sinks:
            s.on_raw(record)
        t = record.timestamp_s
        if isinstance(record, CanFrame):
            self.can_frames += 1
            if record.is_error_frame:
                self.error_frames += 1
                estimates: list[Estimate] = []
            else:
                samples = self.wheels.decode(record)
                if not samples and not self.wheels.is_wheel_frame(record):
                    self.unknown_frames += 1
                estimates = []
                for sample in samples:
                    for s in sinks:
                        s.on_wheel(sample)
                    estimates += self.estimator.add_wheel(sample)
        else:
            fix: GpsFix | None = self.nmea.decode(record) if isinstance(record, NmeaLine) else self.ubx.decode(record)
            if fix is None or not isinstance(record, self._velocity_from):
                estimates = []  # gps.velocity names the other protocol: decoded and counted only
            else:
                for s in sinks:
                    s.on_fix(fix)
                estimates = self.estimator.add_gps(fix)
        for e in estimates:
            self.estimates += 1
            for s in sinks:
                s.on_estimate(e, t)
        self.last_time_s = t
        if self._next_diag_s is None:
            self._next_diag_s = t + DIAGNOSTICS_PERIOD_S
        elif t >= self._next_diag_s:
            self.emit_diagnostics()
            self._next_diag_s = t + DIAGNOSTICS_PERIOD_S

    def process_can_batch(self, frames: CanFrameBatch | Sequence[CanFrame]) -> None:
        """Consecutive CAN frames (a reader's wake-up, a block of a log): the same as process() for each in turn.

        Small batches go one by one; large ones through numpy (decode, unwrap, estimator in bulk), cut only where a
        diagnostics snapshot falls due."""
        n = len(frames)
        if n == 0:
            return
        if n < self.scalar_max_frames:
            for f in frames if not isinstance(frames, CanFrameBatch) else frames.frames():
                self.process(f)
            return
        batch = frames if isinstance(frames, CanFrameBatch) else CanFrameBatch.from_frames(frames)
        ts = batch.timestamp_s
        start = 0
        while start < n:
            if self._next_diag_s is None:
                stop = start + 1
            else:
                due = np.flatnonzero(ts[start:] >= self._next_diag_s)
                stop = start + int(due[0]) + 1 if len(due) else n
            self._can_segment(batch if (start, stop) == (0, n) else batch.slice(start, stop))
            start = stop

    def process_all(self, items: Sequence[RawRecord | CanFrameBatch | Sequence[CanFrame]]) -> None:
        """process_can_batch for each batch of CAN frames (a CanFrameBatch or a list of CanFrames) and process for
        each other record, in turn: the same calls to every sink, in the same order, and the same counters at every
        diagnostics snapshot. Offline runs read ahead: the wheel frames of consecutive batches (of at least
        scalar_max_frames) up to where the next snapshot falls due are decoded at once (WheelDecoder.decode_batch
        gives the same samples and counters whatever the batches), so numpy's fixed cost is paid once for many."""
        queue = [CanFrameBatch.from_frames(x) if isinstance(x, list) and len(x) >= self.scalar_max_frames else x
                 for x in items]
        self._queue = queue
        try:
            for k, item in enumerate(queue):
                if isinstance(item, (CanFrameBatch, list)):
                    self._queue_pos, self._item_first = k, self.can_frames
                    self.process_can_batch(item)
                else:
                    self.process(item)  # type: ignore[arg-type]  # a queue item that is not a batch is one raw record
        finally:
            self._queue = self._ahead = None

    def _decode_ahead(self, first: int) -> _Ahead | None:
        """Decode the queued frames from `first` (in the item being processed) up to the frame that makes the next
        diagnostics snapshot due, a batch below scalar_max_frames, or a GPS record that makes the snapshot due."""
        due = self._next_diag_s
        queue = self._queue
        if due is None or queue is None:
            return None
        parts: list[CanFrameBatch] = []
        n = 0
        off = first - self._item_first
        for it in queue[self._queue_pos:]:
            if isinstance(it, CanFrameBatch):
                if len(it) < self.scalar_max_frames:
                    break
                b = it.slice(off, len(it)) if off else it
                off = 0
                hit = np.flatnonzero(b.timestamp_s >= due)
                if len(hit):
                    parts.append(b.slice(0, int(hit[0]) + 1))
                    break
                parts.append(b)
                n += len(b)
                if n >= AHEAD_MAX_FRAMES:
                    break
            elif isinstance(it, list) or it.timestamp_s >= due:  # type: ignore[union-attr]  # not a batch or a list: a raw record, which has timestamp_s
                break
        if not parts:
            return None
        run = parts[0] if len(parts) == 1 else CanFrameBatch.concat(parts)
        which = self.wheels.wheel_frames(run)
        return _Ahead(first, which, self.wheels.decode_batch(run, which))

    def _can_segment(self, batch: CanFrameBatch) -> None:
        """Frames of which at most the last may make a diagnostics snapshot due."""
        n = len(batch)
        first = self.can_frames
        ahead = self._ahead
        if self._queue is not None and (ahead is None or not ahead.first <= first < ahead.stop):
            ahead = self._ahead = self._decode_ahead(first)
        if ahead is not None and ahead.first <= first < ahead.stop:
            assert first + n <= ahead.stop, "a segment beyond the frames decoded ahead"  # they end where segments do
            which, samples = ahead.take(first, n)
        else:
            which = self.wheels.wheel_frames(batch)
            samples = self.wheels.decode_batch(batch, which)
        self.can_frames += n
        error = (batch.flags & FLAG_ERROR) != 0
        self.error_frames += int(np.count_nonzero(error))
        self.unknown_frames += int(np.count_nonzero(~error & (which < 0)))
        released = self.estimator.add_wheels(samples.wheel, samples.timestamp_s, samples.revolutions) \
            if len(samples) else []
        # the sinks get the frames and samples up to the frame that released an estimate, then the estimate: the
        # order of process() frame by frame
        start = 0
        ts = batch.timestamp_s
        for i, e in released:
            stop = int(samples.frame[i]) + 1
            if stop > start:
                self._deliver(batch, samples, start, stop)
                start = stop
            self.estimates += 1
            for s in self.sinks:
                s.on_estimate(e, float(ts[stop - 1]))
        if start < n:
            self._deliver(batch, samples, start, n)
        t = float(batch.timestamp_s[-1])
        self.last_time_s = t
        if self._next_diag_s is None:
            self._next_diag_s = t + DIAGNOSTICS_PERIOD_S
        elif t >= self._next_diag_s:
            self.emit_diagnostics()
            self._next_diag_s = t + DIAGNOSTICS_PERIOD_S

    def _deliver(self, batch: CanFrameBatch, samples: WheelSampleBatch, start: int, stop: int) -> None:
        """Frames start..stop of batch and their samples to the sinks."""
        piece = batch if (start, stop) == (0, len(batch)) else batch.slice(start, stop)
        for s in self.sinks:
            s.on_can_batch(piece)
        if not len(samples):
            return
        frame = samples.frame
        i0, i1 = int(frame.searchsorted(start)), int(frame.searchsorted(stop))
        if i1 <= i0:
            return
        mine = samples if (i0, i1) == (0, len(samples)) and start == 0 else samples.slice(i0, i1, frame_offset=-start)
        for s in self.sinks:
            s.on_wheel_batch(mine)

    def run(self, records: Iterable[RawRecord]) -> None:
        for r in records:
            self.process(r)
        self.finish()

    def finish(self) -> None:
        """A last diagnostics snapshot, so that the log ends with the final counters."""
        if self.last_time_s is not None:
            self.emit_diagnostics()

    def diagnostics(self) -> Diagnostics:
        return Diagnostics(
            time_s=self.last_time_s or 0.0,
            can_frames=self.can_frames,
            wpt_frames=dict(self.wheels.frames),
            lost_frames=dict(self.wheels.lost_frames),
            count_wraps=dict(self.wheels.count_wraps),
            counter_resets=dict(self.wheels.counter_resets),
            unknown_frames=self.unknown_frames,
            error_frames=self.error_frames,
            bad_frames=self.wheels.bad_frames,
            nmea_lines=self.nmea.lines,
            bad_sentences=self.nmea.bad_sentences,
            dropped_sentences=dict(self.nmea.dropped),
            gps_fixes=self.nmea.fixes + self.ubx.fixes,
            ubx_frames=self.ubx.frames,
            bad_ubx_frames=self.ubx.bad_frames,
            estimates=self.estimates,
            estimator=self.estimator.status(),
        )

    def emit_diagnostics(self) -> None:
        d = self.diagnostics().as_dict()
        for s in self.sinks:
            s.on_diagnostics(d, d["time_s"])  # type: ignore[arg-type]  # Diagnostics.as_dict's time_s is a float
