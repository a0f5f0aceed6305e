"""Sinks: where the pipeline's output goes (MCAP log, live status view, CSV export)."""

from __future__ import annotations

from typing import Protocol

from slipdaq.records import Estimate, GpsFix, RawRecord, WheelSample


class Sink(Protocol):
    """What the pipeline calls, in record order (the python-can Listener idea)."""

    def on_raw(self, record: RawRecord) -> None: ...
    def on_wheel(self, sample: WheelSample) -> None: ...
    def on_fix(self, fix: GpsFix) -> None: ...
    def on_estimate(self, estimate: Estimate, log_time_s: float) -> None: ...
    def on_diagnostics(self, diagnostics: dict[str, object], log_time_s: float) -> None: ...


class CollectingSink:
    """Keeps everything in lists (replay into memory, tests)."""

    def __init__(self) -> None:
        self.raw: list[RawRecord] = []
        self.wheels: list[WheelSample] = []
        self.fixes: list[GpsFix] = []
        self.estimates: list[Estimate] = []
        self.diagnostics: list[dict[str, object]] = []

    def on_raw(self, record: RawRecord) -> None:
        self.raw.append(record)

    def on_wheel(self, sample: WheelSample) -> None:
        self.wheels.append(sample)

    def on_fix(self, fix: GpsFix) -> None:
        self.fixes.append(fix)

    def on_estimate(self, estimate: Estimate, log_time_s: float) -> None:
        self.estimates.append(estimate)

    def on_diagnostics(self, diagnostics: dict[str, object], log_time_s: float) -> None:
        self.diagnostics.append(diagnostics)
