"""High-rate slip: at each instant t of a fixed grid (estimator.fast_rate_hz), each wheel's circumferential speed
against the vehicle speed (vehicle_speed.py):
  omega*r0 = 2*pi*r0 * dN/dt    slope of the least-squares line through the 2*FAST_LINE_HALF+1 revolution samples
                                around t (the kernel the latency fit uses: ring.local_lines)
  s(t)     = (omega*r0 - V) / V  (SAE slip), undefined below the minimum speed
An ABS cycle (5-15 Hz) is resolved: at 500 wheel frames per second the line spans 20 ms.

A grid instant is released once every wheel that reports has FAST_LINE_HALF + 1 samples at or after it (so its line
no longer depends on when it is computed), or WHEEL_WAIT_S of reference time has passed (that wheel: no slip).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence

import numpy as np

from slipdaq import WHEELS
from slipdaq.estimator.ring import SeriesRing
from slipdaq.estimator.vehicle_speed import VehicleSpeedFilter
from slipdaq.estimator.windows import TWO_PI, has_gap
from slipdaq.records import FastSlip, FastWheel

FAST_LINE_HALF = 5
WHEEL_WAIT_S = 0.5


class FastSlipRows:
    def __init__(self, rate_hz: float, min_speed_mps: float) -> None:
        self.speed = VehicleSpeedFilter(rate_hz)
        self.min_speed_mps = min_speed_mps
        self._pending: deque[tuple[float, float, float]] = deque()

    def release(self, rings: Sequence[SeriesRing], r0_m: Sequence[float], now_s: float) -> list[FastSlip]:
        """The grid instants that are ready (see the module docstring), as FastSlip rows; now_s: the newest reference
        fix's time."""
        pending = self._pending
        pending.extend(self.speed.take_rows())
        if not pending:
            return []
        need = FAST_LINE_HALF + 1
        n = 0
        for t, _, _ in pending:
            if now_s - t <= WHEEL_WAIT_S and any(len(r) and r.count_from(t) < need for r in rings):
                break
            n += 1
        if n == 0:
            return []
        rows = [pending.popleft() for _ in range(n)]
        times = np.array([r[0] for r in rows])
        wheel_speeds: list[list[float | None]] = []
        for ring, r0 in zip(rings, r0_m):
            lines = ring.local_lines(times, FAST_LINE_HALF) if len(ring) else None
            if lines is None:
                wheel_speeds.append([None] * n)
                continue
            slopes = lines[1].tolist()
            span = FAST_LINE_HALF * ring.mean_interval()
            speeds: list[float | None] = []
            for t, slope in zip(times.tolist(), slopes):
                ok = ring.count_from(t) >= need and ring.first_time <= t - span and not has_gap(ring, t - span, t + span)
                speeds.append(TWO_PI * r0 * slope if ok else None)
            wheel_speeds.append(speeds)
        source = "imu" if self.speed.has_imu else "gps"
        out = []
        for k, (t, v, a) in enumerate(rows):
            wheels = {}
            for w, speeds in zip(WHEELS, wheel_speeds):
                ws = speeds[k]
                slip = (ws - v) / v if ws is not None and v >= self.min_speed_mps and math.isfinite(ws) else None
                wheels[w] = FastWheel(slip, ws)
            out.append(FastSlip(t, v, a, source, wheels))
        return out
