"""The reference speed from GPS: the fixes in arrival order (speed, UTC time, stated speed accuracy), and what a
window takes from them: the distance driven (integral of the piecewise-linear speed), the acceleration at the
window's centre (central difference of GPS speed) and the weight of the window's fixes.

Fix times: a fix with a UTC time arrives at UTC + median(arrival - UTC) of recent fixes (the receiver's clock, free
of the jitter with which sentences are read), minus the GPS latency.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right

import numpy as np

from slipdaq.compiled import kernel
from slipdaq.estimator.numpy_rules import block_sum, interp_at, interp_into, pairwise_sum, search_with_guess
from slipdaq.estimator.ring import SeriesRing, first_index

MAX_GPS_GAP_S = 1.0
"""GPS fixes further apart than this do not make a window or a central difference."""
TIME_TOL_S = 1e-5
"""GPS times this close count as equal when a window's ends are compared with fixes: the fix that ends a window
(UTC + offset - latency) and the window's end (centre + W/2) are the same instant computed two ways, and float
rounding (a few ulps: 2.4e-7 s at today's epoch seconds) must not decide whether an estimate waits for one more fix."""
ACCEL_HALF_BASELINE_S = 0.075
"""The central difference's fixes are at least this far either side of the centre (a 10 Hz receiver's neighbours)."""
GPS_GAP_INTERVALS = 2.5
"""A fix interval this many times the mean inside a window makes it disturbed."""
REFERENCE_SPEED_ACCURACY_MPS = 0.05
"""A window whose fixes state this speed accuracy (1 sigma) has weight 1 in the r0 and Cx fits; weight ~ 1/sigma^2."""


def integrate_speed_m(times_s: np.ndarray, speeds_mps: np.ndarray, t0: float, t1: float) -> float:
    """Integral of the piecewise-linear speed over [t0, t1] (trapezoids on the fixes plus both ends)."""
    return float(integrate_speed()(times_s, speeds_mps, t0, t1))


def _integrate_speed(times_s: np.ndarray, speeds_mps: np.ndarray, t0: float, t1: float) -> float:
    """integrate_speed_m with numpy's bits: t = [t0, the fixes strictly inside, t1] (searchsorted's sides),
    v = np.interp(t, times, speeds), np.sum((t[1:] - t[:-1]) * (v[1:] + v[:-1])) * 0.5."""
    i0 = first_index(times_s, t0, 0, True)
    i1 = first_index(times_s, t1, 0, False)
    inner = max(i1 - i0, 0)
    t = np.empty(inner + 2)
    t[0] = t0
    for k in range(inner):
        t[k + 1] = times_s[i0 + k]
    t[inner + 1] = t1
    v = np.empty(inner + 2)
    interp_into(t, times_s, speeds_mps, v)
    parts = np.empty(inner + 1)
    for k in range(inner + 1):
        parts[k] = (t[k + 1] - t[k]) * (v[k + 1] + v[k])
    return pairwise_sum(parts) * 0.5


integrate_speed = kernel(_integrate_speed, "float64(float64[:], float64[:], float64, float64)",
                         uses=(first_index, search_with_guess, interp_at, interp_into, block_sum, pairwise_sum))
"""integrate_speed()(times_s, speeds_mps, t0, t1): see _integrate_speed (integrate_speed_m)."""


def _div(a: float, b: float) -> float:
    """a / b with numpy's float64 result for b == 0 (inf or nan) instead of ZeroDivisionError."""
    if b != 0.0:
        return a / b
    if a == 0.0 or a != a:
        return math.nan
    return math.copysign(math.inf, a) * math.copysign(1.0, b)


def smooth_arrival(arrival_s: float, utc_s: float, offset_s: float | None) -> float:
    """One fix's arrival time without read jitter: UTC + offset where it has a UTC time (NaN: none);
    GpsTrack.smooth_arrivals for all fixes at once."""
    return arrival_s if offset_s is None or utc_s != utc_s else utc_s + offset_s


def smooth_arrival_times(arrivals_s: np.ndarray, utc_s: np.ndarray, offset_s: float | None) -> np.ndarray:
    """smooth_arrival of many fixes: UTC + offset where a fix has a UTC time (NaN: none), else its arrival."""
    if offset_s is None:
        return arrivals_s
    return np.where(np.isnan(utc_s), arrivals_s, utc_s + offset_s)


class GpsTrack:
    def __init__(self) -> None:
        self.speed = SeriesRing(256)  # arrival time -> speed
        self.utc = SeriesRing(256)  # arrival time -> the fix's UTC time (NaN without one)
        self.accuracy = SeriesRing(256)  # arrival time -> the receiver's speed accuracy (NaN without one)
        self.last_utc_s = math.nan
        """The newest fix's UTC time (NaN without one)."""

    @property
    def last_t(self) -> float:
        """The newest fix's arrival time (-inf before the first)."""
        return self.speed.last_t

    def add(self, arrival_s: float, speed_mps: float, utc_s: float, accuracy_mps: float) -> None:
        """One fix (utc_s, accuracy_mps: NaN when the fix has none)."""
        self.speed.append(arrival_s, speed_mps)
        self.utc.append(arrival_s, utc_s)
        self.last_utc_s = utc_s
        self.accuracy.append(arrival_s, accuracy_mps)

    def drop_before(self, t: float) -> None:
        self.speed.drop_before = self.utc.drop_before = self.accuracy.drop_before = t

    def smooth_arrivals(self, offset_s: float | None) -> np.ndarray:
        """Arrival times with the read jitter taken out: UTC + offset where the fix has a UTC time."""
        return smooth_arrival_times(self.speed.times, self.utc.values, offset_s)

    @staticmethod
    def covers(fix_times: list[float], t0: float, t1: float) -> bool:
        """Fixes span [t0, t1] with no gap over MAX_GPS_GAP_S."""
        if len(fix_times) < 2 or fix_times[0] > t0 + TIME_TOL_S or fix_times[-1] < t1 - TIME_TOL_S:
            return False
        i0 = max(bisect_right(fix_times, t0) - 1, 0)
        i1 = bisect_left(fix_times, t1)
        seg = fix_times[i0 : i1 + 1]
        return max([b - a for a, b in zip(seg, seg[1:])]) <= MAX_GPS_GAP_S

    def gap_in(self, fix_times: list[float], t0: float, t1: float) -> bool:
        """The fixes spanning [t0, t1] have an interval over GPS_GAP_INTERVALS times the mean fix interval (epochs
        lost inside the window: the speed is interpolated across them)."""
        n = len(fix_times)
        if n < 3:
            return False
        i0 = max(bisect_right(fix_times, t0) - 1, 0)
        i1 = min(bisect_left(fix_times, t1) + 1, n)
        seg = fix_times[i0:i1]
        mean = (fix_times[-1] - fix_times[0]) / (n - 1)
        return len(seg) >= 2 and max([b - a for a, b in zip(seg, seg[1:])]) > GPS_GAP_INTERVALS * mean

    @staticmethod
    def accel(fix_times: list[float], speeds: list[float], t_c: float) -> float | None:
        """a(c) = (v(c+1) - v(c-1)) / (t(c+1) - t(c-1)), or None at the ends or across a gap; c-1 and c+1 are the
        nearest fixes at least ACCEL_HALF_BASELINE_S from c (a fast reference: not its neighbours, whose difference
        is mostly noise)."""
        i = bisect_left(fix_times, t_c)
        n = len(fix_times)
        if i < 1 or i + 1 >= n:
            return None
        j0 = min(bisect_right(fix_times, t_c - ACCEL_HALF_BASELINE_S) - 1, i - 1)
        j1 = max(bisect_left(fix_times, t_c + ACCEL_HALF_BASELINE_S), i + 1)
        if j0 < 0 or j1 >= n or fix_times[j1] - fix_times[j0] > 2 * MAX_GPS_GAP_S:
            return None
        return _div(speeds[j1] - speeds[j0], fix_times[j1] - fix_times[j0])

    def weight(self, fix_times: list[float], t0: float, t1: float) -> float:
        """(reference / stated speed accuracy)^2 over the window's fixes, within 0.1..10; 1 without a stated one."""
        i0 = bisect_left(fix_times, t0)
        # as np.searchsorted(fix_times, (t0, t1)): the second key's search starts where the first one ended
        i1 = bisect_left(fix_times, t1, i0) if t0 < t1 else bisect_left(fix_times, t1, 0, min(i0 + 1, len(fix_times)))
        acc = [x for x in self.accuracy.values[i0 : i1 + 1].tolist() if x == x]
        if not acc:
            return 1.0
        sigma = max(float(np.sum(acc)) / len(acc), 1e-3)
        return min(max((REFERENCE_SPEED_ACCURACY_MPS / sigma) ** 2, 0.1), 10.0)
