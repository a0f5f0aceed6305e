"""High-rate slip: at each instant t of a fixed grid (estimator.fast_rate_hz), each wheel's circumferential speed
against the vehicle speed (vehicle_speed.py):
  omega*r0 = 2*pi*r0 * dN/dt    slope of the least-squares line through the 2*FAST_LINE_HALF+1 revolution samples
                                around t (the kernel the latency fit uses: ring.local_lines)
  s(t)     = (omega*r0 - V) / V  (SAE slip), undefined below the minimum speed
An ABS cycle (5-15 Hz) is resolved: at 500 wheel frames per second the line spans 20 ms.

A grid instant is released once every wheel that reports has FAST_LINE_HALF + 1 samples at or after it (so its line
no longer depends on when it is computed), or WHEEL_WAIT_S of reference time has passed (that wheel: no slip). A line
whose samples have a gap over wheel_revolutions.gap_limit gives no slip (the windows' rule).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence

import numpy as np

from slipdaq import WHEELS
from slipdaq.compiled import kernel
from slipdaq.estimator.ring import LINE_USES, SeriesRing, first_index, local_line_values
from slipdaq.estimator.vehicle_speed import VehicleSpeedFilter
from slipdaq.estimator.wheel_revolutions import TWO_PI, gap_limit
from slipdaq.records.fast_rows import FastSlipBatch

FAST_LINE_HALF = 5
WHEEL_WAIT_S = 0.5


class FastSlipRows:
    def __init__(self, rate_hz: float, min_speed_mps: float) -> None:
        self.speed = VehicleSpeedFilter(rate_hz)
        self.min_speed_mps = min_speed_mps
        self._pending: deque[tuple[float, float, float]] = deque()

    def release(self, rings: Sequence[SeriesRing], r0_m: Sequence[float], now_s: float) -> FastSlipBatch | None:
        """The grid instants that are ready (see the module docstring), as columns (None: none ready); now_s: the
        newest reference fix's time."""
        pending = self._pending
        pending.extend(self.speed.take_rows())
        if not pending:
            return None
        need = FAST_LINE_HALF + 1
        # an instant t has `need` samples of a ring at or after it when t <= the need-th last sample's time
        ready_until = min((float(r.times[-need]) if len(r) >= need else -math.inf for r in rings if len(r)),
                          default=math.inf)
        n = 0
        for t, _, _ in pending:
            if t > ready_until and now_s - t <= WHEEL_WAIT_S:
                break
            n += 1
        if n == 0:
            return None
        rows = [pending.popleft() for _ in range(n)]
        times = [r[0] for r in rows]
        speeds = [r[1] for r in rows]
        grid = np.array(times)
        low = self.min_speed_mps
        slips, wheel_speeds = {}, {}
        for w, ring, r0 in zip(WHEELS, rings, r0_m):
            ws_all = wheel_speeds[w] = self._wheel_speeds(ring, r0, grid)
            slips[w] = [(ws - v) / v if ws is not None and v >= low and math.isfinite(ws) else None
                        for ws, v in zip(ws_all, speeds)]
        return FastSlipBatch(times, speeds, [r[2] for r in rows], ["imu" if self.speed.has_imu else "gps"] * n, WHEELS,
                             slips, wheel_speeds)

    @staticmethod
    def _wheel_speeds(ring: SeriesRing, r0_m: float, times: np.ndarray) -> list[float | None]:
        """omega*r0 at each time: 2*pi*r0 * the slope of its local line; None without FAST_LINE_HALF + 1 samples at
        or after it, without the line's samples before it, or with a gap in them (windows.py's rule)."""
        half = FAST_LINE_HALF
        if len(ring) < 2 * half + 1:
            return [None] * len(times)
        speeds = np.empty(len(times))
        ok = np.empty(len(times), dtype=np.bool_)
        line_speeds()(ring.times, ring.values, times, half, TWO_PI * r0_m, speeds, ok)
        return [x if good else None for x, good in zip(speeds.tolist(), ok.tolist())]


def _line_speeds(t: np.ndarray, v: np.ndarray, times: np.ndarray, half: int, scale: float, speeds: np.ndarray,
                 ok: np.ndarray) -> None:
    """speeds[q]: scale x the slope of ring.local_lines' line at times[q] (samples t, values v, at least 2*half+1);
    ok[q]: half + 1 samples at or after times[q], half before it, and no interval between the line's samples over
    gap_limit(t) (an interval that is NaN counts as over, as numpy's max has it)."""
    n = len(t)
    max_gap_s = gap_limit(t)
    values = np.empty(len(times))
    local_line_values(t, v, times, half, values, speeds)
    for q in range(len(times)):
        first = first_index(t, times[q], 0, False)
        c = min(max(first, half), n - half - 1)  # the line's centre sample, as local_line_values takes it
        longest = t[c - half + 1] - t[c - half]
        for k in range(c - half + 1, c + half):
            d = t[k + 1] - t[k]
            if d > longest or d != d:
                longest = d
        ok[q] = n - first >= half + 1 and first >= half and longest <= max_gap_s
        speeds[q] = scale * speeds[q]


line_speeds = kernel(_line_speeds,
                     "void(float64[:], float64[:], float64[:], int64, float64, float64[:], boolean[:])",
                     uses=(*LINE_USES, gap_limit))
"""line_speeds()(t, v, times, half, scale, speeds, ok): see _line_speeds (FastSlipRows._wheel_speeds)."""
