"""Sinks: where the pipeline's output goes (MCAP log, live status view, CSV export)."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from types import TracebackType
from typing import Any

from slipdaq import WHEELS
from slipdaq.maneuver.record import Maneuver
from slipdaq.records import (
    CanFrameBatch,
    Estimate,
    FastSlip,
    GpsFix,
    RawRecord,
    SensorSample,
    SourceEvent,
    WheelSample,
    WheelSampleBatch,
)


class Sink:
    """What the pipeline calls, in record order (python-can's `Listener` model).

    Every method does nothing by default; a sink overrides what it takes. The batch methods default to a loop over
    their per-record method, so a sink that keeps records one by one overrides only those, and a sink that can take
    a whole batch at once (the MCAP log) overrides the batch method too. A sink that overrides neither pays nothing
    for the batch (no record is made of it)."""

    def on_raw(self, record: RawRecord) -> None:
        """One raw record: a CAN frame outside a batch, an NMEA line or a UBX frame."""

    def on_can_batch(self, batch: CanFrameBatch) -> None:
        if type(self).on_raw is Sink.on_raw:
            return
        for frame in batch.frames():
            self.on_raw(frame)

    def on_wheel(self, sample: WheelSample) -> None:
        """One decoded wheel sample."""

    def on_wheel_batch(self, samples: WheelSampleBatch) -> None:
        if type(self).on_wheel is Sink.on_wheel:
            return
        for sample in samples.samples(WHEELS):
            self.on_wheel(sample)

    def on_fix(self, fix: GpsFix) -> None:
        """One GPS fix of the protocol gps.velocity names."""

    def on_sensor(self, sample: SensorSample) -> None:
        """One value of the other sensors on CAN (reference speed, IMU, brake), decoded."""

    def on_estimate(self, estimate: Estimate, log_time_s: float) -> None:
        """One estimate, at the log time of the record that released it."""

    def on_fast_slip(self, row: FastSlip, log_time_s: float) -> None:
        """One high-rate slip row, at the log time of the record that released it."""

    def on_fast_slip_rows(self, rows: Sequence[FastSlip], log_time_s: float) -> None:
        """The high-rate slip rows one record released, in time order (the pipeline's: a FastSlipBatch, whose columns
        a sink may read as they are): on_fast_slip for each."""
        if type(self).on_fast_slip is Sink.on_fast_slip:
            return
        for row in rows:
            self.on_fast_slip(row, log_time_s)

    def on_maneuver(self, maneuver: Maneuver, log_time_s: float) -> None:
        """One maneuver's results, at the log time it was decided (its end and its span's high-rate rows came)."""

    def on_test_set(self, record: dict[str, Any], log_time_s: float) -> None:
        """A procedure's set after one of its maneuvers (its /test_set record, maneuver.test_set), at that time."""

    def on_diagnostics(self, diagnostics: dict[str, object], log_time_s: float) -> None:
        """The pipeline's counters, once a second of log time and at the end."""

    def on_source_event(self, event: SourceEvent) -> None:
        """A device or log event (live runs)."""

    def close(self) -> None:
        """Release what the sink holds (a file, a server); the default holds nothing. Safe to call twice."""

    def __enter__(self) -> Sink:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


SINK_CALLS: tuple[str, ...] = tuple(
    name for name, value in vars(Sink).items() if name.startswith("on_") and callable(value))
"""The calls a sink takes, in the order Sink declares them."""


def _fanned(name: str) -> Callable[..., None]:
    def call(self: SinkFanout, *args: Any) -> None:
        for method in self._calls[name]:
            method(*args)
    call.__name__ = call.__qualname__ = name
    call.__doc__ = f"{name} of every sink, in the order they were given."
    return call


class SinkFanout(Sink):
    """Every call to each of its sinks in turn (python-can's `Notifier` over its listeners): the pipeline's one
    dispatch. Each sink's bound methods are looked up once, when the fan-out is made; close() closes them all, in
    reverse order, each even when an earlier one raised (the first error is raised after)."""

    def __init__(self, sinks: Iterable[Sink]) -> None:
        self.sinks: tuple[Sink, ...] = tuple(sinks)
        self._calls: dict[str, tuple[Callable[..., None], ...]] = {
            name: tuple(getattr(s, name) for s in self.sinks) for name in SINK_CALLS}

    def close(self) -> None:
        first: BaseException | None = None
        for s in reversed(self.sinks):
            try:
                s.close()
            except Exception as e:  # every sink closed, whatever one of them raised
                first = first or e
        if first is not None:
            raise first


for _name in SINK_CALLS:
    setattr(SinkFanout, _name, _fanned(_name))



class EventFanout:
    """Passes each source event to every sink's on_source_event (a source's callback)."""

    def __init__(self, sinks: Iterable[Sink]) -> None:
        self._fanout = SinkFanout(sinks)

    def __call__(self, event: SourceEvent) -> None:
        self._fanout.on_source_event(event)


class CollectingSink(Sink):
    """Keeps everything in lists (replay into memory, tests)."""

    def __init__(self) -> None:
        self.raw: list[RawRecord] = []
        self.wheels: list[WheelSample] = []
        self.fixes: list[GpsFix] = []
        self.estimates: list[Estimate] = []
        self.fast: list[FastSlip] = []
        self.sensors: list[SensorSample] = []
        self.diagnostics: list[dict[str, object]] = []
        self.maneuvers: list[Maneuver] = []
        self.test_sets: list[dict[str, Any]] = []

    def on_raw(self, record: RawRecord) -> None:
        self.raw.append(record)

    def on_wheel(self, sample: WheelSample) -> None:
        self.wheels.append(sample)

    def on_fix(self, fix: GpsFix) -> None:
        self.fixes.append(fix)

    def on_estimate(self, estimate: Estimate, log_time_s: float) -> None:
        self.estimates.append(estimate)

    def on_fast_slip(self, row: FastSlip, log_time_s: float) -> None:
        self.fast.append(row)

    def on_sensor(self, sample: SensorSample) -> None:
        self.sensors.append(sample)

    def on_diagnostics(self, diagnostics: dict[str, object], log_time_s: float) -> None:
        self.diagnostics.append(diagnostics)

    def on_maneuver(self, maneuver: Maneuver, log_time_s: float) -> None:
        self.maneuvers.append(maneuver)

    def on_test_set(self, record: dict[str, Any], log_time_s: float) -> None:
        self.test_sets.append(record)
