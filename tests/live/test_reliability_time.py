"""The host clock stepping during a run: record times come from a clock that never steps (SteadyClock:
wall time at the start, then monotonic), so windows are not corrupted; the log records each step."""

from __future__ import annotations

import asyncio
import os
from pathlib import Path

import can
import pytest

from slipdaq.config import load_config
from slipdaq.logformat.reader import iter_topic
from slipdaq.logformat.topics import TOPIC_EVENTS
from slipdaq.pipeline import Pipeline
from slipdaq.records import CanFrame, NmeaLine, RawRecord
from slipdaq.sinks import CollectingSink
from slipdaq.sinks.mcap_log import McapLogSink
from slipdaq.sources.can_bus import CanBusSource
from slipdaq.sources.clock import SteadyClock, watch_steps
from slipdaq.sources.serial_gps import SerialGpsSource
from support.paths import CONFIG
from support.reliability_support import gps_lines, sim_records


class HostClock:
    """A fake host: a monotonic clock and a wall clock that NTP can step."""

    def __init__(self, wall0: float = 1_767_225_600.0) -> None:
        self.mono = 50.0
        self.offset = wall0 - self.mono

    def wall(self) -> float:
        return self.mono + self.offset

    def monotonic(self) -> float:
        return self.mono


def test_steady_clock_does_not_step_with_the_host_clock() -> None:
    h = HostClock()
    c = SteadyClock(h.wall, h.monotonic)
    assert c() == h.wall()
    h.mono += 10.0
    h.offset -= 3600.0  # NTP steps the host clock back an hour
    assert c() == pytest.approx(1_767_225_610.0) and c.offset_s() == pytest.approx(-3600.0)
    assert c.check_step() == pytest.approx(-3600.0) and c.check_step() is None and c.steps == 1
    h.mono += 1.0
    assert c() == pytest.approx(1_767_225_611.0)
    # a host timestamp taken 5 ms ago (a CAN frame's kernel time) comes into the steady clock; never later than now
    assert c.from_wall(h.wall() - 0.005) == pytest.approx(c() - 0.005)
    assert c.from_wall(h.wall() + 7.0) == c()


def test_gps_lines_stamped_by_the_steady_clock_across_a_host_step() -> None:
    """SerialGpsSource stamps lines with its clock: a SteadyClock keeps them evenly spaced across a 2 s step back."""
    h = HostClock()
    src = SerialGpsSource("/dev/ttyUSB0", 115200, clock=SteadyClock(h.wall, h.monotonic), monotonic=h.monotonic)
    src._port_opened()
    out: list[NmeaLine] = []
    for k, line in enumerate(gps_lines(2.0, rate_hz=10.0)):
        if k % 3 == 0:
            h.mono += 0.1
        if k == 30:
            h.offset -= 2.0
        src.feed((line + "\r\n").encode(), out.append)
    times = [x.timestamp_s for x in out[::3]]
    steps = [b - a for a, b in zip(times, times[1:])]
    assert all(s == pytest.approx(0.1, abs=1e-6) for s in steps)


def _stamped(records: list[RawRecord], step_at_s: float, step_s: float, steady: bool) -> list[RawRecord]:
    """The records as a live run would stamp them when the host clock steps by step_s at step_at_s: with the host's
    wall clock (steady=False), or through SteadyClock.from_wall (what the CAN source does)."""
    h = HostClock(records[0].timestamp_s)
    h.mono = 0.0
    h.offset = records[0].timestamp_s
    clock = SteadyClock(h.wall, h.monotonic)
    t0 = records[0].timestamp_s
    out: list[RawRecord] = []
    for r in records:
        h.mono = r.timestamp_s - t0
        h.offset = t0 + (step_s if h.mono >= step_at_s else 0.0)
        wall_ts = h.wall()
        ts = clock.from_wall(wall_ts) if steady else wall_ts
        out.append(CanFrame(ts, r.arbitration_id, r.data, r.is_extended_id, r.is_error_frame)
                   if isinstance(r, CanFrame) else NmeaLine(ts, r.line))
    return out


def _estimates(records: list[RawRecord]) -> list[dict]:
    c = CollectingSink()
    Pipeline(load_config(CONFIG), [c]).run(records)
    return [e.as_row() for e in c.estimates]


@pytest.mark.parametrize("step_s", [-2.0, 3.0])
def test_host_clock_step_does_not_corrupt_windows(step_s: float) -> None:
    """A host clock step mid-drive: stamped with the wall clock, the estimator loses (back step) or corrupts (forward
    step) the windows around it; stamped through the steady clock, the estimates are those of the drive without a
    step (to float rounding of the stamps)."""
    records = sim_records(10.0)
    clean = _estimates(records)
    steady = _estimates(_stamped(records, 5.0, step_s, steady=True))
    assert len(steady) == len(clean)
    for a, b in zip(steady, clean):
        assert a["time_s"] == pytest.approx(b["time_s"], abs=1e-6)
        for k in ("slip_FL", "slip_RR", "speed_mps"):
            assert (a[k] is None) == (b[k] is None) and (a[k] is None or a[k] == pytest.approx(b[k], abs=1e-6))
    stepped = _estimates(_stamped(records, 5.0, step_s, steady=False))
    differs = len(stepped) != len(clean) or any(
        a["time_s"] != pytest.approx(b["time_s"], abs=1e-3) for a, b in zip(stepped, clean))
    assert differs  # what the steady clock protects against


def test_a_host_clock_step_is_recorded_in_the_log(tmp_path: Path) -> None:
    h = HostClock()
    clock = SteadyClock(h.wall, h.monotonic)
    path = tmp_path / "step.mcap"

    async def run() -> None:
        sink = McapLogSink(path, load_config(CONFIG), "live", flush_every_s=0.05, clock=clock)
        watch = asyncio.create_task(watch_steps(clock, sink.on_source_event, period_s=0.05))  # as the daemon runs it
        await asyncio.sleep(0.12)
        h.offset += 1.5  # NTP steps the host clock 1.5 s forward
        await asyncio.sleep(0.12)
        watch.cancel()
        sink.close()

    asyncio.run(run())
    events = [d for _, _, d in iter_topic(path, (TOPIC_EVENTS,))]
    assert [(e["source"], e["event"]) for e in events] == [("clock", "stepped")]
    assert "+1.500 s" in events[0]["detail"] and events[0]["counters"]["steps"] == 1


@pytest.mark.parametrize("step_s", [-2.0, 1.5])
def test_can_source_stamps_frames_with_the_steady_clock(step_s: float) -> None:
    """Frames stamped by the bus with the host wall clock (as SocketCAN's kernel stamps are) go through CanBusSource
    with stamp=SteadyClock: a host clock step mid-stream leaves their spacing as it was, and before the step the bus's
    stamps are kept exactly."""
    h = HostClock()
    clock = SteadyClock(h.wall, h.monotonic)
    channel = f"slipdaq-step-{os.getpid()}-{step_s}"
    got: list[CanFrame] = []
    sent: list[float] = []

    async def run() -> None:
        with can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as rx, \
                can.Bus(interface="virtual", channel=channel) as tx:
            task = asyncio.create_task(CanBusSource(rx, stamp=clock).run(got.append))
            for k in range(60):
                h.mono += 0.01
                if k == 30:
                    h.offset += step_s  # NTP steps the host clock
                sent.append(h.wall())
                tx.send(can.Message(timestamp=sent[-1], arbitration_id=0x310, data=bytes(8), is_extended_id=False))
                for _ in range(2000):  # read before the clocks move on, as a reader keeping up does
                    if len(got) > k:
                        break
                    await asyncio.sleep(0.001)
            task.cancel()
            with pytest.raises(asyncio.CancelledError):
                await task

    asyncio.run(run())
    times = [f.timestamp_s for f in got]
    assert len(times) == 60
    assert times[:30] == sent[:30]
    assert all(b - a == pytest.approx(0.01, abs=1e-6) for a, b in zip(times, times[1:]))
    assert sent[30] - sent[29] == pytest.approx(0.01 + step_s, abs=1e-6)  # what the host clock did
