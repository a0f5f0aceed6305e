"""Records pickled by their fields (records/pickling.py): a replay's estimates, fixes and high-rate rows come back
from pickle with every field equal, as copyreg's entry makes them; a class it cannot take is refused."""

from __future__ import annotations

import copyreg
import io
import math
import pickle
import pickletools
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np
import pytest

from slipdaq.config import load_config
from slipdaq.decode.can_wheels import WheelDecoder
from slipdaq.offline.run import process
from slipdaq.records import CanFrame, CanFrameBatch, Estimate, GpsFix, NmeaLine, WheelEstimate
from slipdaq.records.fast_rows import FastSlipBatch
from slipdaq.records.pickling import by_fields
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sinks import Sink
from support.paths import CONFIG


class _Kept(Sink):
    def __init__(self) -> None:
        self.records: list[Any] = []

    def on_fix(self, fix: GpsFix) -> None:
        self.records.append(fix)

    def on_estimate(self, estimate: Estimate, log_time_s: float) -> None:
        self.records.append(estimate)

    def on_fast_slip_rows(self, rows: Any, log_time_s: float) -> None:
        self.records.append(rows)


def _same(a: Any, b: Any) -> bool:
    """Field by field, NaN equal to NaN, records within records compared the same way (arrays: dtype, shape, values)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")
    if isinstance(a, float):
        return a == b or (math.isnan(a) and math.isnan(b))
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if hasattr(a, "__dataclass_fields__"):
        return all(_same(getattr(a, f.name), getattr(b, f.name)) for f in fields(a))
    return bool(a == b)


def test_a_replays_records_come_back_field_by_field() -> None:
    cfg = load_config(CONFIG)
    kept = _Kept()
    process(cfg, [e.record for e in generate(cfg, "cycle", "paved", SimSettings(seed=4), duration_s=12.0)
                  if e.record is not None], [kept], stream=io.StringIO())
    kinds = {type(r) for r in kept.records}
    assert kinds == {GpsFix, Estimate, FastSlipBatch}
    assert any(isinstance(r, Estimate) and r.wheels and r.accel_mps2 is not None for r in kept.records)
    for cls in (GpsFix, WheelEstimate, Estimate, FastSlipBatch):
        assert cls in copyreg.dispatch_table
    back = pickle.loads(pickle.dumps(kept.records, protocol=pickle.HIGHEST_PROTOCOL))
    assert all(_same(a, b) for a, b in zip(kept.records, back, strict=True))
    ops = {op.name for op, _, _ in pickletools.genops(pickle.dumps(kept.records, protocol=pickle.HIGHEST_PROTOCOL))}
    assert "REDUCE" in ops and "BUILD" not in ops  # made by the class's call, no state set afterwards


def test_a_first_pass_fed_records_come_back_field_by_field() -> None:
    """What a two-pass run's first pass is fed (offline.first_pass_feed): NMEA lines, CAN frame batches and the wheel
    decoder's samples, each made by its class's call."""
    cfg = load_config(CONFIG)
    records = [e.record for e in generate(cfg, "cycle", "paved", SimSettings(seed=4), duration_s=3.0)
               if e.record is not None]
    lines = [r for r in records if isinstance(r, NmeaLine)]
    batch = CanFrameBatch.from_frames([r for r in records if isinstance(r, CanFrame)])
    samples = WheelDecoder(cfg).decode_batch(batch)
    fed = [lines, batch, batch.slice(3, 40), samples, samples.of_frames(3, 40)]
    assert lines and len(batch) > 100 and len(samples) > 100
    for record in (lines[0], batch, samples):  # made by the class's call with its fields' values
        made, values = copyreg.dispatch_table[type(record)](record)
        assert made is type(record) and _same(made(*values), record)
    back = pickle.loads(pickle.dumps(fed, protocol=pickle.HIGHEST_PROTOCOL))
    assert all(_same(a, b) for a, b in zip(fed, back, strict=True))


def test_a_class_whose_init_does_not_take_every_field_is_refused() -> None:
    @dataclass(frozen=True, slots=True)
    class Derived:
        a: float
        b: float = field(init=False, default=0.0)

    with pytest.raises(TypeError, match="Derived"):
        by_fields(Derived)
