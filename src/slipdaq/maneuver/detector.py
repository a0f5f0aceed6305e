"""Maneuvers decided online, as each ends: estimate rows, high-rate rows and brake-signal samples in (in the order
of processing), `ManeuverSummary`s out. Pure (no clock, no I/O); the pipeline runs it live and in replay, the report
over a log's rows, so both decide the same maneuvers with the same figures.

An event is closed by the rule of `events.closed_events` over the rows not yet in a closed event; a closed
accelerate or brake event of at least MIN_MANEUVER_ROWS rows with a defined slip is then summarized
(`figures.summarize_maneuver`) once a high-rate row past its span's end has come (all of its span is then in), or at
`finish`. Its anchors (the linearity rule's cruise windows) are the cruise rows known when it closed: the latest
ANCHOR_WINDOWS of the cruise events before it, and those after it so far (the cruise that closed it).
Rows older than any open event's span are let go: what a run keeps, and what deciding a maneuver costs, does not grow
with the length of the run.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from slipdaq import WHEELS
from slipdaq.config import Config, TestConfig, TireConfig, VehicleConfig
from slipdaq.maneuver.events import MIN_MANEUVER_ROWS, MIN_RUN_ROWS, close_events
from slipdaq.maneuver.fast_span import FastRowsHeld, FastSpan
from slipdaq.maneuver.figures import (
    BRAKE_SIGNAL_BEFORE_S,
    SPAN_BEFORE_S,
    ManeuverSummary,
    span_s,
    summarize_maneuver,
)
from slipdaq.maneuver.linearity import LinearityRule
from slipdaq.maneuver.record import Maneuver, maneuver_record
from slipdaq.records import FastSlip
from slipdaq.records.fast_rows import FastSlipBatch

ANCHOR_KEYS = ("speed_mps",) + tuple(k for w in WHEELS for k in (f"slip_{w}", f"force_{w}_n"))
"""What the linearity rule takes of a cruise row."""
BRAKE_MARK = "brake_mark"
"""The sensor kind (/can/sensors) of a time mark of the brake's press: the GPS receiver's UBX-TIM-TM2 of the brake-light
switch ([brake] source = "gps-timemark"), placed on the host's clock."""
ANCHOR_WINDOWS = 1000
"""The cruise windows before a maneuver that anchor its force–slip line (Fx = 0, and the noise of slip and force):
the latest this many (100 s of cruise at 10 Hz). The line's offset s0 is the radius error, which drifts with the
tire's temperature and pressure over a day, and a drift of the cruise values inflates their spread taken as noise
(linearity.anchor_noise): the tire as it is now, not as it was in the morning."""
KEEP_S = SPAN_BEFORE_S + BRAKE_SIGNAL_BEFORE_S + 15.0
"""High-rate rows and brake samples are kept this long before the oldest open row (a window is at most 10 s)."""


@dataclass(frozen=True, slots=True)
class Job:
    """A decided maneuver as data (rows, anchors, high-rate rows and brake samples of its own, the rule and config it
    is judged by): calling it computes its summary (`summarize_maneuver`). It pickles, so it may run in another
    process as well as on another thread."""

    phase: str
    rows: list[dict[str, Any]]
    anchors: Anchors
    fast: FastSpan
    """The high-rate rows over its span, as columns (they pickle as a few arrays)."""
    brake: list[tuple[float, float]]
    marks: list[float]
    t0_s: float
    cfg_latency_s: float | None
    rule: LinearityRule
    vehicle: VehicleConfig
    lost_frames: dict[str, int]
    mu_max: float
    test: TestConfig

    def __call__(self) -> ManeuverSummary:
        return summarize_maneuver(
            self.phase, self.rows, t0_s=self.t0_s, cfg_latency_s=self.cfg_latency_s, rule=self.rule,
            anchors=self.anchors.rows(), fast=self.fast, brake=self.brake, vehicle=self.vehicle,
            lost_frames=self.lost_frames, mu_max=self.mu_max, test=self.test, marks=self.marks)

    def record(self, index: int) -> Maneuver:
        """Its /maneuver record, the log's maneuver number `index`."""
        return maneuver_record(self(), index, self.test, WHEELS)


def _anchor(row: dict[str, Any]) -> dict[str, Any]:
    return {k: row.get(k) for k in ANCHOR_KEYS}


class AnchorRing:
    """The latest ANCHOR_WINDOWS cruise rows' ANCHOR_KEYS, in arrays allocated once (float64, and whether the row had
    the value: None is not NaN): what a run keeps of them is the same size from its first row on. rows() gives them
    back as the rows' values (a float64 holds a row's float exactly), oldest first."""

    def __init__(self, size: int = ANCHOR_WINDOWS) -> None:
        self.values = np.zeros((size, len(ANCHOR_KEYS)))
        self.present = np.zeros((size, len(ANCHOR_KEYS)), dtype=bool)
        self.added = 0

    def __len__(self) -> int:
        return min(self.added, len(self.values))

    def add(self, row: dict[str, Any]) -> None:
        i = self.added % len(self.values)
        got = [row.get(k) for k in ANCHOR_KEYS]
        self.present[i] = [v is not None for v in got]
        self.values[i] = [0.0 if v is None else v for v in got]
        self.added += 1

    def rows(self) -> list[dict[str, Any]]:
        return self.snapshot().rows()

    def snapshot(self) -> Anchors:
        """The rows as they are now, as arrays (copies)."""
        n = len(self)
        order = np.arange(self.added - n, self.added) % len(self.values)
        return Anchors(self.values[order], self.present[order])


@dataclass(frozen=True, slots=True)
class Anchors:
    """A maneuver's anchors: the ring's rows as arrays (oldest first) and the cruise rows after it; rows() gives them
    as rows (made where the summary is computed, not where the maneuver is decided)."""

    values: np.ndarray
    present: np.ndarray
    after: tuple[dict[str, Any], ...] = ()

    def rows(self) -> list[dict[str, Any]]:
        return [{k: v if p else None for k, v, p in zip(ANCHOR_KEYS, vs, ps)}
                for vs, ps in zip(self.values.tolist(), self.present.tolist())] + list(self.after)


NO_ANCHORS = Anchors(np.zeros((0, len(ANCHOR_KEYS))), np.zeros((0, len(ANCHOR_KEYS)), dtype=bool))


def _has_slip(rows: list[dict[str, Any]]) -> bool:
    return any(r.get(f"slip_{w}") is not None for r in rows for w in WHEELS)


class ManeuverDetector:
    """phases: the rows' own `phase` (default) or given per row (old logs: `fallback.derive_phases`)."""

    def __init__(self, config: Config | None, *, phases: tuple[str, ...] = ("accelerate", "cruise", "brake"),
                 rule: LinearityRule | None = None, lost_frames: Mapping[str, int] | None = None) -> None:
        """phases: which events become maneuvers (the report takes cruise too); lost_frames: per wheel, for the
        report's tables."""
        rule = rule or LinearityRule()
        if config is not None:  # the bounds the estimator used for Cx
            rule = LinearityRule(**{**rule.__dict__, "slip_min": config.estimator.cx_slip_min,
                                    "slip_max": config.estimator.cx_slip_max})
        self.rule = rule
        self.vehicle = config.vehicle if config is not None else VehicleConfig()
        self.cfg_latency_s = None if config is None else (config.latency_fixed_s or 0.0)  # "auto": 0
        self.mu_max = config.tire.mu_max if config is not None else TireConfig().mu_max
        self.test = config.test if config is not None else TestConfig()
        self.phases = phases
        self.fast_rows = config is None or config.estimator.fast_rate_hz > 0
        """High-rate rows come (a maneuver waits for those past its span); else the estimates' time decides."""
        self.lost_frames = dict(lost_frames or {})
        self.t0_s: float | None = None
        """Time of the first estimate: maneuver times count from it."""
        self._rows: list[dict[str, Any]] = []
        self._phase: list[str | None] = []
        self._times: list[float] = []
        self._await_seal = False
        """An open accelerate or brake event long enough for a maneuver: a cruise after it closes it in time."""
        self._anchors = AnchorRing()
        self._queue: deque[tuple[str, list[dict[str, Any]], Anchors, float, float]] = deque()
        """Closed events waiting for their high-rate rows: (phase, rows, anchors, span from, span to)."""
        self._fast = FastRowsHeld()
        self._brake: deque[tuple[float, float]] = deque()
        self._marks: deque[float] = deque()
        self._decided: list[Job] = []
        """Maneuvers decided by the input being taken: each the summary's computation, on its own data."""

    def add_estimate(self, row: dict[str, Any], phase: str | None = None) -> list[Job]:
        """One estimate row (Estimate.as_row()); phase: its phase when the row has none of its own. Returns the
        maneuvers it decided, each as the computation of its summary (pure, on data of its own: it may run on
        another thread), in order."""
        if self.t0_s is None:
            self.t0_s = row["time_s"]
        p = row.get("phase") if phase is None else phase
        prev = self._phase[-1] if self._phase else None
        self._rows.append(row)
        self._phase.append(p)
        self._times.append(row["time_s"])
        run = 1
        while run <= MIN_RUN_ROWS and run < len(self._phase) and self._phase[-1 - run] == p:
            run += 1
        if p != prev or run == MIN_RUN_ROWS or (self._await_seal and p == "cruise"):
            self._close(*close_events(self._phase, self._times))
        return self._decide()

    def add_fast(self, rows: FastSlipBatch | Iterable[FastSlip | dict[str, Any]]) -> list[Job]:
        """High-rate rows (the estimator's batch or FastSlip records, or their rows as dicts), in time order. Returns
        the maneuvers they decided (add_estimate)."""
        self._fast.add(rows)
        return self._decide()

    def add_brake(self, time_s: float, value: float) -> None:
        """One sample of the brake signal (nonzero: pressed)."""
        self._brake.append((time_s, value))

    def add_brake_mark(self, time_s: float) -> None:
        """One time mark of the brake's press (the receiver's, on the host's clock)."""
        self._marks.append(time_s)

    def add_sensor_row(self, sample: Mapping[str, Any]) -> None:
        """A /can/sensors sample as the log's JSON gives it: a brake sample or a brake mark (others: nothing)."""
        if sample.get("kind") == "brake":
            self.add_brake(sample["time_s"], sample["value"])
        elif sample.get("kind") == BRAKE_MARK:
            self.add_brake_mark(sample["time_s"])

    def finish(self) -> list[Job]:
        """Every event still open closed and decided with what has come (the end of a log): the maneuvers, as
        add_estimate returns them."""
        if self._rows:
            self._close(*close_events(self._phase, self._times, final=True))
        return self._decide(final=True)

    # ---- internals ----
    def _close(self, found: list[tuple[str | None, list[int]]], closed: int) -> None:
        self._await_seal = any(p in ("accelerate", "brake") and len(idx) >= MIN_MANEUVER_ROWS
                               for p, idx in found[closed:])
        if not closed:
            return
        rows = self._rows
        for k, (p, idx) in enumerate(found[:closed]):
            ev = [rows[i] for i in idx]
            if p == "cruise":
                for r in ev:
                    self._anchors.add(r)
            if p in self.phases and len(ev) >= MIN_MANEUVER_ROWS and _has_slip(ev):
                t_from, t_to = span_s(str(p), ev)
                after = [_anchor(rows[i]) for q, later in found[k + 1:] if q == "cruise" for i in later]
                anchors = dataclasses.replace(self._anchors.snapshot(), after=tuple(after)) if p != "cruise" else NO_ANCHORS
                self._queue.append((str(p), ev, anchors, t_from, t_to))
        last = found[closed - 1][1][-1] + 1
        del self._rows[:last], self._phase[:last], self._times[:last]

    def _decide(self, final: bool = False) -> list[Job]:
        last_s = self._fast.last_s if self.fast_rows else (self._times[-1] if self._times else float("-inf"))
        while self._queue and (final or last_s > self._queue[0][4]):
            p, ev, anchors, t_from, t_to = self._queue.popleft()
            fast = self._fast.span(t_from, t_to)
            brake = [(t, v) for t, v in self._brake if t_from - BRAKE_SIGNAL_BEFORE_S <= t <= t_to]
            marks = [t for t in self._marks if t_from <= t <= t_to]
            assert self.t0_s is not None
            self._decided.append(Job(p, ev, anchors, fast, brake, marks, self.t0_s, self.cfg_latency_s, self.rule,
                                     self.vehicle, self.lost_frames, self.mu_max, self.test))
        self._prune()
        out, self._decided = self._decided, []
        return out

    def _prune(self) -> None:
        """High-rate rows and brake samples that no open or queued event's span can reach any more."""
        oldest = self._queue[0][3] if self._queue else (self._times[0] - 1.0 if self._times else self._fast.last_s)
        keep_from = oldest - KEEP_S
        self._fast.drop_before(keep_from)
        while self._brake and self._brake[0][0] < keep_from:
            self._brake.popleft()
        while self._marks and self._marks[0] < keep_from:
            self._marks.popleft()


class TimeOrderFeed:
    """Estimate rows and high-rate rows to a detector merged by time, an estimate row before a high-rate row of the
    same time (the order of `heapq.merge` over the two); the high-rate rows between two estimate rows go at once (the
    detector decides the same from them as from each in turn). Both kinds may come as a run makes them, each in time
    order: `take` feeds what the other kind cannot precede any more."""

    def __init__(self, detector: ManeuverDetector) -> None:
        self.detector = detector
        self._rows: deque[tuple[dict[str, Any], str | None]] = deque()
        self._fast: deque[FastSlipBatch] = deque()
        self._fast_at = 0
        """The rows of the first batch in _fast given to the detector already."""

    def estimate(self, row: dict[str, Any], phase: str | None = None) -> None:
        """An estimate row (phase: add_estimate's)."""
        self._rows.append((row, phase))

    def fast(self, rows: FastSlipBatch) -> None:
        if len(rows):
            self._fast.append(rows)

    def take(self, until_s: float = math.inf, final: bool = False) -> list[Job]:
        """The rows before until_s that no row still to come can precede (final: every row), to the detector; the
        maneuvers they decided, in order."""
        rows, fast, det = self._rows, self._fast, self.detector
        jobs: list[Job] = []
        while rows or fast:
            if not (rows and fast) and not final:  # the other's next row may come first
                break
            next_fast_s = fast[0].time_s[self._fast_at] if fast else math.inf
            take_row = bool(rows) and rows[0][0]["time_s"] <= next_fast_s
            if not final and (rows[0][0]["time_s"] if take_row else next_fast_s) >= until_s:
                break
            if take_row:
                jobs += det.add_estimate(*rows.popleft())
                continue
            before_s = min(rows[0][0]["time_s"] if rows else math.inf, math.inf if final else until_s)
            times, start = fast[0].time_s, self._fast_at
            stop = start + 1
            while stop < len(times) and times[stop] < before_s:
                stop += 1
            jobs += det.add_fast(fast[0].part(start, stop))
            if stop == len(times):
                fast.popleft()
                stop = 0
            self._fast_at = stop
        return jobs
