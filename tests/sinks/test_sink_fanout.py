"""The pipeline's one dispatch: every sink call fanned out in order, and sinks closed in a `with` block."""

from __future__ import annotations

import pytest

from slipdaq.records import SensorSample
from slipdaq.sinks import SINK_CALLS, CollectingSink, Sink, SinkFanout


class _Recording(Sink):
    def __init__(self, name: str, log: list[str], fail_close: bool = False) -> None:
        self.name, self.log, self.fail_close = name, log, fail_close

    def on_sensor(self, sample: SensorSample) -> None:
        self.log.append(f"{self.name}:{sample.kind}")

    def close(self) -> None:
        self.log.append(f"{self.name}:close")
        if self.fail_close:
            raise OSError(f"{self.name} could not close")


def test_every_call_of_a_sink_is_fanned_out() -> None:
    """Each Sink method (SINK_CALLS lists them all) reaches every sink through the fan-out."""
    assert {"on_raw", "on_can_batch", "on_wheel_batch", "on_fix", "on_sensor", "on_estimate", "on_fast_slip_rows",
            "on_maneuver", "on_diagnostics", "on_source_event"} <= set(SINK_CALLS)
    for name in SINK_CALLS:
        assert getattr(SinkFanout, name) is not getattr(Sink, name), name


def test_calls_reach_each_sink_in_the_order_given() -> None:
    log: list[str] = []
    collected = CollectingSink()
    fan = SinkFanout([_Recording("a", log), collected, _Recording("b", log)])
    sample = SensorSample(1.0, "brake", 1.0)
    fan.on_sensor(sample)
    fan.on_sensor(SensorSample(2.0, "imu_accel", 0.5))
    assert log == ["a:brake", "b:brake", "a:imu_accel", "b:imu_accel"]
    assert collected.sensors[0] is sample and len(collected.sensors) == 2


def test_with_block_closes_every_sink_even_when_one_fails() -> None:
    log: list[str] = []
    with pytest.raises(OSError, match="b could not close"):
        with SinkFanout([_Recording("a", log), _Recording("b", log, fail_close=True), _Recording("c", log)]) as fan:
            fan.on_sensor(SensorSample(1.0, "brake", 1.0))
    assert log == ["a:brake", "b:brake", "c:brake", "c:close", "b:close", "a:close"]


def test_a_sink_in_a_with_block_is_closed_on_error() -> None:
    log: list[str] = []
    with pytest.raises(RuntimeError):
        with _Recording("a", log):
            raise RuntimeError("boom")
    assert log == ["a:close"]
