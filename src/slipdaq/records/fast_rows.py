"""High-rate slip rows as columns: the rows one fix released (FastSlipBatch, what the estimator hands the sinks) and
the rows of a whole run (FastRows, what a report holds), one numpy array per field in place of an object or a dict
per row. Their values are FastSlip's, field for field; a dict or a FastSlip is made only where a reader asks for one.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any, overload

import numpy as np

from slipdaq.records import FastSlip, FastWheel
from slipdaq.records.columns import FAST_ACCEL_SOURCES, FAST_SLIP_COLUMNS


def _values(x: np.ndarray, defined: np.ndarray) -> list[float | None]:
    """x as floats, None where not defined."""
    out: list[float | None] = x.tolist()
    if not defined.all():
        out = [v if ok else None for v, ok in zip(out, defined.tolist())]
    return out


@dataclass(frozen=True, slots=True, eq=False)
class FastSlipBatch(Sequence[FastSlip]):
    """High-rate slip rows in time order as columns (one entry per row), every wheel of `wheels` in each; as a
    sequence, its rows as FastSlip records (made when asked for)."""

    time_s: np.ndarray
    speed_mps: np.ndarray
    accel_mps2: np.ndarray
    accel_imu: np.ndarray
    """bool: accel_source 'imu' (else 'gps')."""
    wheels: tuple[str, ...]
    slip: dict[str, np.ndarray]
    """Per wheel, FastWheel.slip (NaN where slip_defined is false: None)."""
    slip_defined: dict[str, np.ndarray]
    wheel_speed_mps: dict[str, np.ndarray]
    """Per wheel, FastWheel.speed_mps (NaN where speed_defined is false: None)."""
    speed_defined: dict[str, np.ndarray]

    def __len__(self) -> int:
        return len(self.time_s)

    @overload
    def __getitem__(self, i: int) -> FastSlip: ...
    @overload
    def __getitem__(self, i: slice) -> list[FastSlip]: ...
    def __getitem__(self, i: int | slice) -> FastSlip | list[FastSlip]:
        if isinstance(i, slice):
            return self.records()[i]
        if not -len(self) <= i < len(self):
            raise IndexError(i)
        i %= len(self)
        return self.slice(i, i + 1).records()[0]

    def __iter__(self) -> Iterator[FastSlip]:
        return iter(self.records())

    def slice(self, start: int, stop: int) -> FastSlipBatch:
        """Rows start..stop."""
        def part(by_wheel: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
            return {w: x[start:stop] for w, x in by_wheel.items()}

        return FastSlipBatch(self.time_s[start:stop], self.speed_mps[start:stop], self.accel_mps2[start:stop],
                             self.accel_imu[start:stop], self.wheels, part(self.slip), part(self.slip_defined),
                             part(self.wheel_speed_mps), part(self.speed_defined))

    def columns(self) -> dict[str, list[Any]]:
        """The rows' values by column name (FAST_SLIP_COLUMNS, in order; None: undefined): FastSlip.as_row's."""
        by_attribute: dict[str, Any] = {
            "time_s": self.time_s.tolist(), "speed_mps": self.speed_mps.tolist(),
            "accel_mps2": self.accel_mps2.tolist(),
            "accel_source": [FAST_ACCEL_SOURCES[0] if imu else FAST_ACCEL_SOURCES[1] for imu in self.accel_imu.tolist()],
        }
        per_wheel = {"slip": (self.slip, self.slip_defined), "speed_mps": (self.wheel_speed_mps, self.speed_defined)}
        out: dict[str, list[Any]] = {}
        for group in FAST_SLIP_COLUMNS:
            for w in self.wheels if group.per_wheel else ("",):
                for c in group.columns:
                    if group.per_wheel:
                        values, defined = per_wheel[c.attribute]
                        out[c.key(w)] = _values(values[w], defined[w])
                    else:
                        out[c.name] = by_attribute[c.attribute]
        return out

    def dicts(self) -> list[dict[str, Any]]:
        """Each row as FastSlip.as_row gives it."""
        columns = self.columns()
        keys = list(columns)
        return [dict(zip(keys, values)) for values in zip(*columns.values())]

    def records(self) -> list[FastSlip]:
        """Each row as a FastSlip record."""
        wheels = [list(zip(_values(self.slip[w], self.slip_defined[w]),
                           _values(self.wheel_speed_mps[w], self.speed_defined[w]))) for w in self.wheels]
        names = self.wheels
        return [FastSlip(t, v, a, FAST_ACCEL_SOURCES[0] if imu else FAST_ACCEL_SOURCES[1],
                         {w: FastWheel(*ws) for w, ws in zip(names, per)})
                for t, v, a, imu, *per in zip(self.time_s.tolist(), self.speed_mps.tolist(),
                                              self.accel_mps2.tolist(), self.accel_imu.tolist(), *wheels)]

    @classmethod
    def concat(cls, parts: Sequence[FastSlipBatch]) -> FastSlipBatch:
        """The batches' rows in order (the same wheels in each)."""
        if len(parts) == 1:
            return parts[0]
        wheels = parts[0].wheels if parts else ()
        if any(p.wheels != wheels for p in parts):
            raise ValueError("batches of high-rate rows with other wheels")

        def cat(arrays: list[np.ndarray], dtype: Any = np.float64) -> np.ndarray:
            return np.concatenate(arrays) if arrays else np.empty(0, dtype=dtype)

        def per_wheel(field: str, dtype: Any = np.float64) -> dict[str, np.ndarray]:
            return {w: cat([getattr(p, field)[w] for p in parts], dtype) for w in wheels}

        return cls(cat([p.time_s for p in parts]), cat([p.speed_mps for p in parts]),
                   cat([p.accel_mps2 for p in parts]), cat([p.accel_imu for p in parts], np.bool_), wheels,
                   per_wheel("slip"), per_wheel("slip_defined", np.bool_), per_wheel("wheel_speed_mps"),
                   per_wheel("speed_defined", np.bool_))

    @classmethod
    def of_rows(cls, rows: Sequence[FastSlip], wheels: Sequence[str]) -> FastSlipBatch:
        """FastSlip records (each with every wheel of `wheels`) as columns."""
        def col(get: Any) -> np.ndarray:
            return np.array([get(r) for r in rows], dtype=np.float64)

        def maybe(values: list[float | None]) -> tuple[np.ndarray, np.ndarray]:
            defined = np.array([v is not None for v in values], dtype=np.bool_)
            return np.array([np.nan if v is None else v for v in values], dtype=np.float64), defined

        slips = {w: maybe([r.wheels[w].slip for r in rows]) for w in wheels}
        speeds = {w: maybe([r.wheels[w].speed_mps for r in rows]) for w in wheels}
        return cls(col(lambda r: r.time_s), col(lambda r: r.speed_mps), col(lambda r: r.accel_mps2),
                   np.array([r.accel_source == FAST_ACCEL_SOURCES[0] for r in rows], dtype=np.bool_), tuple(wheels),
                   {w: s[0] for w, s in slips.items()}, {w: s[1] for w, s in slips.items()},
                   {w: s[0] for w, s in speeds.items()}, {w: s[1] for w, s in speeds.items()})


class FastRows(Sequence[dict[str, Any]]):
    """The high-rate slip rows of a run as they come (FastSlipBatch by FastSlipBatch), held as columns; as a
    sequence, its rows as dicts (FastSlip.as_row's, made when asked for)."""

    CHUNK = 4096
    """Rows made into dicts at a time by iteration."""
    JOIN_EVERY = 1024
    """Batches held apart before they are joined into one (each array has its own overhead)."""

    def __init__(self) -> None:
        self._parts: list[FastSlipBatch] = []
        self._joined: list[FastSlipBatch] = []
        self._n = 0

    def add(self, batch: FastSlipBatch) -> None:
        if not len(batch):
            return
        self._parts.append(batch)
        self._n += len(batch)
        if len(self._parts) >= self.JOIN_EVERY:
            self._joined.append(FastSlipBatch.concat(self._parts))
            self._parts = []

    def batch(self) -> FastSlipBatch:
        """Every row so far as one batch of columns."""
        parts = self._joined + self._parts
        if not parts:
            return FastSlipBatch.concat([])
        one = FastSlipBatch.concat(parts)
        self._joined, self._parts = [one], []
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
        return self.batch().slice(i, i + 1).dicts()[0]

    def __iter__(self) -> Iterator[dict[str, Any]]:
        """The rows as dicts, made a chunk at a time."""
        b = self.batch()
        for start in range(0, len(b), self.CHUNK):
            yield from b.slice(start, start + self.CHUNK).dicts()
