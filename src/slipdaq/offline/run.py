"""Offline runs (import, replay, report): a record stream through the pipeline into sinks (a new MCAP log), with
progress; the first pass of a two-pass run."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from slipdaq import WHEELS, compiled
from slipdaq.config import Config
from slipdaq.config.calibration import Calibration, Learned, merged, parse_calibration, to_toml
from slipdaq.estimator.force import driven_wheels
from slipdaq.estimator.gps_track import MAX_GPS_GAP_S, smooth_arrival_times
from slipdaq.maneuver.figures import ManeuverSummary
from slipdaq.offline.decoder_tape import DecoderTape
from slipdaq.offline.first_pass_feed import FedPasses, fed_whole
from slipdaq.offline.items import BATCH_FRAMES, batched, items_of, read_ahead
from slipdaq.offline.log_process import LogProcess
from slipdaq.offline.read_once import ReadOnce
from slipdaq.offline.summaries import DetectorFeed, SummaryProcess, worth_a_process
from slipdaq.pipeline import Pipeline
from slipdaq.records import (
    CanFrame,
    CanFrameBatch,
    Estimate,
    FastSlip,
    GpsFix,
    RawRecord,
    SensorSample,
    WheelSampleBatch,
)
from slipdaq.records.fast_rows import FastRows, FastSlipBatch
from slipdaq.sinks import Sink
from slipdaq.sinks.mcap_log import McapLogSink


def frame_runs(items: Iterable[RawRecord | CanFrameBatch]) -> Iterator[RawRecord | CanFrameBatch]:
    """Consecutive CanFrameBatches (a reader's slices of a log, merge_by_time's) cut as batched() cuts the same frames
    one by one: a piece every BATCH_FRAMES frames from each run's start, each naming only its own frames' channels,
    in the order they come; everything else as it comes. The log then gets the same batches (and a new channel at
    the same place) as from a reader of single frames."""
    parts: list[CanFrameBatch] = []
    n = 0
    for item in items:
        if not isinstance(item, CanFrameBatch):
            if parts:
                yield _piece(parts)
                parts, n = [], 0
            yield item
            continue
        pos = 0
        while pos < len(item):
            take = min(BATCH_FRAMES - n, len(item) - pos)
            parts.append(item if take == len(item) else item.slice(pos, pos + take))
            n += take
            pos += take
            if n == BATCH_FRAMES:
                yield _piece(parts)
                parts, n = [], 0
    if parts:
        yield _piece(parts)


def _piece(parts: list[CanFrameBatch]) -> CanFrameBatch:
    """The parts as one batch naming only its frames' channels (in order of appearance), payloads as wide as its
    widest (at least 8 bytes), as CanFrameBatch.from_frames makes it."""
    b = parts[0] if len(parts) == 1 else CanFrameBatch.concat(parts)
    if len(b.channels) > 1:
        codes, first = np.unique(b.channel, return_index=True)
        order = codes[np.argsort(first)]
        if order.tolist() != list(range(len(b.channels))):
            lut = np.zeros(len(b.channels), dtype=np.uint16)
            lut[order] = np.arange(len(order), dtype=np.uint16)
            b = dataclasses.replace(b, channel=lut[b.channel], channels=tuple(b.channels[i] for i in order.tolist()))
    if b.data.shape[1] > 8:
        width = max(8, int(b.payload_lengths().max()))
        if width < b.data.shape[1]:
            b = dataclasses.replace(b, data=b.data[:, :width])
    return b


def process(
    config: Config,
    records: Iterable[RawRecord | CanFrameBatch | list[CanFrame]],
    sinks: list[Sink],
    *,
    calibration: Calibration | None = None,
    frozen: bool = False,
    gps_speeds: Sequence[float] | None = None,
    total: int | None = None,
    stream: TextIO | None = None,
    description: str = "",
    maneuvers: bool = True,
    fast_slip: bool = True,
    wheel_estimates: bool = True,
    summaries: Executor | None = None,
    tape: DecoderTape | None = None,
) -> Pipeline:
    """Every record through a fresh pipeline into the sinks (Pipeline's calibration, frozen, gps_speeds); shows
    progress on a terminal, a line every 5 s otherwise. maneuvers=False: the pipeline summarizes no maneuver (a pass
    whose sinks take no /maneuver record: the first pass, the report's rows, which decides its own). fast_slip=False:
    no /slip/fast rows (the first pass). wheel_estimates=False: estimates without their wheels (the first pass: its
    sinks take none). summaries: where the maneuvers' summaries are computed (a SummaryProcess),
    the sinks' calls after each held back until it is in: the same calls as without. tape: the wheel and NMEA
    decoders' outputs recorded (a first pass) or played back (the second: DecoderTape.attach).

    records: raw records and batches of CAN frames (iter_raw_batches); runs of CanFrames are batched here. The
    estimates are the same whatever the batches (Pipeline.process_can_batch)."""
    stream = stream or sys.stderr
    pipeline = Pipeline(config, sinks, calibration=calibration, frozen=frozen, gps_speeds=gps_speeds,
                        maneuvers=maneuvers, fast_slip=fast_slip, wheel_estimates=wheel_estimates,
                        maneuver_executor=summaries, hold_output=True)
    if tape is not None:
        tape.attach(pipeline)
    compiled.prepare()
    if stream.isatty():
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        with Progress(
            TextColumn(description), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(), transient=True,
        ) as bar:
            task = bar.add_task(description, total=total)
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
                print(f"{description}: {done} messages", file=stream, flush=True)
    pipeline.finish()
    return pipeline


def process_to_log(
    config: Config,
    records: Iterable[Any],
    out_path: Path,
    mode: str,
    *,
    metadata: dict[str, str] | None = None,
    decode: Callable[[Iterable[Any]], Iterable[RawRecord | CanFrameBatch]] | None = None,
    apart: LogProcess | None = None,
    **options: Any,
) -> Pipeline:
    """process() (its keyword options; the description defaults to the mode) into a new MCAP log at out_path; the
    calibration it started from is stored in the log's metadata (calibration_toml), so that a replay of the log
    starts from it too. A run of a known total of at least summaries.MIN_RAW_RECORDS records summarizes its
    maneuvers in a second process (forked before the log's writer starts its thread), and, given decode (records
    are then the input's pieces, a replay's raw messages, and decode(records) its records), writes its log in a
    process of its own (log_process.LogProcess, forked first), which takes the pieces from the run: the same
    bytes. apart: the log's process forked already, which reads the input itself (log_process_for with read; records
    are then the input's items, decoded already), and which the caller closes."""
    calibration = options.get("calibration")
    meta = (metadata or {}) | {"calibration_toml": to_toml(calibration) if calibration is not None else ""}
    beside = worth_a_process(options.get("total"))
    with contextlib.ExitStack() as stack:
        if apart is None and decode is not None and beside:
            apart = stack.enter_context(log_process_for(config, out_path, mode, decode))
        summaries = stack.enter_context(SummaryProcess()) if beside and options.get("maneuvers", True) else None
        if apart is not None:
            apart.begin(metadata=meta)
        sink = apart or McapLogSink(out_path, config, mode=mode, metadata=meta)
        items: Iterable[Any]
        if apart is not None and not apart.reads_itself:
            items = apart.input(records)
        elif decode is not None and apart is None:
            items = decode(records)
        else:  # records as they are, or the input's items for a log's process that reads the input itself
            items = records
        try:
            return process(config, items, [sink], **({"description": mode, "summaries": summaries} | options))
        finally:
            if apart is None:
                sink.close()


def log_process_for(config: Config, out_path: Path, mode: str,
                    decode: Callable[[Iterable[Any]], Iterable[RawRecord | CanFrameBatch]],
                    read: Callable[[], Iterable[Any]] | None = None, **feed: Any) -> LogProcess:
    """The process that writes process_to_log's log at out_path (LogProcess), its input's pieces decoded by decode;
    read: the pieces, which it reads itself, ahead of the run's first call (feed, feed_end: LogProcess's)."""
    return LogProcess(functools.partial(McapLogSink, out_path, config, mode=mode), items_of(decode), config, read,
                      **feed)


def replay_two_pass(config: Config, log: str | Path, out_path: Path, start: Calibration | None, *,
                    metadata: dict[str, str], total: int | None, scanned: Any = None) -> tuple[Pipeline, FirstPass]:
    """`replay --two-pass` of a log into a new log at out_path: the first pass (first_pass), then the second into the
    log (process_to_log), the input read and decoded once (ReadOnce, its decoders' tape). Where the run is worth a
    log's process (summaries.worth_a_process), it is forked before the first pass and reads and decodes the log
    itself meanwhile, on the core the first pass leaves idle; the run then sends it no input. A log fed whole
    (first_pass_feed.fed_whole): that process feeds the first pass the items and the decoders' calls (LogProcess.fed),
    and the scan comes back with them. A finished log too long for that: its first pass fed by a process of its own
    (first_pass_feed.FedPasses.forked), the second pass reading and decoding the log itself. scanned: the
    logformat.salvage.ScanResult the first read fills."""
    from slipdaq.logformat.reader import data_bytes, iter_raw_messages

    decode = log_decoder(log)
    read: ReadOnce | FedPasses = ReadOnce(lambda scan: iter_raw_messages(log, scanned if scan else None), items_of(decode))
    with contextlib.ExitStack() as stack:
        apart = None
        if worth_a_process(total):
            feed = fed_whole(log)
            if not feed and data_bytes(log) is not None:  # finished, too long to keep: a feed of its own, the second
                # pass reading the log itself (the other core then runs the log's process and the summaries)
                read = stack.enter_context(FedPasses.forked(
                    config, functools.partial(iter_raw_messages, log, scanned), items_of(decode), False,
                    read_again=functools.partial(iter_raw_messages, log), end=lambda: scanned))
            apart = stack.enter_context(log_process_for(config, out_path, "replay", decode,
                                                        functools.partial(iter_raw_messages, log, scanned if feed else None),
                                                        feed=feed, feed_end=lambda: scanned))
            if feed:
                fed_by = apart
                read = FedPasses(fed_by.fed, end=lambda: fed_by.fed_end)
        first = first_pass(config, read.first(), start, str(log), total=total, tape=read.tape)
        made_there = read.fed_end() if isinstance(read, FedPasses) else None
        if made_there is not None and scanned is not None:  # the scan made where the log was read
            vars(scanned).update(vars(made_there))
        p = process_to_log(config, read.second(), out_path, "replay", metadata=metadata, total=total, apart=apart,
                           tape=read.tape, **first.second_pass())
    return p, first


class _FirstPassSink(Sink):
    """The GPS fixes and the given wheels' samples (the reference speed's: the non-driven wheels) of the first pass
    (all it keeps: no raw record, estimate, high-rate slip row or diagnostics, no other wheel's sample)."""

    def __init__(self, wheels: Sequence[str] = WHEELS) -> None:
        self.fixes: list[GpsFix] = []
        self._index = {w: WHEELS.index(w) for w in wheels}
        self._time: dict[str, list[np.ndarray]] = {w: [] for w in wheels}
        self._revs: dict[str, list[np.ndarray]] = {w: [] for w in wheels}

    def on_fix(self, fix: GpsFix) -> None:
        self.fixes.append(fix)

    def on_wheel_batch(self, samples: WheelSampleBatch) -> None:
        for w, i in self._index.items():
            mine = samples.wheel == i
            self._time[w].append(samples.timestamp_s[mine])
            self._revs[w].append(samples.revolutions[mine])

    def wheel_series(self, wheel: str) -> tuple[np.ndarray, np.ndarray]:
        """One kept wheel's (sample times, revolutions), in time order."""
        if not self._time[wheel]:
            return np.empty(0), np.empty(0)
        t, r = np.concatenate(self._time[wheel]), np.concatenate(self._revs[wheel])
        if bool((t[1:] > t[:-1]).all()):  # every sample later than the one before: all count
            return t, r
        # a sample counts when it is later than every one before it, as the estimator keeps them (readiness.py)
        keep = t > np.concatenate(([-np.inf], np.maximum.accumulate(t)[:-1]))
        return t[keep], r[keep]


@dataclass(frozen=True)
class FirstPass:
    """What the first pass of a two-pass run learned over the whole log."""

    learned: Learned
    calibration: Calibration
    """The calibration the second pass uses: the one the run started from, with what the first pass learned."""
    gps_speeds: list[float]
    """Per GPS fix, in order, the speed the second pass takes (estimator/reference_speed.py)."""

    def second_pass(self) -> dict[str, Any]:
        """process()'s options for the second pass: this calibration held fixed, these speeds."""
        return {"calibration": self.calibration, "frozen": True, "gps_speeds": self.gps_speeds,
                "description": "pass 2 of 2"}


def log_decoder(log: str | Path) -> Callable[[Iterable[Any]], Iterator[RawRecord | CanFrameBatch]]:
    """A log's raw messages (reader.iter_raw_messages) to its records (reader.raw_batches), an error in reading or
    decoding them one InputError naming the log (sources.read_errors.guarded)."""
    from slipdaq.logformat.reader import raw_batches
    from slipdaq.sources.read_errors import guarded

    return lambda messages: guarded(log, raw_batches(messages))


def first_pass(config: Config, records: Iterable[RawRecord | CanFrameBatch | list[CanFrame]], start: Calibration | None,
               learned_from: str, *, total: int | None = None, stream: TextIO | None = None,
               tape: DecoderTape | None = None) -> FirstPass:
    """Learn the calibration over the whole log (latency, r0, Cx) and the run's reference speed at each fix. What
    only the second pass keeps is not made: no maneuver summarized, no high-rate slip row, no wheel's estimate,
    nothing written."""
    seen = _FirstPassSink(reference_wheels(config))
    p = process(config, records, [seen], calibration=start, total=total, stream=stream, description="pass 1 of 2",
                maneuvers=False, fast_slip=False, wheel_estimates=False, tape=tape)
    learned = p.estimator.learned()
    calibration = merged(start, learned, config, learned_from)
    return FirstPass(learned, calibration, smoothed_gps_speeds(seen, calibration, config))


def reference_wheels(config: Config) -> list[str]:
    """The wheels whose speed shapes the reference speed: the non-driven ones."""
    return [w for w in WHEELS if w not in driven_wheels(config.vehicle.driven_axle)]


def smoothed_gps_speeds(seen: _FirstPassSink, calibration: Calibration, config: Config) -> list[float]:
    """Each fix's speed smoothed over the run (reference_speed_mps), where the fixes are valid, finite and in time
    order, on the estimator's time line (smooth_arrival_times with the run's median offset of arrival from UTC,
    minus the latency); the others' speeds as they are."""
    # imported here: its kernels are loaded (compiled.prepare) by two-pass runs only
    from slipdaq.estimator.reference_speed import reference_speed_mps, wheel_speed_mps

    fixes = seen.fixes
    speeds = [f.speed_mps for f in fixes]
    arrival = np.array([f.timestamp_s for f in fixes])
    utc = np.array([math.nan if f.fix_time_utc_s is None else f.fix_time_utc_s for f in fixes])
    offsets = (arrival - utc)[np.isfinite(arrival - utc)]
    times = smooth_arrival_times(arrival, utc, float(np.median(offsets)) if len(offsets) else None)
    fixed = config.latency_fixed_s
    times = times - (fixed if fixed is not None else calibration.latency.latency_s if calibration.latency else 0.0)
    use: list[int] = []
    last = -math.inf
    for i, (t, f) in enumerate(zip(times.tolist(), fixes)):
        if f.valid and math.isfinite(f.speed_mps) and t > last:
            use.append(i)
            last = t
    if len(use) < 3:
        return speeds
    t_use = times[use]
    acc = np.array([math.nan if (a := fixes[i].speed_accuracy_mps) is None else a for i in use])
    reference = reference_wheels(config)
    wheel = None
    if reference:
        radius = [calibration.r0[w].radius_m if w in calibration.r0 else config.tire.radius_m
                  for w in reference]
        wheel = np.mean([wheel_speed_mps(t_use, *seen.wheel_series(w), r) for w, r in zip(reference, radius)], axis=0)
    smooth = reference_speed_mps(t_use, np.array([speeds[i] for i in use]), wheel,
                                 acc if np.isfinite(acc).any() else None, max_gap_s=MAX_GPS_GAP_S)
    for i, v in zip(use, smooth.tolist()):
        speeds[i] = max(v, 0.0)
    return speeds


def start_calibration(metadata: dict[str, str], log: str | Path) -> Calibration | None:
    """The calibration a logged run started from (its metadata's calibration_toml; none in a log from before it)."""
    text = metadata.get("calibration_toml", "")
    return parse_calibration(text, f"{log}: calibration_toml") if text else None


class Rows(Sink):
    """The estimates as the log's rows, the high-rate slip rows (as columns: a sequence of the log's rows), the sensor
    samples (as the log's JSON), and the last diagnostics; feed: each also to a DetectorFeed (its maneuvers decided as
    the rows come)."""

    def __init__(self, feed: DetectorFeed | None = None) -> None:
        self.rows: list[dict[str, Any]] = []
        self.fast = FastRows()
        self.sensors: list[dict[str, Any]] = []
        self.diagnostics: dict[str, Any] | None = None
        self.feed = feed
        self.maneuvers: list[ManeuverSummary] | None = None
        """The feed's maneuvers (report.summary.detect_maneuvers over the rows), once the pass is over."""

    def on_estimate(self, estimate: Estimate, log_time_s: float) -> None:
        self.rows.append(row := estimate.as_row())
        if self.feed is not None:
            self.feed.estimate(row)

    def on_fast_slip(self, row: FastSlip, log_time_s: float) -> None:
        self.on_fast_slip_rows(FastSlipBatch.of_rows([row], tuple(row.wheels)), log_time_s)

    def on_fast_slip_rows(self, rows: Sequence[FastSlip], log_time_s: float) -> None:
        batch = rows if isinstance(rows, FastSlipBatch) else FastSlipBatch.of_rows(rows, WHEELS)
        self.fast.add(batch)
        if self.feed is not None:
            self.feed.fast(batch)

    def on_sensor(self, sample: SensorSample) -> None:
        self.sensors.append(d := dataclasses.asdict(sample))
        if self.feed is not None:
            self.feed.sensor(d)

    def on_diagnostics(self, diagnostics: dict[str, object], log_time_s: float) -> None:
        self.diagnostics = diagnostics
        if self.feed is not None:
            self.feed.log_time(log_time_s)


def two_pass_rows(log: str | Path, *, stream: TextIO | None = None, maneuvers: bool = False) -> Rows | None:
    """A log's estimates (and high-rate slip) post-processed two-pass (as `replay --two-pass`, in memory), as its
    /estimate (/slip/fast, /can/sensors) rows, and the last diagnostics; None when the log has no raw records.
    maneuvers: with a log worth a second process (summaries.worth_a_process), its maneuvers decided and summarized
    beside the second pass (DetectorFeed; Rows.maneuvers), and its first pass fed by a process that reads and decodes
    the log (first_pass_feed.FedPasses)."""
    from slipdaq.logformat.reader import config_from_log, iter_raw_messages, raw_record_count, read_metadata

    config = config_from_log(log)
    start = start_calibration(read_metadata(log), log)
    total = raw_record_count(log)
    if total == 0:
        return None
    beside = maneuvers and worth_a_process(total)
    with contextlib.ExitStack() as stack:
        read: ReadOnce | FedPasses = ReadOnce(lambda _: iter_raw_messages(log), items_of(log_decoder(log)))
        if beside:  # the first pass fed by a process that reads the log (forked first), the maneuvers summarized beside
            read = stack.enter_context(FedPasses.forked(config, lambda: iter_raw_messages(log),
                                                        items_of(log_decoder(log)), fed_whole(log)))
        summaries = stack.enter_context(SummaryProcess()) if beside else None
        first = first_pass(config, read.first(), start, str(log), total=total, stream=stream, tape=read.tape)
        rows = Rows(DetectorFeed(config, summaries) if summaries is not None else None)
        p = process(config, read.second(), [rows], total=total, stream=stream, maneuvers=False, tape=read.tape,
                    **first.second_pass())
        if p.can_frames + p.nmea.lines + p.ubx.frames == 0:
            return None
        if rows.feed is not None:
            rows.maneuvers, rows.feed = rows.feed.finish(), None
    return rows
