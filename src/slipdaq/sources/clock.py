"""The live runs' clock: wall time that never steps.

Record timestamps are the log's clock and the estimator's windows are built on them, so they must not jump when NTP
(or an operator) steps the host clock during a run: a step back would make every record look out of order (the
estimator drops them until the clock catches up), a step forward would open a gap in every window.

SteadyClock reads the host wall clock once, at construction, and from then on adds the monotonic clock's elapsed
time (CLOCK_MONOTONIC: slewed by NTP like the wall clock, never stepped). So it is UTC at the start of the run and
keeps the wall clock's rate; after a step of the host clock it differs from it by that step, which offset_s() tells
(the MCAP log records each step on /diagnostics/events). Timestamps taken by the host wall clock elsewhere (the
kernel's SO_TIMESTAMP of a SocketCAN frame, python-can's time.time() on the virtual bus) are brought into this clock
with from_wall().
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable, Iterable

from slipdaq.records import EventHandler, SourceEvent

STEP_THRESHOLD_S = 0.010
"""A change of the host-clock offset larger than this is reported as a step."""
OFFSET_TRIES = 5
OFFSET_GOOD_S = 50e-6
"""offset_s() stops trying once the wall clock was read within this long."""


class SteadyClock:
    """Callable: seconds since the epoch, as the host wall clock read at start, advancing with the monotonic clock."""

    def __init__(
        self, wall: Callable[[], float] = time.time, monotonic: Callable[[], float] = time.monotonic
    ) -> None:
        self._wall = wall
        self._monotonic = monotonic
        self._origin = 0.0
        self._origin = self.offset_s()  # with origin 0: the wall clock minus the monotonic clock
        self._last_offset_s = 0.0
        self._stamp_offset_s = 0.0
        """The offset from_wall_many() subtracts: changed only by a step."""
        self.steps = 0
        """Host clock steps seen by check_step()."""

    def __call__(self) -> float:
        return self._origin + self._monotonic()

    def offset_s(self) -> float:
        """Host wall clock minus this clock: about 0 until the host clock steps, then the sum of the steps.

        The wall clock is read between two monotonic reads, and the narrowest of a few tries is kept: a process
        preempted between the reads (a busy host, a VM) would otherwise see a false offset of that delay."""
        best_width = best = float("inf")
        for _ in range(OFFSET_TRIES):
            m0 = self._monotonic()
            w = self._wall()
            m1 = self._monotonic()
            if m1 - m0 < best_width:
                best_width, best = m1 - m0, w - (self._origin + 0.5 * (m0 + m1))
                if best_width <= OFFSET_GOOD_S:
                    break
        return best

    def from_wall_many(self, wall_stamps: Iterable[float], not_before: float = -math.inf) -> list[float]:
        """Host wall-clock timestamps (taken before now, in order: a read of CAN frames' kernel stamps) in this clock.

        The host clock's offset is taken to change only when it moves by more than STEP_THRESHOLD_S (a step), so
        that until a step the stamps are kept exactly, not jittered by the offset's reading. A stamp taken before a
        step and converted after it would be off by the step: it becomes now if it lands in the future, and no stamp
        goes before the previous one or not_before (the source's last), so that the records stay in order."""
        now = self()
        offset = self.offset_s()
        if abs(offset - self._stamp_offset_s) > STEP_THRESHOLD_S:
            self._stamp_offset_s = offset
        offset = self._stamp_offset_s
        latest = now + STEP_THRESHOLD_S
        out: list[float] = []
        last = not_before
        for w in wall_stamps:
            t = w - offset
            if t > latest:
                t = now
            if t < last:
                t = last
            out.append(t)
            last = t
        return out

    def from_wall(self, wall_ts: float) -> float:
        """One host wall-clock timestamp in this clock (from_wall_many)."""
        return self.from_wall_many((wall_ts,))[0]

    def check_step(self, threshold_s: float = STEP_THRESHOLD_S) -> float | None:
        """The host clock's step since the last call (seconds, signed) when larger than threshold_s, else None."""
        off = self.offset_s()
        step = off - self._last_offset_s
        if abs(step) <= threshold_s:
            return None
        self._last_offset_s = off
        self.steps += 1
        return step


async def watch_steps(clock: SteadyClock, on_event: EventHandler, period_s: float = 1.0) -> None:
    """Until cancelled: every period_s, a step of the host clock (check_step) becomes a 'clock stepped' event."""
    while True:
        await asyncio.sleep(period_s)
        step_s = clock.check_step()
        if step_s is not None:
            on_event(SourceEvent(
                clock(), "clock", "stepped", f"host clock stepped by {step_s:+.3f} s; log times go on from the run's "
                f"start (host clock - log clock = {clock.offset_s():+.3f} s)", None, {"steps": clock.steps}))

