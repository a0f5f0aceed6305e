"""The high-rate rows a maneuver's figures take (time, fused speed and acceleration, each wheel's slip), as columns:
held as they come (FastRowsHeld: a detector's, from the estimator's batches or a log's rows) and a span of them as
arrays (FastSpan: what a decided maneuver carries; it pickles as a few arrays). An undefined slip is NaN."""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from slipdaq import WHEELS
from slipdaq.records import FastSlip
from slipdaq.records.fast_rows import FastSlipBatch


@dataclass(frozen=True)
class FastSpan:
    """The high-rate rows over a maneuver's span, as columns (NaN: an undefined slip)."""

    time_s: np.ndarray
    speed_mps: np.ndarray
    accel_mps2: np.ndarray
    slips: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.time_s)

    @classmethod
    def of(cls, rows: FastSlipBatch | Iterable[FastSlip | dict[str, Any]] | FastSpan) -> FastSpan:
        """From the estimator's rows (FastSlip records or their batch) or /slip/fast rows (dicts, as a log gives
        them)."""
        if isinstance(rows, FastSpan):
            return rows
        held = FastRowsHeld()
        held.add(rows)
        return held.span()


def _batch_of(rows: list[FastSlip | dict[str, Any]]) -> FastSlipBatch:
    """FastSlip records (each with every wheel) or /slip/fast dicts as one batch of columns."""
    dicts = [r for r in rows if isinstance(r, dict)]
    if len(dicts) == len(rows):
        return FastSlipBatch.of_dicts(dicts)
    records = [r for r in rows if isinstance(r, FastSlip)]
    if len(records) != len(rows):
        raise TypeError("high-rate rows: FastSlip records or /slip/fast dicts, not both")
    return FastSlipBatch.of_rows(records, WHEELS)


def _nan_for_none(values: Sequence[float | None]) -> list[float]:
    return [math.nan if x is None else x for x in values]


class FastRowsHeld:
    """High-rate rows as they come, in time order, as a column per field (slip: NaN where undefined, and for a wheel
    a row lacks)."""

    def __init__(self) -> None:
        self.time_s: deque[float] = deque()
        self.speed_mps: deque[float] = deque()
        self.accel_mps2: deque[float] = deque()
        self.slips: dict[str, deque[float]] = {w: deque() for w in WHEELS}
        self.last_s = -math.inf
        """The newest row's time (-inf: none came), kept when the rows are let go."""

    def __len__(self) -> int:
        return len(self.time_s)

    def add(self, rows: FastSlipBatch | Iterable[FastSlip | dict[str, Any]]) -> None:
        """The estimator's rows (their batch, whose columns are taken as they are, or FastSlip records) or /slip/fast
        rows (dicts), in time order."""
        if not isinstance(rows, FastSlipBatch):
            rows = _batch_of(list(rows))
        self.time_s.extend(rows.time_s)
        self.speed_mps.extend(rows.speed_mps)
        self.accel_mps2.extend(rows.accel_mps2)
        for w, column in self.slips.items():
            slip = rows.slip.get(w)
            column.extend(_nan_for_none(slip) if slip is not None else [math.nan] * len(rows))
        if self.time_s:
            self.last_s = self.time_s[-1]

    def span(self, t_from_s: float = -math.inf, t_to_s: float = math.inf) -> FastSpan:
        """The rows with t_from_s <= time_s <= t_to_s."""
        t = np.array(self.time_s, dtype=np.float64)
        inside = (t_from_s <= t) & (t <= t_to_s)

        def col(values: deque[float]) -> np.ndarray:
            return np.array(values, dtype=np.float64)[inside]

        return FastSpan(t[inside], col(self.speed_mps), col(self.accel_mps2),
                        {w: col(values) for w, values in self.slips.items()})

    def drop_before(self, t_s: float) -> None:
        """Let go of the rows older than t_s."""
        columns = (self.time_s, self.speed_mps, self.accel_mps2, *self.slips.values())
        times = self.time_s
        while times and times[0] < t_s:
            for c in columns:
                c.popleft()
