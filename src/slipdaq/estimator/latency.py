"""GPS latency (fix time -> host arrival time), estimated two ways. UTC is used when plausible; the wheels' estimate
when UTC is not plausible, or when both exist and disagree by more than 3 sigma + 20 ms (a host clock that is not
really on UTC).

- From UTC: arrival time minus the fix's own UTC time (RMC date + time), its lower envelope (UtcLatency). Right
  when the host clock is synchronised to UTC (NTP, PPS); it then includes the receiver's output delay and the
  serial transmission time.
- From the wheels: the lag tau that best aligns GPS distance between consecutive fixes with the distance rolled by
  the non-driven wheels while they roll freely: minimise sum_k (y_k - r * x_k(tau))^2 over a grid of tau, with
  y_k the GPS distance over fix interval k (trapezoid) and x_k(tau) = 2*pi*revolutions over the same interval of
  arrival times shifted by -tau (r, the radius, is fitted per tau), the revolutions from local lines through the
  nearest samples; tau on a 1 ms grid from -20 ms (a minimum at 0 is inside it), taken as >= 0. Needs speed changes
  to be identifiable: it counts only after MIN_INFORMATIVE_ROWS rows taken while the wheels accelerate
  (a >= 0.5 m/s^2, from the wheels themselves). Least squares with exponential forgetting; uncertainty from the
  curvature of the residual at its minimum. Every wheel driven (none rolls freely): the rows while driving, with
  the wheels' slip in proportion to the acceleration in the fit (slip_terms); that estimate never replaces a
  plausible UTC one (slip.py).
"""

from __future__ import annotations

import math
from bisect import bisect_left, insort
from collections import deque
from dataclasses import dataclass

import numpy as np

from slipdaq.compiled import kernel
from slipdaq.estimator.phase import PHASE_ACCEL_MPS2
from slipdaq.estimator.ring import LINE_USES, SeriesRing, cached_line_values, longest_gap_of
from slipdaq.estimator.wheel_revolutions import TWO_PI, gap_limit


@dataclass(frozen=True, slots=True)
class LatencyEstimate:
    latency_s: float
    source: str
    """'fixed' (configured), 'wheels', 'utc' or 'none' (no estimate yet: 0 is used)."""
    utc_s: float | None
    wheels_s: float | None
    wheels_sigma_s: float | None


class UtcLatency:
    """The lower envelope of (arrival - fix UTC) over the last fixes: its second smallest value (one glitch of a
    receiver's clock is not taken). A host reads and stamps a sentence late, never early: how late varies with the
    host's load (in the HIL VM the median moved from 3 to 12 ms within a minute, p90 25 ms, and with it every fix
    against the wheels), while the fastest reads stay within a few ms (NTP's clock filter takes the least-delayed
    sample for the same reason). Plausible only when from -20 ms (taken as 0) to max_latency_s, and steady (median
    absolute deviation <= 20 ms).

    The values are also kept sorted (NaN counted apart), so the order statistics cost a few steps per fix, and are
    kept until the next add; the median is the float64 result np.median gives (the middle value, or the mean of the
    middle two).
    """

    def __init__(self, max_latency_s: float, history: int = 50) -> None:
        self.max_latency_s = max_latency_s
        self._d: deque[float] = deque(maxlen=history)
        self._sorted: list[float] = []  # the values of _d but NaN, in order
        self._nans = 0
        self._offset_s: float | None = None
        self._estimate_s: float | None = None
        self._fresh = True  # the cached medians are those of _d

    def add(self, arrival_s: float, fix_utc_s: float | None) -> None:
        if fix_utc_s is None:
            return
        x = float(arrival_s - fix_utc_s)
        d = self._d
        if d.maxlen is not None and len(d) == d.maxlen:
            if not d:
                return
            old = d[0]
            if old != old:
                self._nans -= 1
            else:
                del self._sorted[bisect_left(self._sorted, old)]
        d.append(x)
        if x != x:
            self._nans += 1
        else:
            insort(self._sorted, x)
        self._fresh = False

    def offset_s(self) -> float | None:
        """The lower envelope of (arrival - fix UTC): host clock minus UTC plus the least latency, whatever the host
        clock."""
        if not self._fresh:
            self._update()
        return self._offset_s

    def estimate(self) -> float | None:
        if not self._fresh:
            self._update()
        return self._estimate_s

    def _update(self) -> None:
        self._fresh = True
        s = self._sorted
        if not self._d:
            self._offset_s = self._estimate_s = None
            return
        med = math.nan if self._nans else _median_sorted(s)
        low = math.nan if self._nans else 0.0 + s[min(1, len(s) - 1)]
        self._offset_s = low
        if len(self._d) < 5:
            self._estimate_s = None
            return
        spread = math.nan if self._nans else _median_abs_deviation(s, med)
        # a few ms below 0 is rounding (NMEA times to 0.01 s) or clock jitter around a latency near 0
        self._estimate_s = max(low, 0.0) if -0.02 <= low <= self.max_latency_s and spread <= 0.02 else None


def _median_sorted(s: list[float]) -> float:
    """np.median of sorted values without NaN: the mean of the middle one or two as numpy takes it, a sum from 0.0
    (so -0.0 comes out as 0.0)."""
    h = len(s) // 2
    return 0.0 + s[h] if len(s) % 2 else (0.0 + s[h - 1] + s[h]) / 2.0


def _median_abs_deviation(s: list[float], med: float) -> float:
    """np.median(np.abs(s - med)) for sorted s without NaN: the deviations taken in order from med outwards."""
    if not math.isfinite(med):
        return math.nan  # inf - inf among the deviations
    n = len(s)
    j = bisect_left(s, med)
    i = j - 1
    below = dev = 0.0
    for _ in range(n // 2 + 1):
        if i >= 0 and (j >= n or med - s[i] <= s[j] - med):
            below, dev = dev, abs(s[i] - med)
            i -= 1
        else:
            below, dev = dev, abs(s[j] - med)
            j += 1
    return 0.0 + dev if n % 2 else (0.0 + below + dev) / 2.0


MIN_INFORMATIVE_ROWS = 8
MIN_ROWS = 8
NEGATIVE_LAG_S = 0.02
"""The grid of lags starts this far below 0, so that a latency near 0 is a minimum inside it, not at its edge
(an edge is no estimate): a receiver and a reader with almost no delay, as in the lab."""


def parabolic_minimum(resid: np.ndarray, j: int, step_s: float) -> tuple[float, float]:
    """The parabola through resid[j - 1 .. j + 1] on a grid of step_s: its minimum's offset from the grid's j-th
    point, and its curvature (<= 0: no minimum, and the offset 0)."""
    r0, r1, r2 = resid[j - 1], resid[j], resid[j + 1]
    curv = (r0 - 2 * r1 + r2) / step_s**2
    return (0.5 * (r0 - r2) / (r0 - 2 * r1 + r2) * step_s if curv > 0 else 0.0), curv


class WheelLatency:
    """Grid search of the lag that aligns GPS distance with free-rolling wheel distance (see module docstring)."""

    def __init__(self, max_latency_s: float, step_s: float = 0.001, forgetting: float = 0.998,
                 slip_terms: bool = False) -> None:
        """slip_terms: the wheels slip in proportion to the acceleration (every wheel driven: no free-rolling one),
        y_k = x_k(tau) * (r + b_drive * max(a_k, 0) + b_brake * min(a_k, 0)), fitted per tau."""
        self.taus_s = np.arange(-NEGATIVE_LAG_S, max_latency_s + 0.5 * step_s, step_s)
        self.max_tau_s = float(self.taus_s[-1])
        self.step_s = step_s
        self.forgetting = forgetting
        self.slip_terms = slip_terms
        self._syy = 0.0
        self._sxy = np.zeros_like(self.taus_s)
        self._sxx = np.zeros_like(self.taus_s)
        self._terms = np.zeros((6, len(self.taus_s)))
        """With slip_terms, per tau: sum p*x^2, n*x^2, p^2*x^2, n^2*x^2, p*x*y, n*x*y (p, n: the acceleration's
        positive and negative parts)."""
        self.rows = 0
        self.informative_rows = 0
        self._weight = 0.0
        self.latency_s: float | None = None
        self.sigma_s: float | None = None
        self.radius_m: float | None = None

    def add(self, gps_distance_m: float, wheel_arc_m: np.ndarray, informative: bool = False,
            accel_mps2: float = 0.0) -> None:
        """One fix interval: GPS distance, and 2*pi*revolutions of the reference wheels for each lag on the grid;
        informative when taken while the speed changes; the acceleration for the slip terms."""
        lam = self.forgetting
        y, x = gps_distance_m, wheel_arc_m
        self._syy = lam * self._syy + y * y
        self._sxy = lam * self._sxy + y * x
        xx = x * x
        self._sxx = lam * self._sxx + xx
        if self.slip_terms:
            p, n = max(accel_mps2, 0.0), min(accel_mps2, 0.0)
            self._terms *= lam
            self._terms[0] += p * xx
            self._terms[1] += n * xx
            self._terms[2] += p * p * xx
            self._terms[3] += n * n * xx
            self._terms[4] += p * y * x
            self._terms[5] += n * y * x
        self._weight = lam * self._weight + 1.0
        self.rows += 1
        self.informative_rows += informative
        if self.rows >= MIN_ROWS and (self.rows % 5 == 0 or not self.converged()):  # every row until it converges
            self._solve()

    def residuals(self) -> tuple[np.ndarray, np.ndarray]:
        """Per tau (taus_s): the least-squares residual of the rows so far and the radius."""
        if not self.slip_terms:
            return self._syy - self._sxy**2 / self._sxx, self._sxy / self._sxx
        sxp, sxn, spp, snn, spy, sny = self._terms[:6]
        ridge = 1e-9 * self._sxx  # no rows with one sign of acceleration yet: that term stays 0
        a = np.zeros((len(self.taus_s), 3, 3))
        a[:, 0, 0], a[:, 1, 1], a[:, 2, 2] = self._sxx, spp + ridge, snn + ridge
        a[:, 0, 1] = a[:, 1, 0] = sxp
        a[:, 0, 2] = a[:, 2, 0] = sxn
        b = np.stack((self._sxy, spy, sny), axis=1)
        coef = np.linalg.solve(a, b[:, :, None])[:, :, 0]
        return self._syy - (coef * b).sum(axis=1), coef[:, 0]

    def _solve(self) -> None:
        if np.any(self._sxx <= 0):
            return
        resid, radius = self.residuals()
        j = int(np.argmin(resid))
        if j == 0 or j == len(resid) - 1:
            self.latency_s = self.sigma_s = None
            return
        offset, curv = parabolic_minimum(resid, j, self.step_s)
        if curv <= 0:
            return
        sigma2 = max(resid[j], 0.0) / max(self._weight - 2.0, 1.0)
        self.latency_s = max(float(self.taus_s[j] + offset), 0.0)  # a few ms below 0: timing noise about 0
        self.sigma_s = float(math.sqrt(2.0 * sigma2 / curv))
        self.radius_m = float(radius[j])

    def converged(self, sigma_max_s: float = 0.01) -> bool:
        return (
            self.informative_rows >= MIN_INFORMATIVE_ROWS
            and self.latency_s is not None and self.sigma_s is not None and self.sigma_s <= sigma_max_s
        )


LAG_GUARD_ROWS = 5
"""A latency row is used once this many later rows showed no braking (the central difference lags the onset)."""
LATENCY_MIN_SPEED_MPS = 0.5
"""Slowest fix interval used: the rows' information on the lag is a*dt whatever the speed, so the first second of a
start from standstill counts."""
NOMINAL_RADIUS_M = 0.3
"""Turns the wheels' arc into a speed for the braking test until the fit has a radius (+-20 % moves the test's
threshold by as much)."""
LOCAL_FIT_HALF_SAMPLES = 5
"""The wheels' revolutions at the lagged times come from a line through the 11 nearest samples: with linear
interpolation, the noise of jittered CAN timestamps depends on where a lag falls between samples, which biased the
lag by several ms (2 ms of jitter: 5 ms); a parabola is noisier under jitter (docs/accuracy.md, "Live runs in the
VM")."""
MAX_ROW_INTERVAL_S = 0.3
MAX_SLIP_TERMS_ACCEL_MPS2 = 4.0
"""Every wheel driven: rows while driving up to this acceleration (the tires' linear region, where the slip is in
proportion to the force); not while braking, whose slip on a loose surface is far from that (on the simulator's sand,
braking rows moved the lag by 39 ms)."""


class WheelLatencyRows:
    """The rows of the wheel-based latency fit: each fix interval against the free-rolling (reference) wheels, taken
    while they roll freely and not just before or after braking."""

    def __init__(self, fit: WheelLatency, every_wheel_driven: bool, max_latency_s: float,
                 window_s: float) -> None:
        self.fit = fit
        self.every_wheel_driven = every_wheel_driven
        self.max_latency_s = max_latency_s
        self.window_s = window_s
        """After braking, rows are skipped for max latency + window."""
        self._prev: tuple[float, float, np.ndarray] | None = None
        self._queue: deque[tuple[float, np.ndarray, bool]] = deque()
        self._blocked_until_s = -math.inf
        self._wheel_speed: float | None = None
        """The reference wheels' speed over the last fix interval (at lag 0)."""

    def observe(self, arrival_s: float, speed_mps: float, rings: list[SeriesRing]) -> None:
        """One fix (its smoothed arrival time and speed); rings: the reference wheels'. Whether the car brakes (or
        accelerates) is taken from the wheels' own acceleration over the last two fix intervals, not from the GPS
        speed: selecting rows by a noisy GPS acceleration selects their GPS noise too, and biased the lag."""
        fit = self.fit
        times = arrival_s - fit.taus_s
        first_needed_s = (arrival_s - fit.max_tau_s) - 0.5  # = times[-1] - 0.5
        arcs = np.empty(len(times))
        add = ring_revolutions()
        for k, ring in enumerate(rings):
            if not add(ring.times, ring.values, times, first_needed_s, arrival_s, LOCAL_FIT_HALF_SAMPLES, arcs, k == 0,
                       ring.dropped, *ring.line_cache(LOCAL_FIT_HALF_SAMPLES, len(times))):
                self._prev = None
                return
        arcs *= TWO_PI / len(rings)
        prev, self._prev = self._prev, (arrival_s, speed_mps, arcs)
        if prev is None:
            self._wheel_speed = None
            return
        a_prev, v_prev, arcs_prev = prev
        dt = arrival_s - a_prev
        if not dt > 0:
            self._wheel_speed = None
            return
        wheel_speed = (fit.radius_m or NOMINAL_RADIUS_M) * float(arcs[0] - arcs_prev[0]) / dt
        speed_before, self._wheel_speed = self._wheel_speed, wheel_speed
        if speed_before is None:
            return
        accel = (wheel_speed - speed_before) / dt
        thr = PHASE_ACCEL_MPS2  # the reference wheels roll freely unless the car brakes (all driven: or drives)
        if self.every_wheel_driven:  # driving: slip in proportion to the acceleration, in the fit (slip_terms)
            if -thr <= accel <= MAX_SLIP_TERMS_ACCEL_MPS2 and min(v_prev, speed_mps) >= LATENCY_MIN_SPEED_MPS \
                    and dt <= MAX_ROW_INTERVAL_S:
                fit.add(0.5 * (v_prev + speed_mps) * dt, arcs - arcs_prev, abs(accel) >= 0.5, accel)
            return
        free = accel >= -thr
        if not free:  # the reference wheels are braked: drop the rows just before, skip the rows just after
            self._queue.clear()
            self._blocked_until_s = arrival_s + self.max_latency_s + self.window_s
            return
        if arrival_s < self._blocked_until_s:
            return
        if min(v_prev, speed_mps) >= LATENCY_MIN_SPEED_MPS and dt <= MAX_ROW_INTERVAL_S:
            row = (0.5 * (v_prev + speed_mps) * dt, arcs - arcs_prev, accel >= 0.5)
            self._queue.append(row)
        while len(self._queue) > LAG_GUARD_ROWS:  # a row counts once the next rows show no braking
            fit.add(*self._queue.popleft())


def _ring_revolutions(t: np.ndarray, v: np.ndarray, times: np.ndarray, first_needed_s: float, arrival_s: float,
                      half: int, arcs: np.ndarray, first: bool, base: int, keys: np.ndarray, lines: np.ndarray) -> bool:
    """One reference wheel's revolutions at the lagged times (ring.local_linear's lines), into arcs (first: arcs =
    revs + 0.0, else arcs += revs); False, arcs as they were or partly written, where its samples (times t, values v)
    do not reach from first_needed_s to arrival_s, have a gap over gap_limit between the times, or are fewer
    than a line takes. base, keys, lines: the ring's line cache (SeriesRing.dropped, line_cache): a fix's lagged
    times share most of their lines with the fix before."""
    n = len(t)
    if n < 2 or t[0] > first_needed_s or t[n - 1] < arrival_s:
        return False
    if longest_gap_of(t, times[len(times) - 1], times[0]) > gap_limit(t) or n < 2 * half + 1:
        return False
    revs = np.empty(len(times))
    slopes = np.empty(len(times))
    cached_line_values(t, v, times, half, base, keys, lines, revs, slopes)
    for q in range(len(times)):
        arcs[q] = revs[q] + 0.0 if first else arcs[q] + revs[q]
    return True


ring_revolutions = kernel(_ring_revolutions, "boolean(float64[:], float64[:], float64[:], float64, float64, int64, "
                          "float64[:], boolean, int64, int64[:], float64[:, :])",
                          uses=(*LINE_USES, longest_gap_of, gap_limit))
"""ring_revolutions()(t, v, times, first_needed_s, arrival_s, half, arcs, first, base, keys, lines): see
_ring_revolutions (WheelLatencyRows.observe)."""
