"""A sensor's samples placed on the host's clock by the sensor's own sample counter (an MTi's SampleTimeFine). Pure.

A host reads a serial port late, never early, and how late moves with its load: a sample stamped on arrival moves
with it, and a burst of late samples leaves a gap and then a crowd. A sample is placed at its own time plus the lower
envelope of (arrival − own time) over the last HISTORY_S seconds of its own clock: the fastest read of that span,
as a GPS fix is placed by its UTC (estimator/latency.py, UtcLatency). The smallest value, not the second smallest:
the counter comes in a checksummed packet and cannot glitch early, and no arrival is stamped before its read. Placed
times never pass the arrival and never go back while the counter counts forward.

A sample read at the envelope's delay, to within EXACT_S, keeps its read time exactly: the records of an imported
capture, stamped from the MTi's own times, keep those stamps.

The counter wraps at 2^32 ticks (SampleTimeFine: 10 kHz, every 4.97 days). The envelope starts again from a sample
when the count goes back (the sensor restarted), when (arrival − own time) is more than RESET_S from the envelope
(the host's clock stepped, or the counter jumped), or when the fastest read of the last RECENT_S is more than
DRIFT_S slower than the envelope's: the counter does not run at the host's rate (a capture played into a port at
another pace than it was sampled), where the envelope would hold samples back; a host that reads late for less than
RECENT_S does not do that.
"""

from __future__ import annotations

from collections import deque

TICKS_PER_S = 10_000
"""SampleTimeFine counts at 10 kHz."""
WRAP = 2**32
HISTORY_S = 5.0
"""The envelope's span on the sensor's clock: 500 samples at 100 Hz, the span of the GPS's 50 fixes at 10 Hz. A
sensor clock 50 ppm off the host's moves 0.25 ms over it."""
RESET_S = 0.5
"""Slower than any read of a loaded host seen here (the HIL VM's worst: 0.31 s); a counter far off the host's
rate (a capture played at a quarter of its pace) is held back at most this much."""
RECENT_S = 1.0
DRIFT_S = 0.05
"""A counter 1 % off the host's rate reaches this in 5 s; a real sensor's crystal (tens of ppm) never does."""
EXACT_S = 1e-6


def ticks_between(earlier: int, later: int) -> int:
    """Counter ticks from `earlier` to `later`, across the 2^32 wrap."""
    return (later - earlier) % WRAP


class SampleClock:
    """place(arrival, ticks): the sample's time on the host's clock (module docstring)."""

    def __init__(self, ticks_per_s: int = TICKS_PER_S, history_s: float = HISTORY_S, reset_s: float = RESET_S) -> None:
        self.ticks_per_s = ticks_per_s
        self.history_s = history_s
        self.reset_s = reset_s
        self._last_ticks: int | None = None
        self._ticks = 0
        """The counter since the envelope started, unwrapped."""
        self._envelope: deque[tuple[float, float]] = deque()
        """(own time, arrival - own time), own time ascending and the second increasing: its first is the minimum."""
        self._recent: deque[tuple[float, float]] = deque()
        """The same over the last RECENT_S."""
        self.resets = 0

    def place(self, arrival_s: float, ticks: int | None) -> float:
        """The sample's time: its arrival where it has no counter."""
        if ticks is None:
            return arrival_s
        ticks %= WRAP
        if self._last_ticks is not None:
            step = ticks_between(self._last_ticks, ticks)
            if step >= WRAP // 2:  # the counter went back: the sensor restarted
                self._restart(arrival_s)
            else:
                self._ticks += step
        self._last_ticks = ticks
        own_s = self._ticks / self.ticks_per_s
        x = arrival_s - own_s
        env, recent = self._envelope, self._recent
        if env and abs(x - env[0][1]) > self.reset_s:
            own_s, x = self._restart(arrival_s)
        self._take(own_s, x)
        if recent[0][1] - env[0][1] > DRIFT_S:  # the counter runs slower than the host's clock
            own_s, x = self._restart(arrival_s)
            self._take(own_s, x)
        placed = own_s + env[0][1]
        return arrival_s if arrival_s - placed <= EXACT_S else placed

    def _take(self, own_s: float, x: float) -> None:
        _push(self._envelope, own_s, x, self.history_s)
        _push(self._recent, own_s, x, RECENT_S)

    def _restart(self, arrival_s: float) -> tuple[float, float]:
        """The envelope started again at this sample: its (own time, arrival - own time)."""
        self._ticks = 0
        self._envelope.clear()
        self._recent.clear()
        self.resets += 1
        return 0.0, arrival_s


def _push(window: deque[tuple[float, float]], own_s: float, x: float, span_s: float) -> None:
    """(own_s, x) into a window whose first is the minimum of x over the last span_s of own time."""
    while window and window[-1][1] >= x:
        window.pop()
    window.append((own_s, x))
    while window[0][0] < own_s - span_s:
        window.popleft()
