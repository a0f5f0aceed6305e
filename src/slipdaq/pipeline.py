"""Raw records in -> decoded -> estimator -> sinks. Live, replay and import all call Pipeline.process for a GPS
record and Pipeline.process_can_batch for consecutive CAN frames (a CAN frame alone is a batch of one).

Records are processed in the order given; the estimates depend on nothing else, so a log replayed in
the order it was recorded gives the same estimates, bit for bit. How CAN frames are grouped into batches does not
change anything either: a batch gives the same samples, estimates (released by the same frames, with the same log
times), counters and diagnostics snapshots as its frames one by one.
"""

from __future__ import annotations

from bisect import bisect_right
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from concurrent.futures import Executor, Future
from dataclasses import replace

import numpy as np

from slipdaq import WHEELS
from slipdaq.config import Config
from slipdaq.config.calibration import Calibration
from slipdaq.decode.can_signals import SignalDecoder
from slipdaq.decode.can_wheels import WheelDecoder
from slipdaq.decode.mti_accel import MtiAccel
from slipdaq.decode.nmea import NmeaDecoder
from slipdaq.decode.timemark import TimeMark
from slipdaq.decode.ubx import UbxDecoder
from slipdaq.estimator import EstimatorParams, SlipEstimator
from slipdaq.estimator.force import RoadLoads
from slipdaq.maneuver.coast import CoastDetector, CoastRun
from slipdaq.maneuver.detector import BRAKE_MARK, Job, ManeuverDetector
from slipdaq.maneuver.record import MANEUVER_KINDS, Maneuver, coast_record
from slipdaq.maneuver.test_set import TestSets
from slipdaq.records import (
    FLAG_ERROR,
    CanFrame,
    CanFrameBatch,
    Diagnostics,
    Estimate,
    GpsFix,
    NmeaLine,
    RawRecord,
    RtcmFrame,
    SensorSample,
    UbxFrame,
    WheelSampleBatch,
    XbusBytes,
)
from slipdaq.sinks import Sink, SinkFanout
from slipdaq.sinks.held import HOLD_MAX_CALLS, HeldCalls, ready

DIAGNOSTICS_PERIOD_S = 1.0
COURSE_MIN_SPEED_MPS = 2.0
"""A fix's course is the heading of an MTi's FreeAcceleration (without orientation) from this speed on."""
MERGE_MAX_FRAMES = 8192
"""process_all decodes and estimates at most this many frames of consecutive batches at once."""


class _Decoded:
    """Wheel frames decoded ahead (Pipeline.process_all): the frames from `first` (counted as can_frames) on."""

    __slots__ = ("first", "stop", "which", "samples")
    NONE: _Decoded

    def __init__(self, first: int, which: np.ndarray, samples: WheelSampleBatch) -> None:
        self.first = first
        self.stop = first + len(which)
        self.which = which
        self.samples = samples

    def contains(self, i: int) -> bool:
        return self.first <= i < self.stop

    def covers(self, first: int, n: int) -> bool:
        return self.first <= first and first + n <= self.stop

    def take(self, first: int, n: int) -> tuple[np.ndarray, WheelSampleBatch]:
        """wheel_frames and decode_batch of the n frames from `first` on, as if decoded alone."""
        k = first - self.first
        return self.which[k : k + n], self.samples.of_frames(k, k + n)


_Decoded.NONE = _Decoded(0, np.empty(0, dtype=np.int64), WheelSampleBatch.empty())


class _Parts:
    """The batches a run of frames came in: the sinks get the frames in those batches."""

    __slots__ = ("parts", "starts")

    def __init__(self, parts: list[CanFrameBatch]) -> None:
        self.parts = parts
        self.starts = [0]
        for p in parts:
            self.starts.append(self.starts[-1] + len(p))

    def pieces(self, start: int, stop: int) -> Iterator[tuple[int, int, CanFrameBatch]]:
        """(a, b, frames a..b of the run) covering start..stop, cut where the batches end."""
        k = bisect_right(self.starts, start) - 1
        while start < stop:
            p, p0, p1 = self.parts[k], self.starts[k], self.starts[k + 1]
            b = min(stop, p1)
            yield start, b, p if (start, b) == (p0, p1) else p.slice(start - p0, b - p0)
            start = b
            k += 1


class Pipeline:
    def __init__(self, config: Config, sinks: Sequence[Sink], *, calibration: Calibration | None = None,
                 frozen: bool = False, gps_speeds: Sequence[float] | None = None, maneuvers: bool = True,
                 maneuver_executor: Executor | None = None, hold_output: bool = False, fast_slip: bool = True,
                 wheel_estimates: bool = True) -> None:
        """calibration: the stored calibration the estimator starts from (frozen: uses throughout, a second pass);
        gps_speeds: the speed the estimator takes for each GPS fix in turn, in place of the fix's own (a second
        pass's smoothed speeds); the sinks get the fixes as decoded. maneuvers=False: no maneuver is summarized (a
        pass whose sinks take no /maneuver record: the maneuver detector gets nothing). maneuver_executor: where a decided
        maneuver's summary is computed (a live run: a thread, so that its fits never hold up reading); its record goes
        to the sinks, in order, with the first record processed after it is ready (its log time then); without one,
        at once (replay, import: the log time of the record that decided it). hold_output (an executor in another
        process): its record goes to the sinks as it would at once, their later calls held until it is in (sinks.held).
        fast_slip=False: no /slip/fast rows (a pass that keeps none: the first; SlipEstimator's fast_rows).
        wheel_estimates=False: estimates without their wheels (a pass whose sinks take no estimate: the first;
        SlipEstimator's wheels)."""
        self.config = config
        self.sinks = list(sinks)
        self._out: Sink = SinkFanout(self.sinks)
        self._fanout = self._out
        """Every sink, called once per record (the one dispatch); _out: it or, behind a maneuver not in yet, _hold."""
        self.wheels = WheelDecoder(config)
        self.nmea = NmeaDecoder()
        self.ubx = UbxDecoder()
        self.sensors = SignalDecoder(config)
        self.xbus = MtiAccel(config.imu)
        """An Xsens MTi on a serial port ([imu] source = "serial"): its forward acceleration, as the CAN IMU's, at its own
        sample time placed on the host's clock."""
        self._marks_brake = config.brake.source == "gps-timemark"
        self._velocity_from: type | tuple[()] = () if config.gps.source == "can" else \
            NmeaLine if config.gps.velocity == "nmea" else UbxFrame
        """The raw records whose fixes are the reference speed (none: it comes from CAN)."""
        self.estimator = SlipEstimator(EstimatorParams.from_config(config), calibration, frozen, fast_rows=fast_slip,
                                       wheels=wheel_estimates)
        self.maneuvers = ManeuverDetector(config, phases=MANEUVER_KINDS if maneuvers else ())
        self._detect = maneuvers
        """Decides each accelerate or brake maneuver as it ends (the report's rule); sinks get its /maneuver record."""
        self.coasts = CoastDetector(config)
        """Decides each coast-down as it ends: the estimator gets its road loads (for the calibration), the sinks its
        /maneuver record (unless maneuvers=False)."""
        self._coast_records = maneuvers
        self.maneuver_count = 0
        self.test_sets = TestSets(config.test)
        """The test's procedures' sets, fed each /maneuver record; sinks get a set's /test_set record after each."""
        self._executor = maneuver_executor
        self._summaries: deque[Future[Maneuver]] = deque()
        """Maneuvers being summarized on the executor (no hold_output), in the order they were decided."""
        self._hold = HeldCalls(self._fanout) if hold_output and maneuver_executor is not None else None
        self._gps_speeds = gps_speeds
        self.fixes = 0
        self.valid_fixes = 0
        """... of them marked valid (an RMC status A, a UBX fix OK, a valid reference frame)."""
        """GPS fixes of the protocol gps.velocity names, so far."""
        self.can_frames = 0
        self.unknown_frames = 0
        self.error_frames = 0
        self.estimates = 0
        self.last_time_s: float | None = None
        self._next_diag_s: float | None = None
        self._ahead = _Decoded.NONE

    def waiting_for_wheels(self) -> bool:
        """An estimate waits only for wheel frames (a live CAN reader that pauses between reads should read now)."""
        return self.estimator.waiting_for_wheels()

    def process(self, record: RawRecord) -> None:
        """One raw record through decode and estimator to every sink (a CAN frame is a batch of one)."""
        if isinstance(record, CanFrame):
            self.process_can_batch(CanFrameBatch.from_frames([record]))
            return
        self._out.on_raw(record)
        if isinstance(record, RtcmFrame):  # corrections for the receiver, logged, not decoded
            self._tick(record.timestamp_s)
            return
        if isinstance(record, XbusBytes):
            sample = self.xbus.sample(record)
            if sample is not None:
                self._sensor(SensorSample(sample[0], "imu_accel", sample[1]))
            self._tick(record.timestamp_s)
            return
        fix: GpsFix | None = self.nmea.decode(record) if isinstance(record, NmeaLine) else self.ubx.decode(record)
        if fix is not None and isinstance(record, self._velocity_from):  # else gps.velocity names the other protocol
            self._fix(fix, record.timestamp_s)
        elif self._marks_brake and isinstance(record, UbxFrame) and self.ubx.is_time_mark(record):
            self._time_mark(self.ubx.time_mark(record))
        self._tick(record.timestamp_s)

    def _time_mark(self, mark: TimeMark | None) -> None:
        """A TIM-TM2 time mark: its new edge of the brake's press ([brake] edge), valid and in GNSS or UTC time, placed
        on the host's clock as a fix's UTC time is, is a brake_mark sample (dropped before the first fix with UTC)."""
        if mark is None or not mark.valid:
            return
        rising = self.config.brake.edge == "rising"
        utc_s, new = (mark.rising_utc_s, mark.new_rising) if rising else (mark.falling_utc_s, mark.new_falling)
        host_s = self.estimator.host_time_s(utc_s) if new and utc_s is not None else None
        if host_s is not None:
            self._sensor(SensorSample(host_s, BRAKE_MARK, 1.0))

    def _fix(self, fix: GpsFix, log_time_s: float) -> None:
        """A reference-speed fix (GPS on the serial port, or the reference on CAN) to the sinks and the estimator."""
        self._out.on_fix(fix)
        if self._gps_speeds is not None and self.fixes < len(self._gps_speeds):
            fix = replace(fix, speed_mps=self._gps_speeds[self.fixes])
        self.fixes += 1
        self.valid_fixes += bool(fix.valid)
        if fix.valid and fix.course_deg is not None and fix.speed_mps >= COURSE_MIN_SPEED_MPS:
            self.xbus.course_deg = fix.course_deg  # the heading of an MTi's FreeAcceleration without orientation
        self.coasts.add_course(fix.timestamp_s, fix.course_deg)
        for e in self.estimator.add_gps(fix):
            self._estimate(e, log_time_s)
        if self.estimator.events:
            self._events()
        if self.estimator.fast_rows:
            rows = self.estimator.take_fast()
            self._out.on_fast_slip_rows(rows, log_time_s)
            if self._detect:
                self._maneuvers(self.maneuvers.add_fast(rows), log_time_s)

    def _sensor(self, sample: SensorSample) -> None:
        self._out.on_sensor(sample)
        if sample.kind == "brake":
            if self._detect:
                self.maneuvers.add_brake(sample.time_s, sample.value)
            self.coasts.add_brake(sample.time_s, sample.value)
        elif sample.kind == BRAKE_MARK:
            if self._detect:
                self.maneuvers.add_brake_mark(sample.time_s)
        elif sample.kind == "imu_accel":
            self.estimator.add_imu(sample.time_s, sample.value, self.xbus.source)
        elif sample.kind == "reference_speed":
            self._fix(GpsFix(sample.time_s, sample.value, None, sample.valid, sentence="CAN",
                             speed_accuracy_mps=sample.accuracy), sample.time_s)

    def _events(self) -> None:
        """The estimator's events (a stored calibration value replaced) to every sink."""
        for ev in self.estimator.take_events():
            self._out.on_source_event(ev)

    def process_can_batch(self, frames: CanFrameBatch | Sequence[CanFrame]) -> None:
        """Consecutive CAN frames (a reader's wake-up, a block of a log): the same sink calls, estimates and counters
        however the frames are cut into batches."""
        batch = frames if isinstance(frames, CanFrameBatch) else CanFrameBatch.from_frames(frames)
        self._process_run(batch, _Parts([batch]))

    def process_all(self, items: Sequence[RawRecord | CanFrameBatch | Sequence[CanFrame]]) -> None:
        """process_can_batch for each batch of CAN frames (a CanFrameBatch or a list of CanFrames) and process for
        each other record, in turn. Consecutive batches are estimated as one (up to MERGE_MAX_FRAMES) and the wheel
        frames are decoded ahead, past GPS records, up to where the next diagnostics snapshot falls due (the decoder
        does not depend on GPS): numpy's fixed cost is paid once for many. The sinks get the batches as they came."""
        queue: list[CanFrameBatch | NmeaLine | UbxFrame | XbusBytes | RtcmFrame] = [
            x if isinstance(x, CanFrameBatch | NmeaLine | UbxFrame | XbusBytes | RtcmFrame)
            else CanFrameBatch.from_frames([x] if isinstance(x, CanFrame) else x) for x in items]
        run: list[CanFrameBatch] = []
        frames = 0

        def flush() -> None:
            nonlocal frames
            if run:
                self._process_run(run[0] if len(run) == 1 else CanFrameBatch.concat(run), _Parts(list(run)))
                run.clear()
                frames = 0

        try:
            for k, item in enumerate(queue):
                if isinstance(item, CanFrameBatch):
                    if len(item) == 0:
                        continue
                    ahead = self._ahead
                    if frames + len(item) > MERGE_MAX_FRAMES or (
                            run and ahead.contains(self.can_frames) and not ahead.contains(self.can_frames + frames)):
                        flush()  # no segment of a run begins in the frames decoded ahead and ends past them
                    if not run and not self._ahead.contains(self.can_frames):
                        self._ahead = self._decode_ahead(queue, k)
                    run.append(item)
                    frames += len(item)
                else:
                    flush()
                    self.process(item)
            flush()
        finally:
            self._ahead = _Decoded.NONE

    def _decode_ahead(self, queue: list[CanFrameBatch | NmeaLine | UbxFrame | XbusBytes | RtcmFrame], k: int) -> _Decoded:
        """The wheel frames of queue[k:] decoded at once, up to the record that makes the next diagnostics snapshot
        due (its counters are the decoder's as of that record) or MERGE_MAX_FRAMES."""
        due = self._next_diag_s
        if due is None:
            return _Decoded.NONE
        parts: list[CanFrameBatch] = []
        n = 0
        for it in queue[k:]:
            if isinstance(it, CanFrameBatch):
                hit = np.flatnonzero(it.timestamp_s >= due)
                if len(hit):
                    parts.append(it.slice(0, int(hit[0]) + 1))
                    break
                parts.append(it)
                n += len(it)
                if n >= MERGE_MAX_FRAMES:
                    break
            elif it.timestamp_s >= due:
                break
        if not parts:
            return _Decoded.NONE
        batch = parts[0] if len(parts) == 1 else CanFrameBatch.concat(parts)
        which = self.wheels.wheel_frames(batch)
        return _Decoded(self.can_frames, which, self.wheels.decode_batch(batch, which))

    def _process_run(self, batch: CanFrameBatch, parts: _Parts) -> None:
        """The run's frames in segments that end where a diagnostics snapshot falls due."""
        n = len(batch)
        ts = batch.timestamp_s
        start = 0
        while start < n:
            if self._next_diag_s is None:
                stop = start + 1
            else:
                due = ts[start:] >= self._next_diag_s
                stop = start + int(due.argmax()) + 1 if due.any() else n  # argmax: the first True
            self._can_segment(batch if (start, stop) == (0, n) else batch.slice(start, stop), parts, start)
            start = stop

    def _can_segment(self, batch: CanFrameBatch, parts: _Parts, offset: int) -> None:
        """Frames of which at most the last may make a diagnostics snapshot due (frame k of batch is frame
        offset + k of the run that `parts` cut)."""
        n = len(batch)
        which, samples = self._segment_samples(batch)
        self.can_frames += n
        error = (batch.flags & FLAG_ERROR) != 0
        self.error_frames += int(np.count_nonzero(error))
        unknown = ~error & (which < 0)
        sensed: list[tuple[int, SensorSample]] = []
        if self.sensors:
            frames = self.sensors.sensor_frames(batch)
            unknown[frames] = False
            sensed = self.sensors.decode(batch, frames)
        self.unknown_frames += int(np.count_nonzero(unknown))
        # the sinks get the frames and samples up to the frame that released an estimate (or carried a sensor's
        # value), then the estimate (the value): the order of frames one by one
        ts = batch.timestamp_s
        start = pos = 0  # frames delivered, samples given to the estimator

        def wheels_up_to(stop_sample: int) -> None:
            nonlocal start, pos
            if stop_sample <= pos:
                return
            released = self.estimator.add_wheels(samples.wheel[pos:stop_sample], samples.timestamp_s[pos:stop_sample],
                                                 samples.revolutions[pos:stop_sample])
            for i, e in released:
                stop = int(samples.frame[pos + i]) + 1
                if stop > start:
                    self._deliver(parts, samples, offset, start, stop)
                    start = stop
                self._estimate(e, float(ts[stop - 1]))
            pos = stop_sample

        for f, sample in sensed:
            wheels_up_to(int(samples.frame.searchsorted(f, side="right")))
            if f + 1 > start:
                self._deliver(parts, samples, offset, start, f + 1)
                start = f + 1
            self._sensor(sample)
        wheels_up_to(len(samples))
        if start < n:
            self._deliver(parts, samples, offset, start, n)
        if self.estimator.events:
            self._events()
        self._tick(float(ts[-1]))

    def _segment_samples(self, batch: CanFrameBatch) -> tuple[np.ndarray, WheelSampleBatch]:
        """The segment's wheel frames and samples (WheelDecoder's wheel_frames, decode_batch): decoded ahead, or now."""
        if self._ahead.contains(self.can_frames):
            assert self._ahead.covers(self.can_frames, len(batch)), "a segment beyond the frames decoded ahead"
            return self._ahead.take(self.can_frames, len(batch))
        which = self.wheels.wheel_frames(batch)
        return which, self.wheels.decode_batch(batch, which)

    def _estimate(self, e: Estimate, log_time_s: float) -> None:
        self.estimates += 1
        self._out.on_estimate(e, log_time_s)
        if self._detect:
            self._maneuvers(self.maneuvers.add_estimate(e.as_row()), log_time_s)
        coast = self.coasts.add(e.time_s, e.speed_mps, e.source)
        if coast is not None:
            self._coast(coast, log_time_s)

    def _coast(self, run: CoastRun, log_time_s: float) -> None:
        """A coast decided: its road loads to the estimator (for the calibration, when paired) and its record to the
        sinks, in order with the maneuvers decided before it."""
        if run.runs_paired:
            self.estimator.road_loads_measured(RoadLoads(*run.loads), run.runs_paired)
        if not self._coast_records:
            return
        self.maneuver_count += 1
        record = coast_record(run, self.maneuver_count, self.maneuvers.t0_s or 0.0, WHEELS, self.config.test)
        self._pending(ready(record), log_time_s) if self._executor else self._deliver_maneuver(record, log_time_s)

    def _maneuvers(self, jobs: list[Job], log_time_s: float, at_once: bool = False) -> None:
        """The maneuvers decided now, numbered in turn, to every sink at this log time (an executor's: _pending)."""
        for job in jobs:
            self.maneuver_count += 1
            if self._executor is None or at_once:
                self._deliver_maneuver(job.record(self.maneuver_count), log_time_s)
            else:
                self._pending(self._executor.submit(job.record, self.maneuver_count), log_time_s)

    def _pending(self, record: Future[Maneuver], log_time_s: float) -> None:
        """A maneuver's record on its way: delivered here with hold_output (later calls held till then), else when in."""
        if self._hold is None:
            self._summaries.append(record)
        elif self._out is self._fanout and record.done():
            self._deliver_maneuver(record.result(), log_time_s)
        else:
            self._out = self._hold
            self._hold.mark(record, lambda m: self._deliver_maneuver(m, log_time_s))

    def _summarized(self, log_time_s: float, wait: bool = False) -> None:
        """The maneuvers whose summaries the executor has finished (wait: all), in order, at this log time."""
        while self._summaries and (wait or self._summaries[0].done()):
            self._deliver_maneuver(self._summaries.popleft().result(), log_time_s)

    def _deliver_maneuver(self, record: Maneuver, log_time_s: float) -> None:
        self._fanout.on_maneuver(record, log_time_s)
        test_set = self.test_sets.add(record)
        if test_set is not None:
            self._fanout.on_test_set(test_set, log_time_s)

    def _tick(self, t: float) -> None:
        """The newest record's time: a diagnostics snapshot every DIAGNOSTICS_PERIOD_S of log time."""
        self.last_time_s = t
        if self._out is self._hold and self._hold.release(len(self._hold) > HOLD_MAX_CALLS):
            self._out = self._fanout  # the calls held behind maneuvers now in (over HOLD_MAX_CALLS: waited for)
        elif self._summaries:
            self._summarized(t)
        if self._next_diag_s is None:
            self._next_diag_s = t + DIAGNOSTICS_PERIOD_S
        elif t >= self._next_diag_s:
            self.emit_diagnostics()
            self._next_diag_s = t + DIAGNOSTICS_PERIOD_S

    def _deliver(self, parts: _Parts, samples: WheelSampleBatch, offset: int, start: int, stop: int) -> None:
        """Frames start..stop of the segment (at offset in the run) and their samples to the sinks, in the batches
        the frames came in."""
        for a, b, piece in parts.pieces(offset + start, offset + stop):
            self._out.on_can_batch(piece)
            if not len(samples):
                continue
            mine = samples.of_frames(a - offset, b - offset)
            if len(mine):
                self._out.on_wheel_batch(mine)

    def run(self, records: Iterable[RawRecord]) -> None:
        for r in records:
            self.process(r)
        self.finish()

    def finish(self) -> None:
        """The maneuver still open decided, and a last diagnostics snapshot, so that the log ends with the final
        counters."""
        if (t := self.last_time_s) is None:
            return
        self._summarized(t, wait=True)  # on a thread: those in flight, then the last ones at once
        self._maneuvers(self.maneuvers.finish() if self._detect else [], t, at_once=self._hold is None)
        if self._hold is not None:
            self._hold.release_all()
            self._out = self._fanout
        self.emit_diagnostics()

    def diagnostics(self) -> Diagnostics:
        return Diagnostics(
            time_s=self.last_time_s or 0.0,
            can_frames=self.can_frames,
            wpt_frames=self.wheels.frames,
            lost_frames=self.wheels.lost_frames,
            count_wraps=self.wheels.count_wraps,
            counter_resets=self.wheels.counter_resets,
            unknown_frames=self.unknown_frames,
            error_frames=self.error_frames,
            bad_frames=self.wheels.bad_frames + self.sensors.bad_frames,
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
        self._out.on_diagnostics(d, d["time_s"])  # type: ignore[arg-type]  # Diagnostics.as_dict's time_s is a float
