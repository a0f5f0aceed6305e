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

import time
from collections.abc import Callable

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
        self._origin = self.offset_s()
        self._last_offset_s = 0.0
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

    def from_wall(self, wall_ts: float, not_after: float | None = None) -> float:
        """A host wall-clock timestamp (taken just before now) in this clock, never later than now (or not_after).

        A timestamp taken before a step and converted after it would be off by the step; clamping it to now keeps
        the records in order (a source also keeps its own records monotonic, see CanBusSource in the docs)."""
        now = self()
        t = wall_ts - (self._wall() - now)
        limit = now if not_after is None else min(now, not_after)
        return t if t <= limit else limit

    def check_step(self, threshold_s: float = STEP_THRESHOLD_S) -> float | None:
        """The host clock's step since the last call (seconds, signed) when larger than threshold_s, else None."""
        off = self.offset_s()
        step = off - self._last_offset_s
        if abs(step) <= threshold_s:
            return None
        self._last_offset_s = off
        self.steps += 1
        return step
