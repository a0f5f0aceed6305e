"""Which windows enter the stiffness fit (stiffness.py): the tire's linear region, by what the window's data say.

A window enters when the tire carries a force, the car is at fit_min_speed or faster, |slip| <= cx_slip_max, and no
wheel's slip varies much within the window: each wheel's speed over SPREAD_PARTS equal parts of the window
(revolutions from a local line through 2*LOCAL_HALF+1 samples at each part's ends) deviates from a straight line in
time by at most cx_fit_slip_spread_max RMS, as a fraction of its mean. The car's speed changes smoothly over a
window, so that deviation is a wheel's own slip varying: ABS cycling it through the tire's peak, or a window across
the brake's onset, whose mean slip is small but whose mean force and slip are no point of the linear curve. One
wheel cycled by ABS keeps every wheel's window out: the car brakes at the road's limit, and the tires ABS does not
cycle carry forces beyond their linear region too (the other axle of a stop with ABS on one). On the linear region
the deviation is the counts' and timestamps' noise and the steps of acceleration (docs/method.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from slipdaq.estimator.params import EstimatorParams
from slipdaq.estimator.ring import SeriesRing

SPREAD_PARTS = 10
"""The window's parts over which the wheel's speed is taken (50 ms each in a 0.5 s window: an ABS cycle at 7 Hz spans three)."""
LOCAL_HALF = 2
"""Revolutions at a part's end: a least-squares line through this many samples either side (timestamp jitter)."""


def slip_spread(ring: SeriesRing, t0: float, t1: float) -> float | None:
    """The RMS deviation of the wheel's speed over SPREAD_PARTS parts of [t0, t1] from a straight line in time, as a
    fraction of their mean speed; None without enough samples or with the wheel not rolling forward."""
    ends = np.linspace(t0, t1, SPREAD_PARTS + 1)
    revs = ring.local_linear(ends, LOCAL_HALF)
    if revs is None:
        return None
    r = revs.tolist()
    dt = (t1 - t0) / SPREAD_PARTS
    speeds = [(b - a) / dt for a, b in zip(r, r[1:])]
    mean = sum(speeds) / SPREAD_PARTS
    if not mean > 0:
        return None
    # a line over the parts' midpoints, x = -4.5..4.5 (equally spaced): slope = sum(x*v) / sum(x^2)
    xs = [k - 0.5 * (SPREAD_PARTS - 1) for k in range(SPREAD_PARTS)]
    slope = sum(x * v for x, v in zip(xs, speeds)) / sum(x * x for x in xs)
    rss = sum((v - mean - slope * x) ** 2 for x, v in zip(xs, speeds))
    return math.sqrt(rss / SPREAD_PARTS) / mean


class WindowSpread:
    """The largest slip_spread of the wheels over one window, computed when first asked."""

    def __init__(self, rings: Sequence[SeriesRing], t0: float, t1: float) -> None:
        self.rings, self.t0, self.t1 = rings, t0, t1
        self._value: float | None = None
        self._known = False

    def __call__(self) -> float | None:
        if not self._known:
            spreads = [s for ring in self.rings if (s := slip_spread(ring, self.t0, self.t1)) is not None]
            self._value, self._known = max(spreads, default=None), True
        return self._value


def enters_fit(p: EstimatorParams, force: float | None, slip: float, speed: float,
               spread: Callable[[], float | None]) -> bool:
    """The window is on the tire's linear region (spread: the wheels' largest slip_spread over it, asked last: it
    costs)."""
    if force is None or speed < p.fit_min_speed_mps or abs(slip) > p.cx_slip_max:
        return False
    s = spread()
    return s is None or s <= p.cx_fit_slip_spread_max
