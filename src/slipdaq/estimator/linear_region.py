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

from slipdaq.compiled import kernel
from slipdaq.estimator.params import EstimatorParams
from slipdaq.estimator.ring import LINE_USES, SeriesRing, local_line_values

SPREAD_PARTS = 10
"""The window's parts over which the wheel's speed is taken (50 ms each in a 0.5 s window: an ABS cycle at 7 Hz spans three)."""
LOCAL_HALF = 2
"""Revolutions at a part's end: a least-squares line through this many samples either side (timestamp jitter)."""


def slip_spread(ring: SeriesRing, t0: float, t1: float) -> float | None:
    """The RMS deviation of the wheel's speed over SPREAD_PARTS parts of [t0, t1] from a straight line in time, as a
    fraction of their mean speed; None without enough samples or with the wheel not rolling forward."""
    if len(ring) < 2 * LOCAL_HALF + 1:
        return None
    got = spread_kernel()(ring.times, ring.values, t0, t1, SPREAD_PARTS, LOCAL_HALF, 2.0)
    return None if got == NO_SPREAD else got


NO_SPREAD = -1.0
"""_spread's value for None (a spread is >= 0 or NaN)."""


def _spread(t: np.ndarray, v: np.ndarray, t0: float, t1: float, parts: int, half: int, square: float) -> float:
    """slip_spread over the samples t, v (at least 2*half+1 of them), NO_SPREAD for None: the parts' ends as
    np.linspace(t0, t1, parts + 1) computes them, their revolutions from ring.local_lines' lines, the sums in the
    order Python's sum() takes them. square: 2.0, the residuals' power, as an argument so that numba calls libm's pow
    as Python's ** does (with the constant 2 it multiplies, which differs in the last bit for about 1 value in 1,200)."""
    ends = np.empty(parts + 1)
    delta = t1 - t0
    step = delta / parts
    for k in range(parts + 1):
        ends[k] = (k / parts) * delta + t0 if step == 0 else k * step + t0
    ends[parts] = t1
    revs = np.empty(parts + 1)
    slopes = np.empty(parts + 1)
    local_line_values(t, v, ends, half, revs, slopes)
    dt = (t1 - t0) / parts
    speeds = np.empty(parts)
    total = 0.0
    for k in range(parts):
        speeds[k] = (revs[k + 1] - revs[k]) / dt
        total += speeds[k]
    mean = total / parts
    if not mean > 0:
        return NO_SPREAD
    # a line over the parts' midpoints, x = -4.5..4.5 (equally spaced): slope = sum(x*v) / sum(x^2)
    sxv = sxx = 0.0
    for k in range(parts):
        x = k - 0.5 * (parts - 1)
        sxv += x * speeds[k]
        sxx += x * x
    slope = sxv / sxx
    rss = 0.0
    for k in range(parts):
        d = speeds[k] - mean - slope * (k - 0.5 * (parts - 1))
        rss += math.pow(d, square)
    return math.sqrt(rss / parts) / mean


spread_kernel = kernel(_spread, "float64(float64[:], float64[:], float64, float64, int64, int64, float64)",
                       uses=LINE_USES)
"""spread_kernel()(t, v, t0, t1, parts, half, 2.0): see _spread (slip_spread)."""


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
