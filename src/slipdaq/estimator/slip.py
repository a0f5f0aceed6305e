"""Windowed longitudinal slip, effective rolling radius Re, force Fx and stiffness Cx (docs/method.md).

For a window [t_c - W/2, t_c + W/2] centred on GPS epoch c, at its fix time t_c = arrival time - GPS latency, where
the arrival time of a fix with a UTC time is that time plus the median (arrival - UTC) of recent fixes: the
receiver's own clock, free of the jitter with which sentences are read:
  d_gps = integral of GPS speed (piecewise linear between fixes)
  N     = rev(t1) - rev(t0)                                  wheel revolutions (counts/ppr, interpolated linearly)
  d_wpt = r0 * 2*pi * N                                      distance by wheel revolutions, r0 calibrated per wheel
  s     = (d_wpt - d_gps) / d_gps                            SAE slip: > 0 driving, < 0 braking
  Re    = d_gps / (2*pi*N)                                   = V / omega
  a(c)  = (v(c+1) - v(c-1)) / (t(c+1) - t(c-1))             central difference of GPS speed
  Fx    = M*a [+ f_rr*M*g + rho/2*CdA*v^2 + M*g*sin(grade)]  per tire: driven axle when Fx >= 0, brake share else
  Cx    = Fx_tire / s  per window (cx_slip_min <= |s| <= cx_slip_max), and a fitted Cx over the run (stiffness.py)
Latency (latency.py) and r0 (radius.py) are estimated here too. Pure: records in, estimates out, deterministic in
the order records are given. No clock, no I/O.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from collections import deque
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from slipdaq import WHEELS
from slipdaq.config import Config
from slipdaq.estimator.latency import LatencyEstimate, UtcLatency, WheelLatency
from slipdaq.estimator.radius import RadiusCalibration
from slipdaq.estimator.readiness import (
    MODE_READY,
    MODE_WAIT,
    MODE_WHEELS,
    SCAN_GPS_LOST,
    SCAN_READY,
    head_ready,
    scan,
)
from slipdaq.estimator.ring import SeriesRing
from slipdaq.estimator.stiffness import StiffnessFit
from slipdaq.records import Estimate, GpsFix, WheelEstimate, WheelSample

TWO_PI = 2.0 * math.pi
G_MPS2 = 9.81
WHEEL_ONLY_STEP_S = 0.1
REFERENCE_SPEED_ACCURACY_MPS = 0.05
"""A window whose fixes state this speed accuracy (1 sigma) has weight 1 in the r0 and Cx fits; weight ~ 1/sigma^2."""
WHEEL_INDEX = {w: i for i, w in enumerate(WHEELS)}
LAG_GUARD_ROWS = 5
"""A latency row is used once this many later rows showed no braking (the central difference lags the onset)."""
TIME_TOL_S = 1e-5
"""GPS times this close count as equal when a window's ends are compared with fixes: the fix that ends a window
(UTC + offset - latency) and the window's end (centre + W/2) are the same instant computed two ways, and float
rounding (a few ulps: 2.4e-7 s at today's epoch seconds) must not decide whether an estimate waits for one more fix."""


PHASE_ACCEL_MPS2 = 0.3
"""|a| above this is accelerating or braking; below it, cruising (or coasting)."""
STANDSTILL_SPEED_MPS = 0.5
"""Below this GPS speed the car stands still."""
MAX_GPS_GAP_S = 1.0
"""GPS fixes further apart than this do not make a window or a central difference."""


@dataclass(frozen=True, slots=True)
class EstimatorParams:
    """The estimator's inputs from the config, flat. No defaults here: they are the config models' (config.py)."""

    window_s: float
    min_speed_mps: float
    cx_slip_min: float
    cx_slip_max: float
    mass_kg: float
    driven_axle: str
    brake_front_share: float
    pulses_per_rev: int
    r_ref_m: float
    r_ref_configured: bool
    """True when r_ref is tire.free_radius_m rather than the tire size."""
    gps_latency_s: float | None
    """Fixed GPS latency; None estimates it online ('auto')."""
    max_latency_s: float
    calibrate_r0: bool
    r0_min_speed_mps: float
    fit_min_speed_mps: float
    rolling_resistance_coeff: float
    drag_area_m2: float
    air_density_kgpm3: float
    grade_from_altitude: bool

    @classmethod
    def from_config(cls, cfg: Config, **overrides: Any) -> EstimatorParams:
        """The parameters of cfg; overrides replace single values (tests)."""
        v, e = cfg.vehicle, cfg.estimator
        return replace(cls(
            window_s=e.window_s, min_speed_mps=e.min_speed_mps, cx_slip_min=e.cx_slip_min, cx_slip_max=e.cx_slip_max,
            mass_kg=v.mass_kg, driven_axle=v.driven_axle, brake_front_share=v.brake_front_share,
            pulses_per_rev=cfg.wpt.pulses_per_rev, r_ref_m=cfg.tire.radius_m,
            r_ref_configured=cfg.tire.free_radius_m is not None, gps_latency_s=cfg.latency_fixed_s,
            max_latency_s=e.max_latency_s, calibrate_r0=e.calibrate_r0, r0_min_speed_mps=e.r0_min_speed_mps,
            fit_min_speed_mps=e.fit_min_speed_mps, rolling_resistance_coeff=v.rolling_resistance_coeff,
            drag_area_m2=v.drag_area_m2, air_density_kgpm3=v.air_density_kgpm3,
            grade_from_altitude=e.grade_from_altitude,
        ), **overrides)


def driven_wheels(driven_axle: str) -> tuple[str, ...]:
    return {"front": ("FL", "FR"), "rear": ("RL", "RR"), "all": WHEELS}[driven_axle]


def tire_forces(fx_n: float, driven_axle: str, brake_front_share: float) -> dict[str, float]:
    """Split the total force: evenly over the driven wheels when Fx >= 0, by brake_front_share when Fx < 0."""
    if fx_n >= 0:
        driven = driven_wheels(driven_axle)
        return {w: (fx_n / len(driven) if w in driven else 0.0) for w in WHEELS}
    front = fx_n * brake_front_share / 2.0
    rear = fx_n * (1.0 - brake_front_share) / 2.0
    return {"FL": front, "FR": front, "RL": rear, "RR": rear}


def slip_from_distances(d_wpt_m: float, d_gps_m: float) -> float:
    """s = (d_wpt - d_gps) / d_gps."""
    return (d_wpt_m - d_gps_m) / d_gps_m


def integrate_speed_m(times_s: np.ndarray, speeds_mps: np.ndarray, t0: float, t1: float) -> float:
    """Integral of the piecewise-linear speed over [t0, t1] (trapezoids on the fixes plus both ends)."""
    i0 = int(np.searchsorted(times_s, t0, side="right"))
    i1 = int(np.searchsorted(times_s, t1, side="left"))
    t = np.concatenate(([t0], times_s[i0:i1], [t1]))
    v = np.interp(t, times_s, speeds_mps)
    return float(np.sum((t[1:] - t[:-1]) * (v[1:] + v[:-1])) * 0.5)


def _div(a: float, b: float) -> float:
    """a / b with numpy's float64 result for b == 0 (inf or nan) instead of ZeroDivisionError."""
    if b != 0.0:
        return a / b
    if a == 0.0 or a != a:
        return math.nan
    return math.copysign(math.inf, a) * math.copysign(1.0, b)


def phase_of(speed_mps: float, accel_mps2: float | None) -> str:
    """standstill below STANDSTILL_SPEED_MPS; accelerate / brake beyond +-PHASE_ACCEL_MPS2; cruise otherwise."""
    if speed_mps < STANDSTILL_SPEED_MPS:
        return "standstill"
    if accel_mps2 is None or abs(accel_mps2) <= PHASE_ACCEL_MPS2:
        return "cruise"
    return "accelerate" if accel_mps2 > 0 else "brake"


def _smooth_arrival(arrival_s: float, utc_s: float, offset_s: float | None) -> float:
    """One fix's arrival time without read jitter: UTC + median(arrival - UTC) where it has a UTC time (NaN: none);
    SlipEstimator._smooth_arrivals for all fixes at once."""
    return arrival_s if offset_s is None or utc_s != utc_s else utc_s + offset_s


class SlipEstimator:
    """Feed wheel samples and GPS fixes in record order; each call returns the estimates that became ready.

    An estimate is centred on every valid GPS epoch and is ready when GPS and every wheel that is reporting have
    samples past the window's end (or GPS is a further window past it, for a silent wheel).
    """

    def __init__(self, params: EstimatorParams) -> None:
        self.p = params
        self._gps = SeriesRing(256)  # arrival time -> speed
        self._gps_utc = SeriesRing(256)  # arrival time -> the fix's UTC time (NaN without one); kept in step
        self._gps_acc = SeriesRing(256)  # arrival time -> the receiver's speed accuracy (NaN without one); in step
        self._alt = SeriesRing(256)  # arrival time -> altitude
        self._wheels = {w: SeriesRing(4096) for w in WHEELS}
        self._pending: deque[tuple[float, float]] = deque()  # epochs still to estimate: (arrival, UTC or NaN)
        self._last_utc_s = math.nan  # the newest fix's UTC time (NaN without one)
        self._utc = UtcLatency(params.max_latency_s)
        self._lag = WheelLatency(params.max_latency_s)
        self._lag_prev: tuple[float, float, np.ndarray] | None = None
        self._lag_queue: deque[tuple[float, np.ndarray, bool]] = deque()
        self._lag_blocked_until_s = -math.inf
        self._radius = {w: RadiusCalibration() for w in WHEELS}
        self._stiffness = {w: StiffnessFit() for w in WHEELS}
        self._driven = driven_wheels(params.driven_axle)
        self._reference = tuple(w for w in WHEELS if w not in self._driven)
        self._next_wheel_only_s: float | None = None
        self._last_center_s = -math.inf
        self._latency: LatencyEstimate | None = None
        self._utc_offset_s: float | None = None
        self.rejected_fixes = 0
        self._rings = [self._wheels[w] for w in WHEELS]  # by wheel index (WHEELS order)
        self._head: tuple[int, float, float] | None = None  # the head epoch's readiness constants (_head_consts)

    # ---- latency ------------------------------------------------------------------------------------
    @property
    def latency(self) -> LatencyEstimate:
        """The GPS latency in use (cached; it changes only when a fix or an estimate comes)."""
        if self._latency is None:
            self._latency = self._current_latency()
            self._utc_offset_s = self._utc.offset_s()
        return self._latency

    def _current_latency(self) -> LatencyEstimate:
        utc = self._utc.estimate()
        lag = self._lag
        wheels = lag.latency_s if lag.converged() else None
        if self.p.gps_latency_s is not None:
            return LatencyEstimate(self.p.gps_latency_s, "fixed", utc, wheels, lag.sigma_s)
        if wheels is not None and (utc is None or abs(utc - wheels) > 3.0 * (lag.sigma_s or 0.0) + 0.02):
            # measured alignment beats an assumption about the host clock when the two disagree
            return LatencyEstimate(wheels, "wheels", utc, wheels, lag.sigma_s)
        if utc is not None:
            return LatencyEstimate(utc, "utc", utc, wheels, lag.sigma_s)
        return LatencyEstimate(0.0, "none", utc, wheels, lag.sigma_s)

    # ---- input -------------------------------------------------------------------------------------
    def add_wheel(self, sample: WheelSample) -> list[Estimate]:
        return self.add_wheel_at(WHEEL_INDEX[sample.wheel], sample.timestamp_s, sample.revolutions)

    def add_wheel_at(self, wheel: int, time_s: float, revolutions: float) -> list[Estimate]:
        """One wheel sample (wheel: index in WHEELS): a batch of one."""
        return [e for _, e in self.add_wheels(np.array([wheel]), np.array([time_s], dtype=np.float64),
                                              np.array([revolutions], dtype=np.float64))]

    def add_wheels(
        self, wheel: np.ndarray, time_s: np.ndarray, revolutions: np.ndarray
    ) -> list[tuple[int, Estimate]]:
        """Wheel samples in record order (wheel: indices in WHEELS; times and revolutions float64); returns (index of
        the sample whose arrival released it, estimate) in order. The estimates and the state afterwards do not
        depend on how the samples are cut into batches (estimator/readiness.py scans them one by one)."""
        n = len(time_s)
        out: list[tuple[int, Estimate]] = []
        if n == 0:
            return out
        wheel = np.asarray(wheel, dtype=np.int64)
        last_t = np.array([r.last_t for r in self._rings], dtype=np.float64)
        keep = np.empty(n, dtype=np.bool_)
        run = scan(n)
        pos = 0
        while pos < n:
            mode, need, since = (self._head or self._head_consts()) if self._pending else (MODE_WAIT, 0.0, 0.0)
            k, why = run(wheel, time_s, pos, last_t, keep, self._gps.last_t, mode, need, since)
            stop = min(k + 1, n)
            self._append(wheel, time_s, revolutions, keep, pos, stop)
            if why == SCAN_READY:
                out += [(k, e) for e in self._drain()]
            elif why == SCAN_GPS_LOST:
                out += [(k, e) for e in self._gps_lost()]
            pos = stop
        return out

    def _append(self, wheel: np.ndarray, time_s: np.ndarray, revolutions: np.ndarray, keep: np.ndarray,
                start: int, stop: int) -> None:
        """The kept samples start..stop into their wheels' rings."""
        if stop - start == 1:
            if keep[start]:
                self._rings[wheel[start]].append(time_s[start], revolutions[start])
            return
        w, kept = wheel[start:stop], keep[start:stop]
        for i, ring in enumerate(self._rings):
            mine = kept & (w == i)
            if mine.any():
                ring.extend(time_s[start:stop][mine], revolutions[start:stop][mine])

    def add_gps(self, fix: GpsFix) -> list[Estimate]:
        if not fix.valid or not math.isfinite(fix.speed_mps):
            self.rejected_fixes += 1
            return []
        a = fix.timestamp_s
        if a <= self._gps.last_time:
            self.rejected_fixes += 1
            return []
        utc = fix.fix_time_utc_s
        if utc is not None and not math.isfinite(utc):
            utc = None  # a NaN or infinite UTC time is no UTC time
        self._utc.add(a, utc)
        self._gps.append(a, fix.speed_mps)
        utc_s = float(utc) if utc is not None else math.nan
        self._gps_utc.append(a, utc_s)
        self._last_utc_s = utc_s
        self._gps_acc.append(a, fix.speed_accuracy_mps if fix.speed_accuracy_mps is not None else math.nan)
        self._latency = None
        self._head = None
        if fix.altitude_m is not None and self.p.grade_from_altitude:
            self._alt.append(a, fix.altitude_m)
        self._pending.append((a, utc_s))
        self._next_wheel_only_s = None
        return self._drain()

    # ---- readiness ----------------------------------------------------------------------------------
    def _reporting(self, since_s: float) -> list[SeriesRing]:
        return [r for r in self._wheels.values() if len(r) and r.last_time >= since_s]

    def _head_consts(self) -> tuple[int, float, float]:
        """The head epoch's readiness as (mode, need, since) (estimator/readiness.py), cached until a fix, an
        estimate or GPS loss."""
        lat = self.latency.latency_s
        arrival_s, utc_s = self._pending[0]
        half = 0.5 * self.p.window_s
        offset = self._utc_offset_s
        t1 = _smooth_arrival(arrival_s, utc_s, offset) - lat + half
        gps_last = _smooth_arrival(self._gps.last_t, self._last_utc_s, offset) - lat  # on t1's time line
        if gps_last < t1 - TIME_TOL_S:
            head = (MODE_WAIT, 0.0, 0.0)
        elif gps_last >= t1 + max(self.p.window_s, 0.5):
            head = (MODE_READY, 0.0, 0.0)
        else:
            head = (MODE_WHEELS, max(t1, arrival_s) if self.p.gps_latency_s is None else t1, t1 - 3 * half)
        self._head = head
        return head

    def waiting_for_wheels(self) -> bool:
        """The oldest pending estimate has its GPS and waits only for wheel samples past its window's end."""
        return bool(self._pending) and (self._head or self._head_consts())[0] == MODE_WHEELS

    def _ready(self) -> bool:
        """The head epoch (self._pending[0]) can be estimated now."""
        return head_ready([r.last_t for r in self._rings], *(self._head or self._head_consts()))

    def _drain(self) -> list[Estimate]:
        out: list[Estimate] = []
        while self._pending:
            if not self._ready():
                break
            lat = self.latency
            rows = self._lag.rows
            out.append(self._estimate(self._pending.popleft()[0], lat))
            if self._lag.rows != rows:
                self._latency = None  # the estimate moved the wheels' latency fit
            self._head = None
        first = self._pending[0][0] if self._pending else self._gps.last_time
        keep = first - self.p.max_latency_s - self.p.window_s - MAX_GPS_GAP_S - 2.0
        self._gps.drop_before = keep
        self._gps_utc.drop_before = keep
        self._gps_acc.drop_before = keep
        self._alt.drop_before = keep
        for r in self._wheels.values():
            r.drop_before = keep
        return out

    # ---- helpers ------------------------------------------------------------------------------------
    def _smooth_arrivals(self) -> np.ndarray:
        """Arrival times with the read jitter taken out: UTC + median(arrival - UTC) where the fix has a UTC time."""
        arrivals = self._gps.times
        offset = self._utc_offset_s
        if offset is None:
            return arrivals
        utc = self._gps_utc.values
        return np.where(np.isnan(utc), arrivals, utc + offset)

    def _gps_covers(self, fix_times: list[float], t0: float, t1: float) -> bool:
        if len(fix_times) < 2 or fix_times[0] > t0 + TIME_TOL_S or fix_times[-1] < t1 - TIME_TOL_S:
            return False
        i0 = max(bisect_right(fix_times, t0) - 1, 0)
        i1 = bisect_left(fix_times, t1)
        seg = fix_times[i0 : i1 + 1]
        return max([b - a for a, b in zip(seg, seg[1:])]) <= MAX_GPS_GAP_S

    def _accel(self, fix_times: list[float], speeds: list[float], t_c: float) -> float | None:
        i = bisect_left(fix_times, t_c)
        if i < 1 or i + 1 >= len(fix_times) or fix_times[i + 1] - fix_times[i - 1] > 2 * MAX_GPS_GAP_S:
            return None
        return _div(speeds[i + 1] - speeds[i - 1], fix_times[i + 1] - fix_times[i - 1])

    def _arc_m(self, w: str, t0: float, t1: float) -> float | None:
        """2*pi*revolutions of wheel w over [t0, t1], or None without samples around both ends."""
        ring = self._wheels[w]
        if len(ring) < 2 or ring.first_time > t0 or ring.last_time < t1:
            return None
        rev0, rev1 = np.interp((t0, t1), ring.times, ring.values).tolist()
        return TWO_PI * (rev1 - rev0)

    def _arcs_m(self, t0: float, t1: float) -> dict[str, float | None]:
        """_arc_m of every wheel over the same window."""
        ends = np.array((t0, t1))
        out: dict[str, float | None] = {}
        for w, ring in self._wheels.items():
            revs = ring.at(ends, t0, t1)
            out[w] = None if revs is None else TWO_PI * (revs[1] - revs[0])
        return out

    def _grade_sin(
        self, fix_times: list[float], fix_arr: np.ndarray, t_c: float, latency_s: float,
    ) -> float:
        """sin(grade) from GPS altitude over the last 2 s (backward, so no wait for future fixes)."""
        if not self.p.grade_from_altitude or len(self._alt) < 2:
            return 0.0
        alt_t = self._alt.times - latency_s
        t_a = t_c - 2.0
        if alt_t[0] > t_a or alt_t[-1] < t_c or not self._gps_covers(fix_times, t_a, t_c):
            return 0.0
        climb = float(np.interp(t_c, alt_t, self._alt.values) - np.interp(t_a, alt_t, self._alt.values))
        dist = integrate_speed_m(fix_arr, self._gps.values, t_a, t_c)
        return max(-0.3, min(0.3, climb / dist)) if dist > 5.0 else 0.0

    def _weight(self, fix_times: list[float], t0: float, t1: float) -> float:
        """(reference / stated speed accuracy)^2 over the window's fixes, within 0.1..10; 1 without a stated one."""
        i0 = bisect_left(fix_times, t0)
        # as np.searchsorted(fix_times, (t0, t1)): the second key's search starts where the first one ended
        i1 = bisect_left(fix_times, t1, i0) if t0 < t1 else bisect_left(fix_times, t1, 0, min(i0 + 1, len(fix_times)))
        acc = [x for x in self._gps_acc.values[i0 : i1 + 1].tolist() if x == x]
        if not acc:
            return 1.0
        sigma = max(float(np.sum(acc)) / len(acc), 1e-3)
        return min(max((REFERENCE_SPEED_ACCURACY_MPS / sigma) ** 2, 0.1), 10.0)

    def _force(self, accel: float, speed: float, sin_grade: float) -> float:
        """Fx = M*a + f_rr*M*g*cos + rho/2*CdA*v^2 + M*g*sin (each term off unless configured)."""
        p = self.p
        cos_grade = math.sqrt(1.0 - sin_grade * sin_grade)
        return (
            p.mass_kg * accel
            + p.rolling_resistance_coeff * p.mass_kg * G_MPS2 * cos_grade
            + 0.5 * p.air_density_kgpm3 * p.drag_area_m2 * speed * speed
            + p.mass_kg * G_MPS2 * sin_grade
        )

    def _r0(self, w: str) -> tuple[float, str]:
        return self._r0_all()[w]

    def _r0_all(self) -> dict[str, tuple[float, str]]:
        """(r0, source) per wheel: its calibration when usable, else the usable ones' mean, else the reference."""
        p = self.p
        base = "configured" if p.r_ref_configured else "tire_size"
        if not p.calibrate_r0:
            return {w: (p.r_ref_m, base) for w in self._radius}
        usable = {}  # wheel -> (radius, converged) of the usable calibrations, in wheel order
        for w, cal in self._radius.items():
            radius = cal.radius_m
            if radius is not None and cal.usable:
                usable[w] = (radius, cal.converged)
        others = [r for r, _ in usable.values()]
        fallback = (sum(others) / len(others), "other_wheels") if others else (p.r_ref_m, base)
        return {
            w: ((u[0], "calibrated" if u[1] else "calibrating") if (u := usable.get(w)) is not None else fallback)
            for w in self._radius
        }

    def _free_rolling(self, w: str, accel: float) -> bool:
        """The tire carries little force: a non-driven wheel when not braking, any wheel when coasting."""
        thr = PHASE_ACCEL_MPS2
        return abs(accel) <= thr or (w in self._reference and accel >= -thr)

    def _update_lag(self, arrival_s: float, speed_mps: float, accel: float | None) -> None:
        """One row of the wheel-based latency fit: this fix interval against the free-rolling wheels."""
        refs = self._reference or WHEELS
        lag = self._lag
        times = arrival_s - lag.taus_s
        first_needed_s = (arrival_s - lag.max_tau_s) - 0.5  # = times[-1] - 0.5
        arcs: np.ndarray | None = None
        for w in refs:
            ring = self._wheels[w]
            if len(ring) < 2 or ring.first_time > first_needed_s:
                self._lag_prev = None
                return
            revs = np.interp(times, ring.times, ring.values)
            if arcs is None:
                arcs = revs + 0.0  # as zeros + revs
            else:
                arcs += revs
        assert arcs is not None
        arcs *= TWO_PI / len(refs)
        prev, self._lag_prev = self._lag_prev, (arrival_s, speed_mps, arcs)
        if prev is None or accel is None:
            return
        a_prev, v_prev, arcs_prev = prev
        thr = PHASE_ACCEL_MPS2
        free = accel >= -thr if self._reference else abs(accel) <= thr
        if not free:  # the reference wheels are braked: drop the rows just before, skip the rows just after
            self._lag_queue.clear()
            self._lag_blocked_until_s = arrival_s + self.p.max_latency_s + self.p.window_s
            return
        if arrival_s < self._lag_blocked_until_s:
            return
        if min(v_prev, speed_mps) >= self.p.r0_min_speed_mps and arrival_s - a_prev <= 0.3:
            row = (0.5 * (v_prev + speed_mps) * (arrival_s - a_prev), arcs - arcs_prev, accel >= 0.5)
            self._lag_queue.append(row)
        while len(self._lag_queue) > LAG_GUARD_ROWS:  # a row counts once the next rows show no braking
            lag.add(*self._lag_queue.popleft())

    # ---- the estimate -------------------------------------------------------------------------------
    def _estimate(self, arrival_s: float, lat: LatencyEstimate) -> Estimate:
        p = self.p
        smooth = self._smooth_arrivals()
        i = int(self._gps.times.searchsorted(arrival_s))
        latency_s = lat.latency_s
        fix_arr = smooth - latency_s
        fix_times, speeds = fix_arr.tolist(), self._gps.values.tolist()
        t_c = fix_times[i]
        t0, t1 = t_c - 0.5 * p.window_s, t_c + 0.5 * p.window_s
        speed_c = speeds[i]
        accel = self._accel(fix_times, speeds, t_c)
        if p.gps_latency_s is None:
            self._update_lag(float(smooth[i]), speed_c, accel)
        covered = self._gps_covers(fix_times, t0, t1)
        d_gps = integrate_speed_m(fix_arr, self._gps.values, t0, t1) if covered else None
        speed = d_gps / p.window_s if d_gps is not None else speed_c
        force = None
        if accel is not None:
            force = self._force(accel, speed, self._grade_sin(fix_times, fix_arr, t_c, lat.latency_s))
        per_tire = tire_forces(force, p.driven_axle, p.brake_front_share) if force is not None else {}
        arcs = self._arcs_m(t0, t1)
        weight = self._weight(fix_times, t0, t1)
        if p.calibrate_r0 and accel is not None and d_gps is not None and speed >= p.r0_min_speed_mps:
            # While accelerating, the GPS latency must be known; at steady speed it does not matter.
            steady = abs(accel) <= PHASE_ACCEL_MPS2
            for w in WHEELS:
                arc = arcs[w]
                if arc is not None and self._free_rolling(w, accel) and (steady or lat.source != "none"):
                    self._radius[w].add(d_gps, arc, weight)
        r0 = self._r0_all()
        slip_nd = self._reference_slip(arcs, r0)
        wheels = {w: self._wheel(w, arcs[w], r0[w], d_gps, per_tire.get(w), speed, weight, slip_nd.get(w))
                  for w in WHEELS}
        self._last_center_s = t_c
        return Estimate(
            t_c, speed, accel, force, p.window_s, wheels,
            phase=phase_of(speed, accel),
            source="gps", gps_latency_s=lat.latency_s, latency_source=lat.source,
        )

    def _wheel(
        self, w: str, arc: float | None, r0: tuple[float, str], d_gps: float | None, force: float | None,
        speed: float, weight: float = 1.0, slip_nd: float | None = None,
    ) -> WheelEstimate:
        p = self.p
        r0_m, r0_source = r0
        fit = self._stiffness[w]
        if arc is None:
            return WheelEstimate(None, None, r0_m, None, force, None, r0_source, None, fit.cx_n, fit.confidence)
        d_wpt = r0_m * arc
        wheel_speed = d_wpt / p.window_s
        if d_gps is None or d_gps < p.min_speed_mps * p.window_s or arc <= 0:
            return WheelEstimate(None, None, r0_m, None, force, wheel_speed, r0_source, slip_nd, fit.cx_n,
                                 fit.confidence)
        slip = slip_from_distances(d_wpt, d_gps)
        re = d_gps / arc
        cx = None
        if force is not None and force != 0 and p.cx_slip_min <= abs(slip) <= p.cx_slip_max and force / slip > 0:
            cx = force / slip
        if force is not None and speed >= p.fit_min_speed_mps and abs(slip) <= p.cx_slip_max:
            fit.add(force, arc / d_gps, weight)
        return WheelEstimate(slip, re, r0_m, cx, force, wheel_speed, r0_source, slip_nd, fit.cx_n,
                             fit.confidence if fit.cx_n is not None else None)

    def _reference_slip(
        self, arcs: dict[str, float | None], r0: dict[str, tuple[float, str]],
    ) -> dict[str, float]:
        """Driven wheels' slip against the mean distance of the non-driven wheels (valid while those roll freely),
        for the driven wheels that have one."""
        refs = [r0[w][0] * arcs[w] for w in self._reference if arcs[w] is not None]  # type: ignore[operator]  # arcs[w] is checked for None in the same expression
        if not refs or len(refs) < len(self._reference):
            return {}
        d_ref = sum(refs) / len(refs)
        if d_ref < self.p.min_speed_mps * self.p.window_s:
            return {}
        return {w: slip_from_distances(r0[w][0] * arc, d_ref) for w in self._driven if (arc := arcs[w]) is not None}

    def _with_reference_slip(
        self, wheels: dict[str, WheelEstimate], arcs: dict[str, float | None], r0: dict[str, tuple[float, str]],
    ) -> dict[str, WheelEstimate]:
        """The wheels' estimates with the driven wheels' reference slip (_reference_slip) set."""
        slip_nd = self._reference_slip(arcs, r0)
        if not slip_nd:
            return wheels
        out = dict(wheels)
        for w, s_nd in slip_nd.items():
            e = wheels[w]
            out[w] = WheelEstimate(e.slip, e.re_m, e.r0_m, e.cx_n, e.force_n, e.speed_mps, e.r0_source,
                                   s_nd, e.cx_fit_n, e.cx_fit_conf)
        return out

    # ---- GPS lost: estimates on the wheels' clock -----------------------------------------------------
    def _gps_lost(self) -> list[Estimate]:
        """Epochs that will get no later fix are estimated with what there is; then the wheels' clock takes over."""
        out: list[Estimate] = []
        lat = self.latency
        while self._pending:
            out.append(self._estimate(self._pending.popleft()[0], lat))
        self._head = None
        return out + self._wheel_only()

    def _wheel_only(self) -> list[Estimate]:
        """Every WHEEL_ONLY_STEP_S while GPS is lost: wheel speeds, accel from the reference wheels, slip_nd."""
        p = self.p
        half = 0.5 * p.window_s
        rings = self._reporting(-math.inf)
        if not rings:
            return []
        covered = min(r.last_time for r in rings)
        if self._next_wheel_only_s is None:
            start = max(self._last_center_s, self._gps.last_time) + WHEEL_ONLY_STEP_S
            self._next_wheel_only_s = max(start, max(r.first_time for r in rings) + half)
        out: list[Estimate] = []
        lat = self.latency
        while self._next_wheel_only_s + half <= covered:
            t_c = self._next_wheel_only_s
            self._next_wheel_only_s = t_c + WHEEL_ONLY_STEP_S
            out.append(self._wheel_only_estimate(t_c, lat))
        return out

    def _wheel_only_estimate(self, t_c: float, lat: LatencyEstimate) -> Estimate:
        p = self.p
        half = 0.5 * p.window_s
        refs = self._reference or WHEELS
        r0 = self._r0_all()

        def ref_distance(a: float, b: float) -> float | None:
            ds = [r0[w][0] * arc for w in refs if (arc := self._arc_m(w, a, b)) is not None]
            return sum(ds) / len(ds) if ds else None

        d = ref_distance(t_c - half, t_c + half)
        first, second = ref_distance(t_c - half, t_c), ref_distance(t_c, t_c + half)
        speed = d / p.window_s if d is not None else 0.0
        accel = (second - first) / (half * half) if first is not None and second is not None else None
        arcs = {w: self._arc_m(w, t_c - half, t_c + half) for w in WHEELS}
        wheels = {
            w: WheelEstimate(None, None, r0[w][0], None, None,
                             r0[w][0] * arcs[w] / p.window_s if arcs[w] is not None else None,  # type: ignore[operator]  # arcs[w] is checked for None in the same expression
                             r0[w][1])
            for w in WHEELS
        }
        wheels = self._with_reference_slip(wheels, arcs, r0)
        self._last_center_s = t_c
        return Estimate(t_c, speed, accel, None, p.window_s, wheels,
                        phase=phase_of(speed, accel),
                        source="wheels", gps_latency_s=lat.latency_s, latency_source=lat.source)

    # ---- state for diagnostics ----------------------------------------------------------------------
    def status(self) -> dict[str, object]:
        lat = self.latency
        return {
            "gps_latency_s": lat.latency_s,
            "latency_source": lat.source,
            "gps_latency_utc_s": lat.utc_s,
            "gps_latency_wheels_s": self._lag.latency_s,
            "gps_latency_wheels_sigma_s": lat.wheels_sigma_s,
            "r0_m": {w: self._r0(w)[0] for w in WHEELS},
            "r0_source": {w: self._r0(w)[1] for w in WHEELS},
            "r0_se_m": {w: self._radius[w].standard_error_m for w in WHEELS},
            "cx_fit_n": {w: self._stiffness[w].cx_n for w in WHEELS},
            "cx_fit_conf": {w: self._stiffness[w].confidence for w in WHEELS},
            "rejected_fixes": self.rejected_fixes,
        }
