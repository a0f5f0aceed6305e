"""High-rate slip rows as columns in place of an object or a dict per row: the rows one fix released (FastSlipBatch,
what the estimator hands the sinks: a list per field, a few rows each) and the rows of a whole run (FastRows, what a
report holds: numpy arrays per field, FastColumns). Their values are FastSlip's, field for field; a FastSlip or a
dict is made only where a reader asks for one.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, overload

import numpy as np

from slipdaq import WHEELS
from slipdaq.records import FastSlip, FastWheel
from slipdaq.records.columns import FAST_ACCEL_SOURCES, FAST_SLIP_COLUMNS
from slipdaq.records.pickling import by_fields

Maybe = list[float | None]
"""A column whose value may be undefined (None)."""


def _columns(time_s: list[float], speed_mps: list[float], accel_mps2: list[float], accel_source: list[str],
             wheels: Sequence[str], slip: dict[str, Maybe], wheel_speed_mps: dict[str, Maybe]) -> dict[str, list[Any]]:
    """The rows' values by column name, in FAST_SLIP_COLUMNS' order (FastSlip.as_row's keys)."""
    by_attribute: dict[str, list[Any]] = {"time_s": time_s, "speed_mps": speed_mps, "accel_mps2": accel_mps2,
                                          "accel_source": accel_source}
    per_wheel = {"slip": slip, "speed_mps": wheel_speed_mps}
    out: dict[str, list[Any]] = {}
    for group in FAST_SLIP_COLUMNS:
        for w in wheels if group.per_wheel else ("",):
            for c in group.columns:
                if group.per_wheel:
                    out[c.key(w)] = per_wheel[c.attribute][w]
                else:
                    out[c.name] = by_attribute[c.attribute]
    return out


def _dicts(columns: dict[str, list[Any]]) -> list[dict[str, Any]]:
    keys = list(columns)
    return [dict(zip(keys, values)) for values in zip(*columns.values())]


@dataclass(frozen=True, slots=True, eq=False)
class FastSlipBatch(Sequence[FastSlip]):
    """High-rate slip rows in time order as columns (lists, one entry per row), every wheel of `wheels` in each; as a
    sequence, its rows as FastSlip records (made when asked for)."""

    time_s: list[float]
    speed_mps: list[float]
    accel_mps2: list[float]
    accel_source: list[str]
    wheels: tuple[str, ...]
    slip: dict[str, Maybe]
    """Per wheel, FastWheel.slip."""
    wheel_speed_mps: dict[str, Maybe]
    """Per wheel, FastWheel.speed_mps."""

    def __len__(self) -> int:
        return len(self.time_s)

    @overload
    def __getitem__(self, i: int) -> FastSlip: ...
    @overload
    def __getitem__(self, i: slice) -> list[FastSlip]: ...
    def __getitem__(self, i: int | slice) -> FastSlip | list[FastSlip]:
        return self.records()[i]

    def __iter__(self) -> Iterator[FastSlip]:
        return iter(self.records())

    def columns(self) -> dict[str, list[Any]]:
        """The rows' values by column name (FAST_SLIP_COLUMNS, in order; None: undefined): FastSlip.as_row's."""
        return _columns(self.time_s, self.speed_mps, self.accel_mps2, self.accel_source, self.wheels, self.slip,
                        self.wheel_speed_mps)

    def dicts(self) -> list[dict[str, Any]]:
        """Each row as FastSlip.as_row gives it."""
        return _dicts(self.columns())

    def records(self) -> list[FastSlip]:
        """Each row as a FastSlip record."""
        columns = [(w, self.slip[w], self.wheel_speed_mps[w]) for w in self.wheels]
        out = []
        for k, (t, v, a, src) in enumerate(zip(self.time_s, self.speed_mps, self.accel_mps2, self.accel_source)):
            wheels = {}
            for w, slip, speed in columns:
                wheels[w] = FastWheel(slip[k], speed[k])
            out.append(FastSlip(t, v, a, src, wheels))
        return out

    def part(self, start: int, stop: int) -> FastSlipBatch:
        """Rows start..stop (this batch where they are all of it)."""
        if (start, stop) == (0, len(self)):
            return self
        return FastSlipBatch(self.time_s[start:stop], self.speed_mps[start:stop], self.accel_mps2[start:stop],
                             self.accel_source[start:stop], self.wheels,
                             {w: v[start:stop] for w, v in self.slip.items()},
                             {w: v[start:stop] for w, v in self.wheel_speed_mps.items()})

    @classmethod
    def concat(cls, parts: Sequence[FastSlipBatch]) -> FastSlipBatch:
        """The batches' rows in order (the same wheels in each)."""
        if len(parts) == 1:
            return parts[0]
        wheels = parts[0].wheels if parts else ()
        if any(p.wheels != wheels for p in parts):
            raise ValueError("batches of high-rate rows with other wheels")
        return cls([x for p in parts for x in p.time_s], [x for p in parts for x in p.speed_mps],
                   [x for p in parts for x in p.accel_mps2], [x for p in parts for x in p.accel_source], wheels,
                   {w: [x for p in parts for x in p.slip[w]] for w in wheels},
                   {w: [x for p in parts for x in p.wheel_speed_mps[w]] for w in wheels})

    @classmethod
    def of_dicts(cls, rows: Sequence[Mapping[str, Any]], wheels: Sequence[str] = WHEELS) -> FastSlipBatch:
        """Rows as FastSlip.as_row gives them (a /slip/fast row of a log) as columns: a per-wheel or accel_source
        value a row lacks is None (accel_source: ""); time_s, speed_mps and accel_mps2 it must have."""
        by_wheel = {c.attribute: c for g in FAST_SLIP_COLUMNS if g.per_wheel for c in g.columns}
        slip, speed = by_wheel["slip"], by_wheel["speed_mps"]
        return cls([r["time_s"] for r in rows], [r["speed_mps"] for r in rows], [r["accel_mps2"] for r in rows],
                   [r.get("accel_source", "") for r in rows], tuple(wheels),
                   {w: [r.get(slip.key(w)) for r in rows] for w in wheels},
                   {w: [r.get(speed.key(w)) for r in rows] for w in wheels})

    @classmethod
    def of_rows(cls, rows: Sequence[FastSlip], wheels: Sequence[str]) -> FastSlipBatch:
        """FastSlip records (each with every wheel of `wheels`) as columns."""
        return cls([r.time_s for r in rows], [r.speed_mps for r in rows], [r.accel_mps2 for r in rows],
                   [r.accel_source for r in rows], tuple(wheels), {w: [r.wheels[w].slip for r in rows] for w in wheels},
                   {w: [r.wheels[w].speed_mps for r in rows] for w in wheels})


by_fields(FastSlipBatch)


def _array(values: Maybe) -> tuple[np.ndarray, np.ndarray]:
    """values as float64 (NaN where None) and where they are defined."""
    x = np.array(values, dtype=np.float64)  # None: NaN
    defined = np.ones(len(x), dtype=np.bool_)
    for i in np.flatnonzero(np.isnan(x)).tolist():
        defined[i] = values[i] is not None
    return x, defined


def _values(x: np.ndarray, defined: np.ndarray) -> Maybe:
    """x as floats, None where not defined."""
    out: Maybe = x.tolist()
    if not defined.all():
        out = [v if ok else None for v, ok in zip(out, defined.tolist())]
    return out


@dataclass(frozen=True, slots=True, eq=False)
class FastColumns:
    """High-rate slip rows as numpy arrays, one entry per row (a run's: FastRows)."""

    time_s: np.ndarray
    speed_mps: np.ndarray
    accel_mps2: np.ndarray
    accel_imu: np.ndarray
    """bool: accel_source 'imu' (else 'gps')."""
    wheels: tuple[str, ...]
    slip: dict[str, np.ndarray]
    """Per wheel, FastWheel.slip; NaN where slip_defined is false (None)."""
    slip_defined: dict[str, np.ndarray]
    wheel_speed_mps: dict[str, np.ndarray]
    """Per wheel, FastWheel.speed_mps; NaN where speed_defined is false (None)."""
    speed_defined: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.time_s)

    @classmethod
    def of(cls, batches: Sequence[FastSlipBatch]) -> FastColumns:
        """The batches' rows (the same wheels in each) as arrays."""
        b = FastSlipBatch.concat(batches) if batches else FastSlipBatch([], [], [], [], (), {}, {})
        slips = {w: _array(b.slip[w]) for w in b.wheels}
        speeds = {w: _array(b.wheel_speed_mps[w]) for w in b.wheels}
        return cls(np.array(b.time_s, dtype=np.float64), np.array(b.speed_mps, dtype=np.float64),
                   np.array(b.accel_mps2, dtype=np.float64),
                   np.array([s == FAST_ACCEL_SOURCES[0] for s in b.accel_source], dtype=np.bool_), b.wheels,
                   {w: s[0] for w, s in slips.items()}, {w: s[1] for w, s in slips.items()},
                   {w: s[0] for w, s in speeds.items()}, {w: s[1] for w, s in speeds.items()})

    @classmethod
    def concat(cls, parts: Sequence[FastColumns]) -> FastColumns:
        """The parts' rows in order (the same wheels in each)."""
        if len(parts) == 1:
            return parts[0]
        if not parts:
            return cls.of([])
        wheels = parts[0].wheels
        if any(p.wheels != wheels for p in parts):
            raise ValueError("high-rate rows with other wheels")

        def cat(field: str) -> np.ndarray:
            return np.concatenate([getattr(p, field) for p in parts])

        def per_wheel(field: str) -> dict[str, np.ndarray]:
            return {w: np.concatenate([getattr(p, field)[w] for p in parts]) for w in wheels}

        return cls(cat("time_s"), cat("speed_mps"), cat("accel_mps2"), cat("accel_imu"), wheels, per_wheel("slip"),
                   per_wheel("slip_defined"), per_wheel("wheel_speed_mps"), per_wheel("speed_defined"))

    def batch(self, start: int = 0, stop: int | None = None) -> FastSlipBatch:
        """Rows start..stop as lists (None: undefined), FastSlip's values."""
        part = slice(start, stop)
        imu, gps = FAST_ACCEL_SOURCES[:2]
        return FastSlipBatch(
            self.time_s[part].tolist(), self.speed_mps[part].tolist(), self.accel_mps2[part].tolist(),
            [imu if x else gps for x in self.accel_imu[part].tolist()], self.wheels,
            {w: _values(self.slip[w][part], self.slip_defined[w][part]) for w in self.wheels},
            {w: _values(self.wheel_speed_mps[w][part], self.speed_defined[w][part]) for w in self.wheels})

    def dicts(self, start: int = 0, stop: int | None = None) -> list[dict[str, Any]]:
        """Rows start..stop as FastSlip.as_row gives them."""
        return self.batch(start, stop).dicts()


class FastRows(Sequence[dict[str, Any]]):
    """The high-rate slip rows of a run as they come (FastSlipBatch by FastSlipBatch), held as numpy columns; as a
    sequence, its rows as dicts (FastSlip.as_row's, made when asked for)."""

    CHUNK = 4096
    """Rows made into dicts at a time by iteration."""
    JOIN_EVERY = 1024
    """Batches held as they came before they are made arrays."""

    def __init__(self) -> None:
        self._batches: list[FastSlipBatch] = []
        self._arrays: list[FastColumns] = []
        self._n = 0

    def add(self, batch: FastSlipBatch) -> None:
        if not len(batch):
            return
        self._batches.append(batch)
        self._n += len(batch)
        if len(self._batches) >= self.JOIN_EVERY:
            self._arrays.append(FastColumns.of(self._batches))
            self._batches = []

    def columns(self) -> FastColumns:
        """Every row so far as arrays."""
        parts = self._arrays + ([FastColumns.of(self._batches)] if self._batches else [])
        one = FastColumns.concat(parts)
        self._arrays, self._batches = [one], []
        return one

    def __len__(self) -> int:
        return self._n

    @overload
    def __getitem__(self, i: int) -> dict[str, Any]: ...
    @overload
    def __getitem__(self, i: slice) -> list[dict[str, Any]]: ...
    def __getitem__(self, i: int | slice) -> dict[str, Any] | list[dict[str, Any]]:
        if isinstance(i, slice):
            return [self[k] for k in range(*i.indices(self._n))]
        if not -self._n <= i < self._n:
            raise IndexError(i)
        i %= self._n
        return self.columns().dicts(i, i + 1)[0]

    def __iter__(self) -> Iterator[dict[str, Any]]:
        """The rows as dicts, made CHUNK at a time."""
        c = self.columns()
        for start in range(0, len(c), self.CHUNK):
            yield from c.dicts(start, start + self.CHUNK)
