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

import pytest

from slipdaq.config import load_config
from slipdaq.offline.run import process
from slipdaq.records import Estimate, GpsFix, WheelEstimate
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
    """Field by field, NaN equal to NaN, records within records compared the same way."""
    if type(a) is not type(b):
        return False
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


def test_a_class_whose_init_does_not_take_every_field_is_refused() -> None:
    @dataclass(frozen=True, slots=True)
    class Derived:
        a: float
        b: float = field(init=False, default=0.0)

    with pytest.raises(TypeError, match="Derived"):
        by_fields(Derived)
