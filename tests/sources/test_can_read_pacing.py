"""The CAN reader's pacing on a socket bus (can.read_interval_s): frames read in batches at most every interval,
with the stamps they were given on arrival; no pause while an estimate waits for wheel frames; read_now() ends a
pause. The daemon calls read_now() after the GPS fix that closes a window (tested through the estimator below)."""

from __future__ import annotations

import asyncio
import math
import struct
import time

from slipdaq.estimator.slip import SlipEstimator
from slipdaq.records import CanFrame, CanFrameBatch, GpsFix, WheelSample
from slipdaq.sources.can_bus import CanBusSource
from support.estimator_params import params
from support.fd_bus import FdBus


def _numbers(frames: CanFrameBatch | list[CanFrame]) -> list[tuple[int, float]]:
    fs = frames.frames() if isinstance(frames, CanFrameBatch) else frames
    return [(struct.unpack_from("<I", f.data)[0], f.timestamp_s) for f in fs]


def _source(bus: FdBus, **kw: object) -> tuple[CanBusSource, list[list[tuple[int, float]]]]:
    """A source on bus and the list its batches go to (as (frame number, stamp))."""
    return CanBusSource(bus, **kw), []  # type: ignore[arg-type]


def test_a_paced_reader_takes_frames_in_batches_with_their_arrival_stamps() -> None:
    bus = FdBus()
    src, batches = _source(bus, read_interval_s=0.1)

    async def run() -> None:
        task = asyncio.create_task(src.run(lambda f: None, lambda fs: batches.append(_numbers(fs))))
        await asyncio.sleep(0.05)
        for n in range(1, 61):  # 60 frames over about 0.3 s
            bus.put(n)
            await asyncio.sleep(0.005)
        await asyncio.sleep(0.3)
        task.cancel()

    try:
        asyncio.run(run())
    finally:
        bus.close()
    got = [x for b in batches for x in b]
    assert [n for n, _ in got] == list(range(1, 61))
    assert all(t == bus.stamps[n] for n, t in got)  # the stamps of arrival, not of the read
    assert src.reads < 20  # read every frame as it comes, it would be about 60
    assert max(len(b) for b in batches) >= 5


def test_no_pause_while_an_estimate_waits_for_wheel_frames() -> None:
    bus = FdBus()
    src, batches = _source(bus, read_interval_s=5.0, keep_reading=lambda: True)
    delivered: list[float] = []

    async def run() -> None:
        task = asyncio.create_task(src.run(lambda f: None, lambda fs: (batches.append(_numbers(fs)),
                                                                         delivered.append(time.time()))))
        for n in (1, 2, 3):
            await asyncio.sleep(0.05)
            bus.put(n)
        await asyncio.sleep(0.3)
        task.cancel()

    try:
        asyncio.run(run())
    finally:
        bus.close()
    assert [n for b in batches for n, _ in b] == [1, 2, 3]
    assert len(batches) == 3 and delivered[-1] - bus.stamps[3] < 1.0  # each read when it came, not 5 s later


def test_read_now_ends_a_pause() -> None:
    bus = FdBus()
    src, batches = _source(bus, read_interval_s=5.0)
    seen: dict[str, int] = {}

    async def run() -> None:
        task = asyncio.create_task(src.run(lambda f: None, lambda fs: batches.append(_numbers(fs))))
        await asyncio.sleep(0.05)
        bus.put(1)
        for _ in range(100):  # the first frame is read at once; the reader then pauses for 5 s
            await asyncio.sleep(0.01)
            if batches:
                break
        bus.put(2)
        await asyncio.sleep(0.2)
        seen["during_pause"] = sum(len(b) for b in batches)
        src.read_now()
        await asyncio.sleep(0.2)
        seen["after_read_now"] = sum(len(b) for b in batches)
        task.cancel()

    try:
        asyncio.run(run())
    finally:
        bus.close()
    assert seen == {"during_pause": 1, "after_read_now": 2}


def test_the_estimator_says_when_an_estimate_waits_only_for_wheels() -> None:
    """The fix that closes a window comes before the wheel frames past its end: waiting_for_wheels() is what makes
    the daemon read the (paused) CAN socket at once; the wheel frames then release the estimate."""
    p = params(window_s=0.5, r_ref_m=0.3, gps_latency_s=0.0)
    est = SlipEstimator(p)
    rev = 20.0 / (2 * math.pi * 0.3)
    wheel_t = 0.0

    def wheels_to(t_end: float) -> list:
        nonlocal wheel_t
        out = []
        while wheel_t + 0.001 <= t_end + 1e-12:
            wheel_t = round(wheel_t + 0.001, 6)
            for w in ("FL", "FR", "RL", "RR"):
                out += est.add_wheel(WheelSample(wheel_t, w, rev * wheel_t, int(rev * wheel_t * 1000), 0, 0, 0))
        return out

    released = []
    waiting_at_fix = []
    for k in range(40):  # 20 Hz fixes; the wheels lag each fix by 20 ms
        t = k * 0.05
        released += wheels_to(t - 0.02)
        released += est.add_gps(GpsFix(t, 20.0))
        waiting_at_fix.append(est.waiting_for_wheels())
    released += wheels_to(40 * 0.05)
    assert not any(waiting_at_fix[:5])  # no window closed yet
    assert all(waiting_at_fix[5:])  # fix k closes the window of epoch k-5, whose wheels are 20 ms short
    assert [round(e.time_s, 6) for e in released] == [round(k * 0.05, 6) for k in range(35)]
