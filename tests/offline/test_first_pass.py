"""The first pass of a two-pass run makes only what it keeps (offline.first_pass): no high-rate slip rows, nothing
for the maneuver detector, no wheel's estimate, no record for sinks that take none. It must learn exactly what a pass that makes
everything learns: the same estimates, calibration and events, also where a stored latency is dropped on the way
(the latency is brought up to date at each fix as making the high-rate rows does)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from slipdaq import WHEELS
from slipdaq.config import Config, load_config
from slipdaq.config.calibration import Learned, StoredLatency, merged
from slipdaq.offline.run import (
    _FirstPassSink,
    batched,
    first_pass,
    process,
    read_ahead,
    reference_wheels,
    smoothed_gps_speeds,
)
from slipdaq.pipeline import Pipeline
from slipdaq.records import Estimate, SourceEvent
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sinks import Sink
from support.paths import CONFIG


class _Kept(Sink):
    """The estimates (as rows), the events and how many high-rate rows came; no raw record or wheel sample."""

    def __init__(self) -> None:
        self.rows: list[dict[str, Any]] = []
        self.estimates: list[Estimate] = []
        self.events: list[SourceEvent] = []
        self.fast = 0

    def on_estimate(self, estimate: Estimate, log_time_s: float) -> None:
        self.rows.append(estimate.as_row() | {"log_time_s": log_time_s})
        self.estimates.append(estimate)

    def on_fast_slip_rows(self, rows: Any, log_time_s: float) -> None:
        self.fast += len(rows)

    def on_source_event(self, event: SourceEvent) -> None:
        self.events.append(event)


def _records(cfg: Config) -> list[Any]:
    return [ev.record for ev in generate(cfg, "cycle", "paved", SimSettings(seed=5), duration_s=40.0)
            if ev.record is not None]


def _run(cfg: Config, records: list[Any], start: Any, **options: bool) -> tuple[Pipeline, _Kept]:
    kept = _Kept()
    p = Pipeline(cfg, [kept], calibration=start, **options)
    for run in read_ahead(batched(records)):
        p.process_all(run)
    p.finish()
    return p, kept


@pytest.mark.parametrize("stored", ["none", "wrong latency"])
def test_the_first_pass_learns_what_a_full_pass_learns(stored: str) -> None:
    cfg = load_config(CONFIG)
    records = _records(cfg)
    start = None
    if stored == "wrong latency":  # contradicted by the run's own (UTC) latency: dropped, with an event, mid-run
        start = merged(None, Learned(latency=(0.3, 0.002, "wheels")), cfg, "an earlier drive", "2026-01-01T00:00:00Z")
        assert isinstance(start.latency, StoredLatency)
    full, everything = _run(cfg, records, start)
    lean, kept = _run(cfg, records, start, maneuvers=False, fast_slip=False)
    assert everything.fast > 0 and kept.fast == 0  # the rows the first pass does not make
    assert kept.rows == everything.rows and len(kept.rows) > 100
    assert kept.events == everything.events
    if stored == "wrong latency":
        assert any("GPS latency" in e.detail for e in kept.events)
    assert lean.estimator.learned() == full.estimator.learned()
    assert dataclasses.asdict(lean.diagnostics()) == dataclasses.asdict(full.diagnostics())
    bare, no_wheels = _run(cfg, records, start, maneuvers=False, fast_slip=False, wheel_estimates=False)
    assert all(not e.wheels for e in no_wheels.estimates)  # every wheel's window into its fits, no WheelEstimate
    assert no_wheels.estimates == [dataclasses.replace(e, wheels={}) for e in everything.estimates]
    assert any(e.wheels["FL"].slip is not None for e in everything.estimates)
    assert no_wheels.events == everything.events
    assert bare.estimator.learned() == full.estimator.learned()
    assert dataclasses.asdict(bare.diagnostics()) == dataclasses.asdict(full.diagnostics())
    got = first_pass(cfg, records, start, "log")
    assert got.learned == full.estimator.learned()


def test_the_first_pass_keeps_only_the_reference_wheels_and_gets_the_same_speeds() -> None:
    """The first pass keeps the non-driven wheels' samples only (what the reference speed uses): its per-fix speeds
    equal those smoothed from a full pass's fixes and every wheel's samples."""
    cfg = load_config(CONFIG)
    records = _records(cfg)
    every = _FirstPassSink()
    p = Pipeline(cfg, [every])
    for run in read_ahead(batched(records)):
        p.process_all(run)
    p.finish()
    got = first_pass(cfg, records, None, "log")
    assert len(reference_wheels(cfg)) == 2  # one axle driven
    assert got.gps_speeds == smoothed_gps_speeds(every, got.calibration, cfg)
    assert got.gps_speeds != [f.speed_mps for f in every.fixes] and len(got.gps_speeds) > 300
    kept = _FirstPassSink(reference_wheels(cfg))
    process(cfg, records, [kept], maneuvers=False, fast_slip=False)
    for w in reference_wheels(cfg):
        assert all(np.array_equal(a, b) for a, b in zip(kept.wheel_series(w), every.wheel_series(w)))
    with pytest.raises(KeyError):
        kept.wheel_series(next(w for w in WHEELS if w not in reference_wheels(cfg)))
