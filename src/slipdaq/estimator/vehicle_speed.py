"""The vehicle speed at a fixed rate on the host's clock: an online Kalman filter on x = [v, a] (speed_model.py) fed
the reference speed at its fix time (arrival - GPS latency: the latency applies to the reference only) and, when there
is one, the IMU's acceleration at its sample time. Pure: samples in, (time, speed, acceleration) on a grid out.

The filter runs up to the newest fix time: IMU samples after it wait for the next fix. Each grid time between two
fixes gets the state predicted to it through the IMU samples before it (causal: no later fix is used).

The IMU's bias (a mounting pitch: g*sin(theta), a sensor offset) would carry the speed away between fixes, so the
filter takes a_imu - b, b the mean over about IMU_BIAS_TIME_S of (mean IMU sample - the reference's own speed change)
between consecutive fixes (an exponential average): b = b + dt/tau * ((sum a_imu)/n - (v_k - v_k-1)/(t_k - t_k-1) - b).
That takes a road's grade out too (the reference's speed change has none), as a kinematic speed must; the windows'
force (slip.py) takes the IMU as it is, grade included, as the tire carries it.
"""

from __future__ import annotations

import math
from collections import deque

from slipdaq.estimator.speed_model import State, predict, update_accel, update_speed

JERK_PSD_M2PS5 = 200.0
"""q of the white-noise jerk: lets the acceleration follow an ABS cycle (+-3 m/s^2 at 5-15 Hz) between 10 Hz fixes."""
JERK_PSD_IMU_M2PS5 = 2000.0
"""q with an IMU: its samples pin the acceleration down, so the model may let it change faster."""
IMU_NOISE_MPS2 = 0.1
"""1-sigma of one IMU sample (vibration, quantisation)."""
REFERENCE_NOISE_MPS = 0.03
"""1-sigma of a reference speed without a stated accuracy."""
PRIOR_SIGMA_SPEED_MPS = 10.0
PRIOR_SIGMA_ACCEL_MPS2 = 5.0
IMU_BIAS_TIME_S = 20.0
"""Time constant of the IMU bias estimate."""
RESET_GAP_S = 1.0
"""Fixes further apart than this restart the filter at the next fix (the grid instants between: none)..."""
RESET_GAP_IMU_S = 3.0
"""... or this, with an IMU (its samples carry the speed between the fixes of a 1 Hz CAN GNSS module)."""


class VehicleSpeedFilter:
    def __init__(self, rate_hz: float) -> None:
        self.rate_hz = rate_hz
        self._x: State | None = None
        self._t = -math.inf
        """The filter's time: its newest fix's time."""
        self._imu: deque[tuple[float, float]] = deque()
        self.has_imu = False
        self._next_k = 0
        """The next grid instant: _next_k / rate_hz."""
        self.rows: list[tuple[float, float, float]] = []
        """(time, speed, acceleration) on the grid, not yet taken."""
        self.imu_bias_mps2 = 0.0
        self._last_speed = math.nan
        """The previous fix's speed (for the bias estimate)."""

    def add_imu(self, time_s: float, accel_mps2: float) -> None:
        if time_s > self._t and math.isfinite(accel_mps2):
            self._imu.append((time_s, accel_mps2))
            self.has_imu = True

    def add_speed(self, fix_time_s: float, speed_mps: float, sigma_mps: float) -> None:
        """A reference speed at its fix time (sigma NaN: REFERENCE_NOISE_MPS)."""
        r = (sigma_mps if sigma_mps == sigma_mps and sigma_mps > 0 else REFERENCE_NOISE_MPS) ** 2
        if self._x is None or fix_time_s - self._t > (RESET_GAP_IMU_S if self.has_imu else RESET_GAP_S):
            self._x = (speed_mps, 0.0, PRIOR_SIGMA_SPEED_MPS**2, 0.0, PRIOR_SIGMA_ACCEL_MPS2**2)
            self._t = fix_time_s
            while self._imu and self._imu[0][0] <= fix_time_s:
                self._imu.popleft()
            self._next_k = math.ceil(fix_time_s * self.rate_hz)
            self._last_speed = speed_mps
            return
        if fix_time_s <= self._t:
            return  # the latency in use grew: a fix older than the filter's time
        q = JERK_PSD_IMU_M2PS5 if self.has_imu else JERK_PSD_M2PS5
        x, t = self._x, self._t
        imu = self._imu
        bias = self.imu_bias_mps2
        imu_sum, imu_n = 0.0, 0
        while True:
            t_imu = imu[0][0] if imu and imu[0][0] <= fix_time_s else math.inf
            t_next = min(t_imu, fix_time_s)
            while (g := self._next_k / self.rate_hz) <= t_next:  # grid instants before the next measurement
                x, t = predict(x, g - t, q), g
                self.rows.append((g, x[0], x[1]))
                self._next_k += 1
            x, t = predict(x, t_next - t, q), t_next
            if t_imu == t_next and t_imu != math.inf:
                a_imu = imu.popleft()[1]
                imu_sum += a_imu
                imu_n += 1
                x = update_accel(x, a_imu - bias, IMU_NOISE_MPS2**2)
                continue
            break
        x, _, _ = update_speed(x, speed_mps, r)
        dt = fix_time_s - self._t
        if imu_n:
            observed = imu_sum / imu_n - (speed_mps - self._last_speed) / dt
            self.imu_bias_mps2 = bias + min(dt / IMU_BIAS_TIME_S, 1.0) * (observed - bias)
        self._x, self._t, self._last_speed = x, fix_time_s, speed_mps

    def take_rows(self) -> list[tuple[float, float, float]]:
        rows, self.rows = self.rows, []
        return rows
