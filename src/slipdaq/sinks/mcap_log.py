"""The MCAP layer: topics, JSON schemas and the writer sink. Everything raw and derived, one topic each.

Foxglove opens the file and plots every numeric field. The config (TOML) and DBC text are stored in the
`slipdaq` metadata record, so a log replays with no other input.
"""

from __future__ import annotations

import bisect
import dataclasses
import datetime as dt
import itertools
import logging
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

import slipdaq
from slipdaq import WHEELS
from slipdaq.config import Config
from slipdaq.logformat import cdr
from slipdaq.logformat.json_codec import (
    dumps,
    estimate_json,
    fast_slip_messages,
    fix_json,
    location_fix_json,
    nmea_line_json,
)
from slipdaq.logformat.rotation import RotationPolicy
from slipdaq.logformat.topics import (
    MAX_BATCH_FRAMES,
    MAX_BATCH_SPAN_S,
    TOPIC_CAN,
    TOPIC_DIAGNOSTICS,
    TOPIC_ESTIMATE,
    TOPIC_EVENTS,
    TOPIC_FAST_SLIP,
    TOPIC_FAST_SLIP_ROW,
    TOPIC_GPS,
    TOPIC_GPS_LOCATION,
    TOPIC_IMU_RAW,
    TOPIC_MANEUVER,
    TOPIC_NMEA,
    TOPIC_RTCM,
    TOPIC_SENSORS,
    TOPIC_TEST_SET,
    TOPIC_UBX,
    TOPIC_WPT,
)
from slipdaq.logformat.writer import RETRY_AFTER_FAILURE_S, LogWriter
from slipdaq.maneuver.record import Maneuver
from slipdaq.records import (
    SAMPLE_HAS_COUNT,
    SAMPLE_HAS_SEQ,
    CanFrame,
    CanFrameBatch,
    Estimate,
    EventHandler,
    FastSlip,
    GpsFix,
    NmeaLine,
    RawRecord,
    RtcmFrame,
    SensorSample,
    SourceEvent,
    UbxFrame,
    WheelSample,
    WheelSampleBatch,
    XbusBytes,
)
from slipdaq.sinks import Sink

if TYPE_CHECKING:
    import asyncio

log = logging.getLogger(__name__)

class _Pending:
    """Records waiting for their batch message (/can/raw, /wpt/count): whole batches and runs of single records, in
    order. A batch is full at MAX_BATCH_FRAMES records, or with the first record MAX_BATCH_SPAN_S after its first."""

    def __init__(self) -> None:
        self.parts: list[Any] = []
        self.n = 0
        self.first_index = 0
        self.t0 = 0.0
        self.t_last = 0.0
        """Log time of the last record: the batch's log time."""
        self.frame_last = 0
        """Index of the CAN frame the last record is (or came from): the batch's place in the order of processing."""

    def add_one(self, record: object, t: float, index: int, frame: int) -> bool:
        """One record (log time t, number index in its stream, from CAN frame number frame); True when the batch is
        now full."""
        if not self.n:
            self.first_index, self.t0 = index, t
            self.parts.append([])
        elif not isinstance(self.parts[-1], list):
            self.parts.append([])
        self.parts[-1].append(record)
        self.n += 1
        self.t_last, self.frame_last = t, frame
        return self.n >= MAX_BATCH_FRAMES or t - self.t0 >= MAX_BATCH_SPAN_S

    def add_run(self, ts: np.ndarray, first_index: int, piece: Callable[[int, int], object],
                flush: Callable[[], None], frame: Callable[[int], int]) -> None:
        """Consecutive records with log times ts, the first numbered first_index: piece(i, k) is records i..k-1,
        frame(i) the CAN frame number record i is or came from; flush() is called after each piece that fills the
        batch, as add_one one by one would."""
        i, n = 0, len(ts)
        while i < n:
            if not self.n:
                self.first_index, self.t0 = first_index + i, float(ts[i])
            k = min(n, i + MAX_BATCH_FRAMES - self.n)
            full = self.n + k - i >= MAX_BATCH_FRAMES
            late = ts[i:k] - self.t0 >= MAX_BATCH_SPAN_S
            if late.any():
                k, full = i + int(late.argmax()) + 1, True  # argmax: the first True
            self.parts.append(piece(i, k))
            self.n += k - i
            self.t_last, self.frame_last = float(ts[k - 1]), frame(k - 1)
            i = k
            if full:
                flush()


class _PendingCan(_Pending):
    """Frames waiting for their /can/raw batch."""

    def take(self, channels: tuple[str | None, ...]) -> CanFrameBatch:
        """The batch, its frames' channel indices into `channels` (the log's can_channels)."""
        parts = [(p if isinstance(p, CanFrameBatch) else CanFrameBatch.from_frames(p)).renamed(channels)
                 for p in self.parts]
        self.parts, self.n = [], 0
        return parts[0] if len(parts) == 1 else CanFrameBatch.concat(parts)


class _PendingSamples(_Pending):
    """Wheel samples waiting for their /wpt/count batch."""

    def take(self) -> WheelSampleBatch:
        parts = [p if isinstance(p, WheelSampleBatch) else samples_to_batch(p) for p in self.parts]
        self.parts, self.n = [], 0
        if len(parts) == 1:
            return parts[0]
        return WheelSampleBatch(*(np.concatenate([getattr(p, f) for p in parts]) for f in WheelSampleBatch.__slots__))


_WHEEL_INDEX = {w: i for i, w in enumerate(WHEELS)}


def samples_to_batch(samples: list[WheelSample]) -> WheelSampleBatch:
    n = len(samples)
    return WheelSampleBatch(
        np.full(n, -1, dtype=np.int64), np.array([_WHEEL_INDEX[s.wheel] for s in samples], dtype=np.uint8),
        np.array([s.timestamp_s for s in samples], dtype=np.float64),
        np.array([s.revolutions for s in samples], dtype=np.float64),
        np.array([s.count or 0 for s in samples], dtype=np.int64), np.array([s.raw for s in samples], dtype=np.float64),
        np.array([s.seq or 0 for s in samples], dtype=np.int64),
        np.array([s.lost_frames for s in samples], dtype=np.int64),
        np.array([(SAMPLE_HAS_COUNT if s.count is not None else 0) | (SAMPLE_HAS_SEQ if s.seq is not None else 0)
                  for s in samples], dtype=np.uint8),
    )


class McapLogSink(Sink):
    """Writes every record and result to an MCAP log (logformat.writer), crash-safe; call close() to finish it.

    CAN frames and wheel samples go into /can/raw and /wpt/count batches (pending until full, then written in the
    order of processing). Live runs (flush_every_s set): a chunk is closed and committed at least every
    flush_every_s seconds of the monotonic clock, whether records come or not (a timer on the running event loop,
    when there is one), and a failed write (disk full) never raises out of the sink: it is reported (`error`,
    `log_status()`, an event) and the pipeline goes on. `rotation` cuts the log into segments.
    """

    new_files_only = False
    """Refuse (FileExistsError) to write a segment over a file that is there (the live daemon's log)."""

    def __init__(
        self,
        path: str | Path,
        config: Config,
        mode: str,
        metadata: dict[str, str] | None = None,
        flush_every_s: float | None = None,
        *,
        rotation: RotationPolicy | None = None,
        fsync: bool | None = None,
        clock: Callable[[], float] | None = None,
        on_event: EventHandler | None = None,
        monotonic: Callable[[], float] = time.monotonic,
        can_channels: Sequence[str | None] = (),
        tap: Callable[[str, float, bytes], None] | None = None,
    ) -> None:
        """clock: the log's clock (the sources' SteadyClock in live runs), for the times of the sink's own events.
        on_event: gets the sink's own events (write failed, resumed, rotated), e.g. the live view. fsync: default on
        for live runs (flush_every_s set). can_channels: the CAN channel names known before the first frame (a live
        run's bus); the frames' other channels are added as they come. tap: gets (topic, log time in s, bytes) of
        every message as the log gets it (a late record at the later log time the file gives it), e.g. the Foxglove
        live server (sinks.foxglove_live); it must not block."""
        first_path = Path(path)
        first_path.parent.mkdir(parents=True, exist_ok=True)
        self._flush_every_s = flush_every_s
        self._clock = clock or time.time
        self._on_event = on_event
        self._mono = monotonic
        self._tap = tap
        self._tap_last_s = 0.0
        self.closed = False
        meta = {
            "version": slipdaq.__version__,
            "mode": mode,
            "created_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
            "config_path": str(config.source_path or ""),
            "config_toml": config.to_toml(),
            "config_source_toml": config.source_text,
            "dbc": config.load_dbc_text(),
        } | (metadata or {})
        self._timer: asyncio.TimerHandle | None = None
        self._can = _PendingCan()
        self._samples = _PendingSamples()
        self._ready: list[tuple[int, int, int, str, float, bytes]] = []
        """Closed batches not written yet: (CAN frame number, 0 /can/raw or 1 /wpt/count, sequence, topic, log time,
        message), written in that order before the next other message (see _drain)."""
        self._closed = itertools.count()
        """The closed batches' sequence: the order they closed in."""
        self._piece_first = 0
        """Number of the first frame of the last on_can_batch (its samples' `frame` counts from there)."""
        self.can_index = 0
        """CAN frames received so far (the next frame's index; GPS lines record it as can_index)."""
        self._sample_index = 0
        self.unlogged_records = 0
        self._in_flush = False
        self._loop: asyncio.AbstractEventLoop | None = None
        aio = sys.modules.get("asyncio")  # not imported: no event loop is running (offline runs do not import it)
        if aio is not None:
            try:
                self._loop = aio.get_running_loop()
            except RuntimeError:
                pass
        self.log = LogWriter(
            first_path, meta, chunk_size_bytes=config.log.chunk_size_bytes,
            fsync=flush_every_s is not None if fsync is None else fsync, survive_failures=flush_every_s is not None,
            new_files_only=self.new_files_only, rotation=rotation, monotonic=monotonic, on_event=self._log_event,
            can_channels=can_channels,
        )
        self._arm_timer()

    # ---- the log's state ----
    @property
    def path(self) -> Path:
        return self.log.path

    @property
    def segments(self) -> list[Path]:
        return self.log.segments

    @property
    def error(self) -> str | None:
        return self.log.error

    @property
    def dropped_messages(self) -> int:
        return self.log.dropped_messages

    @property
    def size_bytes(self) -> int:
        """Bytes of the segment being written (committed and buffered)."""
        return self.log.size_bytes

    def log_status(self) -> dict[str, object]:
        """The log's state, for the live view and each /diagnostics record of a live run."""
        w = self.log
        return {"log_path": str(w.path), "log_segments": len(w.segments), "log_write_failures": w.write_failures,
                "log_dropped_messages": w.dropped_messages, "log_error": w.error}

    # ---- events ----
    def _log_event(self, writer: LogWriter, event: str, detail: str, gap_s: float | None) -> None:
        """The writer's events (write failed, resumed, rotated): into the log when it is writing, and to on_event."""
        ev = SourceEvent(self._clock(), "log", event, detail, gap_s, writer.counters())
        if writer.writing:
            self.on_source_event(ev)
        if self._on_event is not None:
            self._on_event(ev)

    def on_source_event(self, event: SourceEvent) -> None:
        """A source's event (GPS unplugged, CAN reader error, ...) -> /diagnostics/events."""
        self._write(TOPIC_EVENTS, event.time_s, dumps(event.as_dict()))

    # ---- writing ----
    def _write(self, topic: str, log_time_s: float, data: bytes) -> None:
        """A message after the closed batches (they come first in the order of processing)."""
        if self._ready:
            self._drain()
        self._emit(topic, log_time_s, data)

    def _drain(self, before: int | None = None) -> None:
        """The closed batches in the order of processing: by the CAN frame each ends with, /can/raw before the
        /wpt/count samples of the same frame. (Pipeline.process_can_batch hands a run of frames to on_can_batch
        before its samples to on_wheel_batch; this puts them in the order frame by frame would.) before: only those
        that end before that frame (frame by frame, the frames after them wrote them)."""
        ready = sorted(self._ready)
        if before is None:
            self._ready = []
        else:
            k = bisect.bisect_left(ready, (before,))  # the first that ends at or after that frame
            ready, self._ready = ready[:k], ready[k:]
        in_flush, self._in_flush = self._in_flush, True  # no chunk flush in between: it would close more batches
        try:
            for _frame, _kind, _seq, topic, t, data in ready:
                self._emit(topic, t, data)
        finally:
            self._in_flush = in_flush

    def _emit(self, topic: str, log_time_s: float, data: bytes) -> None:
        """Write one message (a record that arrived after a later-stamped one, e.g. a GPS line read before the CAN
        frames stamped before it, is logged when it was processed); commit when a live run's period is up."""
        if self._tap is not None:  # the log time the file gets: never earlier than the last message's (LogWriter)
            self._tap_last_s = max(self._tap_last_s, log_time_s)
            self._tap(topic, self._tap_last_s, data)
        now = self._mono()
        if (self.log.write(topic, log_time_s, data, now) and self._flush_every_s is not None
                and now - self.log.last_commit >= self._flush_every_s and not self._in_flush):
            self.flush()

    def flush_batches(self) -> None:
        """Write the pending /can/raw and /wpt/count batches now (after the closed ones that frame by frame would have
        written already: those that end before the last frame)."""
        if self._ready and (self._can.n or self._samples.n):
            self._drain(before=self.can_index - 1)
        if self._can.n:
            self._flush_can()
        if self._samples.n:
            self._flush_samples()
        if self._ready:
            self._drain()

    def flush(self) -> None:
        """Close the chunk in progress and commit the file (it is then complete up to here on disk)."""
        if not self.log.writing:
            return
        self._in_flush = True
        try:
            self.flush_batches()
        finally:
            self._in_flush = False
        self.log.commit()

    def _to_flush(self) -> bool:
        """Anything not on disk yet: messages since the last commit, batches open or closed and not written."""
        return bool(self.log.unflushed or self._can.n or self._samples.n or self._ready)

    def _arm_timer(self) -> None:
        if self._loop is None or self._flush_every_s is None or self.closed or self._loop.is_closed():
            return
        delay = max(0.0, self.log.last_commit + self._flush_every_s - self._mono())
        if delay <= 0.0 and not self._to_flush():
            delay = self._flush_every_s  # nothing to flush (no record for a while): look again later, do not spin
        if not self.log.writing:  # failed: look again when a retry is due
            delay = max(0.05, self.log.last_try + RETRY_AFTER_FAILURE_S - self._mono())
        self._timer = self._loop.call_later(min(delay, self._flush_every_s), self._tick)

    def _tick(self) -> None:
        """On the event loop: close the chunk when it is due even if no record came, rotate, retry."""
        self._timer = None
        if self.closed or self._flush_every_s is None:
            return
        now = self._mono()
        if not self.log.writing:
            self.log.try_resume()
        elif self.log.rotation_due(now):
            self.log.rotate()
        elif self._to_flush() and now - self.log.last_commit >= self._flush_every_s - 1e-3:
            self.flush()
        self._arm_timer()

    # ---- Sink ----
    def on_raw(self, record: RawRecord) -> None:
        if isinstance(record, CanFrame):
            if self._ready:
                self._drain()
            if record.channel not in self.log.channel_names:
                self.log.add_channels((record.channel,))
            full = self._can.add_one(record, record.timestamp_s, self.can_index, self.can_index)
            self.can_index += 1
            if full:
                self._flush_can()
        elif isinstance(record, NmeaLine):
            self.flush_batches()  # the file keeps the order of processing: frames before, line, frames after
            self._write(TOPIC_NMEA, record.timestamp_s, nmea_line_json(record, self.can_index))
        elif isinstance(record, UbxFrame | XbusBytes | RtcmFrame):
            self.flush_batches()
            topic = TOPIC_UBX if isinstance(record, UbxFrame) else TOPIC_IMU_RAW if isinstance(record, XbusBytes) \
                else TOPIC_RTCM
            self._write(topic, record.timestamp_s,
                        dumps({"timestamp_s": record.timestamp_s, "data": record.data.hex(),
                                "can_index": self.can_index}))
        else:  # a raw record type this sink has no topic for yet: say so once, do not stop the run
            self.unlogged_records += 1
            if self.unlogged_records == 1:
                log.error("MCAP log: no topic for raw %s records: not logged", type(record).__name__)

    def _flush_can(self) -> None:
        """Close the pending /can/raw batch: its log time is its last frame's (it is complete then)."""
        p = self._can
        first, t, frame = p.first_index, p.t_last, p.frame_last
        data = cdr.reencode_can_batch(first, p.take(self.log.channel_names))
        self._ready.append((frame, 0, next(self._closed), TOPIC_CAN, t, data))

    def _flush_samples(self) -> None:
        """Close the pending /wpt/count batch: its log time is its last sample's."""
        q = self._samples
        first, t, frame = q.first_index, q.t_last, q.frame_last
        data = cdr.encode_wheel_batch(first, q.take())
        self._ready.append((frame, 1, next(self._closed), TOPIC_WPT, t, data))

    def on_can_batch(self, batch: CanFrameBatch) -> None:
        """Consecutive frames (Pipeline.process_can_batch): into /can/raw batches by the same rule as on_raw."""
        if self._ready:
            self._drain()
        if batch.channels != self.log.channel_names[: len(batch.channels)]:
            self.log.add_channels(batch.channels)
        n = len(batch)
        first = self._piece_first = self.can_index
        self._can.add_run(batch.timestamp_s, first,
                          lambda i, k: batch if (i, k) == (0, n) else batch.slice(i, k), self._flush_can,
                          lambda i: first + i)
        self.can_index += n

    def on_wheel(self, sample: WheelSample) -> None:
        full = self._samples.add_one(sample, sample.timestamp_s, self._sample_index, self.can_index - 1)
        self._sample_index += 1
        if full:
            self._flush_samples()

    def on_wheel_batch(self, samples: WheelSampleBatch) -> None:
        """Samples of the frames of the on_can_batch call just before (samples.frame: their index there)."""
        n = len(samples)
        first, frames = self._piece_first, samples.frame
        self._samples.add_run(
            samples.timestamp_s, self._sample_index,
            lambda i, k: samples if (i, k) == (0, n) else
            WheelSampleBatch(*(getattr(samples, f)[i:k] for f in WheelSampleBatch.__slots__)),
            self._flush_samples, lambda i: first + int(frames[i]) if frames[i] >= 0 else self.can_index - 1)
        self._sample_index += n

    def on_fix(self, fix: GpsFix) -> None:
        self._write(TOPIC_GPS, fix.timestamp_s, fix_json(fix))
        location = location_fix_json(fix)
        if location is not None:  # a valid fix with a position, for Foxglove's Map panel
            self._write(TOPIC_GPS_LOCATION, fix.timestamp_s, location)

    def on_estimate(self, estimate: Estimate, log_time_s: float) -> None:
        self._write(TOPIC_ESTIMATE, log_time_s, estimate_json(estimate))

    def on_fast_slip(self, row: FastSlip, log_time_s: float) -> None:
        self.on_fast_slip_rows((row,), log_time_s)

    def on_fast_slip_rows(self, rows: Sequence[FastSlip], log_time_s: float) -> None:
        """One /slip/fast message of columns per run of rows with the same wheels (all of them, in practice), then
        each row on /slip/fast/row (at the same log time, stamped with its own)."""
        runs, each = fast_slip_messages(rows)
        for data in runs:
            self._write(TOPIC_FAST_SLIP, log_time_s, data)
        for data in each:
            self._write(TOPIC_FAST_SLIP_ROW, log_time_s, data)

    def on_maneuver(self, maneuver: Maneuver, log_time_s: float) -> None:
        self._write(TOPIC_MANEUVER, log_time_s, dumps(maneuver.as_row()))

    def on_test_set(self, record: dict[str, Any], log_time_s: float) -> None:
        self._write(TOPIC_TEST_SET, log_time_s, dumps(record))

    def on_sensor(self, sample: SensorSample) -> None:
        self._write(TOPIC_SENSORS, sample.time_s, dumps(dataclasses.asdict(sample)))

    def on_diagnostics(self, diagnostics: dict[str, object], log_time_s: float) -> None:
        if self._flush_every_s is not None:  # live: the log's own state goes with the counters
            diagnostics = diagnostics | self.log_status()
        self._write(TOPIC_DIAGNOSTICS, log_time_s, dumps(diagnostics))

    def close(self) -> None:
        """Finish the file (summary and footer). Safe to call twice; never raises for a failed write."""
        if self.closed:
            return
        if self.log.writing:
            self.flush_batches()
        self.closed = True
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        self.log.close()
