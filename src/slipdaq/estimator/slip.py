"""Windowed longitudinal slip, effective rolling radius Re, force Fx and stiffness Cx (docs/method.md).

For a window [t_c - W/2, t_c + W/2] centred on GPS epoch c:
  d_gps = integral of GPS speed (piecewise linear between fixes)
  N     = (count(t1) - count(t0)) / pulses_per_rev          wheel revolutions (counts interpolated linearly)
  d_wpt = r_ref * 2*pi * N                                   distance by wheel revolutions
  s     = (d_wpt - d_gps) / d_gps                            SAE slip: > 0 driving, < 0 braking
  Re    = d_gps / (2*pi*N)                                   = V / omega
  a(c)  = (v(c+1) - v(c-1)) / (t(c+1) - t(c-1))             central difference of GPS speed
  Fx    = M * a;  per tire: driven axle share when Fx >= 0, brake_front_share when Fx < 0
  Cx    = Fx_tire / s                                        only for cx_slip_min <= |s| <= cx_slip_max
Pure: records in, estimates out, deterministic in the order records are given. No clock, no I/O.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from slipdaq import WHEELS
from slipdaq.config import Config
from slipdaq.estimator.ring import SeriesRing
from slipdaq.records import Estimate, GpsFix, WheelEstimate, WheelSample

TWO_PI = 2.0 * math.pi


@dataclass(frozen=True, slots=True)
class EstimatorParams:
    window_s: float = 0.5
    min_speed_mps: float = 1.0
    cx_slip_min: float = 0.005
    cx_slip_max: float = 0.10
    mass_kg: float = 1300.0
    driven_axle: str = "front"
    brake_front_share: float = 0.7
    pulses_per_rev: int = 1000
    r_ref_m: float = 0.3075
    gps_latency_s: float = 0.0
    max_gps_gap_s: float = 1.0
    """GPS fixes further apart than this do not make a window or a central difference."""

    @classmethod
    def from_config(cls, cfg: Config) -> "EstimatorParams":
        return cls(
            window_s=cfg.estimator.window_s,
            min_speed_mps=cfg.estimator.min_speed_mps,
            cx_slip_min=cfg.estimator.cx_slip_min,
            cx_slip_max=cfg.estimator.cx_slip_max,
            mass_kg=cfg.vehicle.mass_kg,
            driven_axle=cfg.vehicle.driven_axle,
            brake_front_share=cfg.vehicle.brake_front_share,
            pulses_per_rev=cfg.wpt.pulses_per_rev,
            r_ref_m=cfg.tire.radius_m,
            gps_latency_s=cfg.latency_fixed_s,
        )


def tire_forces(fx_n: float, driven_axle: str, brake_front_share: float) -> dict[str, float]:
    """Split the total force: evenly over the driven wheels when Fx >= 0, by brake_front_share when Fx < 0."""
    if fx_n >= 0:
        driven = {"front": ("FL", "FR"), "rear": ("RL", "RR"), "all": WHEELS}[driven_axle]
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


class SlipEstimator:
    """Feed wheel samples and GPS fixes in record order; each call returns the estimates that became ready.

    An estimate is centred on every valid GPS epoch and is ready when GPS and every wheel that is
    reporting have samples past the window's end (or GPS is a further window past it, for a silent wheel).
    """

    def __init__(self, params: EstimatorParams) -> None:
        self.p = params
        self._gps = SeriesRing(256)
        self._wheels = {w: SeriesRing(4096) for w in WHEELS}
        self._pending: deque[float] = deque()
        self.rejected_fixes = 0

    # ---- input -------------------------------------------------------------------------------------
    def add_wheel(self, sample: WheelSample) -> list[Estimate]:
        ring = self._wheels[sample.wheel]
        if sample.timestamp_s < ring.last_time:
            return []  # out of order: keep the ring monotonic
        ring.append(sample.timestamp_s, float(sample.count))
        return self._drain() if self._pending else []

    def add_gps(self, fix: GpsFix) -> list[Estimate]:
        if not fix.valid or not math.isfinite(fix.speed_mps):
            self.rejected_fixes += 1
            return []
        t = fix.timestamp_s - self.p.gps_latency_s
        if t <= self._gps.last_time:
            self.rejected_fixes += 1
            return []
        self._gps.append(t, fix.speed_mps)
        self._pending.append(t)
        return self._drain()

    # ---- readiness ----------------------------------------------------------------------------------
    def _ready(self, t_c: float) -> bool:
        t1 = t_c + 0.5 * self.p.window_s
        gps_last = self._gps.last_time
        if gps_last < t1:
            return False
        if gps_last >= t1 + max(self.p.window_s, 0.5):
            return True
        return all(r.last_time >= t1 for r in self._wheels.values() if len(r) and r.last_time >= t_c - self.p.window_s)

    def _drain(self) -> list[Estimate]:
        out: list[Estimate] = []
        while self._pending and self._ready(self._pending[0]):
            out.append(self._estimate(self._pending.popleft()))
        keep = (self._pending[0] if self._pending else self._gps.last_time) - self.p.window_s - self.p.max_gps_gap_s
        self._gps.drop_before = keep
        for r in self._wheels.values():
            r.drop_before = keep
        return out

    # ---- the estimate -------------------------------------------------------------------------------
    def _gps_covers(self, t0: float, t1: float) -> bool:
        times = self._gps.times
        if len(times) < 2 or times[0] > t0 or times[-1] < t1:
            return False
        i0 = max(int(np.searchsorted(times, t0, side="right")) - 1, 0)
        i1 = int(np.searchsorted(times, t1, side="left"))
        return bool(np.max(np.diff(times[i0 : i1 + 1])) <= self.p.max_gps_gap_s)

    def _accel(self, t_c: float) -> float | None:
        times, speeds = self._gps.times, self._gps.values
        i = int(np.searchsorted(times, t_c))
        if i < 1 or i + 1 >= len(times) or times[i + 1] - times[i - 1] > 2 * self.p.max_gps_gap_s:
            return None
        return float((speeds[i + 1] - speeds[i - 1]) / (times[i + 1] - times[i - 1]))

    def _estimate(self, t_c: float) -> Estimate:
        p = self.p
        t0, t1 = t_c - 0.5 * p.window_s, t_c + 0.5 * p.window_s
        times, speeds = self._gps.times, self._gps.values
        speed_c = float(np.interp(t_c, times, speeds))
        accel = self._accel(t_c)
        force = p.mass_kg * accel if accel is not None else None
        per_tire = tire_forces(force, p.driven_axle, p.brake_front_share) if force is not None else {}
        d_gps = integrate_speed_m(times, speeds, t0, t1) if self._gps_covers(t0, t1) else None
        speed = d_gps / p.window_s if d_gps is not None else speed_c
        wheels = {w: self._wheel(w, t0, t1, d_gps, per_tire.get(w)) for w in WHEELS}
        return Estimate(t_c, speed, accel, force, p.window_s, wheels)

    def _wheel(self, w: str, t0: float, t1: float, d_gps: float | None, force: float | None) -> WheelEstimate:
        p = self.p
        ring = self._wheels[w]
        empty = WheelEstimate(None, None, p.r_ref_m, None, force, None)
        if len(ring) < 2 or ring.first_time > t0 or ring.last_time < t1:
            return empty
        c0, c1 = np.interp((t0, t1), ring.times, ring.values).tolist()
        revs = (c1 - c0) / p.pulses_per_rev
        d_wpt = p.r_ref_m * TWO_PI * revs
        wheel_speed = d_wpt / p.window_s
        if d_gps is None or d_gps < p.min_speed_mps * p.window_s or revs <= 0:
            return WheelEstimate(None, None, p.r_ref_m, None, force, wheel_speed)
        slip = slip_from_distances(d_wpt, d_gps)
        re = d_gps / (TWO_PI * revs)
        cx = None
        if force is not None and force != 0 and p.cx_slip_min <= abs(slip) <= p.cx_slip_max and force / slip > 0:
            cx = force / slip
        return WheelEstimate(slip, re, p.r_ref_m, cx, force, wheel_speed)
