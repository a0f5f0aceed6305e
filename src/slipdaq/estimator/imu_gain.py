"""An IMU without orientation (on CAN, or an MTi's Acceleration alone): its gain and offset against the GNSS speed,
and their correction (docs/method.md, "The acceleration without gravity"). Pure.

The body pitches by k per unit of acceleration (nose down braking, up accelerating) and the road has a grade, so the
forward accelerometer reads
    a_imu = a*(1 + k) + g*sin(grade) + bias = gain*a + offset
Over each window where both are valid, the IMU's mean and the GNSS speed's change over the window (v(t1) - v(t0))/W
measure the same mean acceleration; the least-squares line of the GNSS one on the IMU one (the GNSS one carries the
noise: fitted this way round the slope is not attenuated), a_gnss = alpha + beta*a_imu, gives
    gain = 1/beta,  offset = -alpha/beta,  and the correction  a = (a_imu - offset)/gain.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from slipdaq.estimator.ring import SeriesRing

SOURCE_RAW = "imu"
SOURCE_CALIBRATED = "imu-calibrated"
MIN_WINDOWS = 100
"""Windows needed before a gain is learned."""
MIN_SPREAD_MPS2 = 1.0
"""The IMU's acceleration must spread this much (standard deviation) over those windows: braking and accelerating."""
MIN_SPEED_MPS = 3.0
"""Slowest window fitted (the GNSS speed's derivative is noisy near standstill)."""
MAX_GAIN_ERROR = 0.2
"""A gain further than this from 1 is not learned (a wrong sign or unit, not a pitching body)."""


@dataclass(frozen=True, slots=True)
class ImuCorrection:
    """a = (a_imu - offset_mps2) / gain, for the raw IMU's samples."""

    gain: float
    offset_mps2: float

    def apply(self, accel_mps2: float) -> float:
        return (accel_mps2 - self.offset_mps2) / self.gain


class ImuGainFit:
    """Running sums of the windows' (IMU mean, GNSS speed change / W) pairs and the line through them."""

    def __init__(self) -> None:
        self.n = 0
        self._sx = self._sy = self._sxx = self._sxy = 0.0

    def add(self, imu_mps2: float, gnss_mps2: float) -> None:
        if math.isfinite(imu_mps2) and math.isfinite(gnss_mps2):
            self.n += 1
            self._sx += imu_mps2
            self._sy += gnss_mps2
            self._sxx += imu_mps2 * imu_mps2
            self._sxy += imu_mps2 * gnss_mps2

    def observe(self, imu_mps2: float | None, fix_times: np.ndarray, speeds: np.ndarray, t0: float, t1: float,
                speed_mps: float, usable: bool) -> None:
        """One window: the raw IMU mean over [t0, t1] and the GNSS speed at t0 and t1 (fixes covering both)."""
        if imu_mps2 is None or not usable or speed_mps < MIN_SPEED_MPS or len(fix_times) < 2 \
                or fix_times[0] > t0 or fix_times[-1] < t1:
            return
        v0, v1 = np.interp((t0, t1), fix_times, speeds)
        self.add(imu_mps2, float(v1 - v0) / (t1 - t0))

    def result(self) -> tuple[float, float, int] | None:
        """(gain, offset_mps2, windows), or None with too few windows, too little spread or an implausible gain."""
        n = self.n
        if n < MIN_WINDOWS:
            return None
        mx, my = self._sx / n, self._sy / n
        sxx = self._sxx / n - mx * mx
        if sxx < MIN_SPREAD_MPS2**2:
            return None
        beta = (self._sxy / n - mx * my) / sxx
        if beta <= 0 or abs(1.0 / beta - 1.0) > MAX_GAIN_ERROR:
            return None
        alpha = my - beta * mx
        return 1.0 / beta, -alpha / beta, n


class ImuInput:
    """The IMU's samples as they read (ring: time -> forward acceleration), where the last came from (source), the
    stored correction of a raw IMU's, and the run's gain fit over the raw IMU's windows."""

    def __init__(self, stored: tuple[float, float] | None) -> None:
        """stored: the calibration's (gain, offset_mps2), or None."""
        self.ring = SeriesRing(1024)
        self.source = SOURCE_RAW
        self.correction = ImuCorrection(*stored) if stored is not None else None
        self.fit = ImuGainFit()

    def add(self, time_s: float, accel_mps2: float, source: str) -> float | None:
        """Keeps a sample newer than the last; returns it as a kinematic acceleration (corrected where raw and a
        correction is stored), or None where it was dropped."""
        if not (time_s > self.ring.last_t and math.isfinite(accel_mps2)):
            return None
        self.ring.append(time_s, accel_mps2)
        self.source = source
        cor = self.correction
        return cor.apply(accel_mps2) if cor is not None and source == SOURCE_RAW else accel_mps2

    def observe(self, imu_raw_mps2: float | None, fix_times: np.ndarray, speeds: np.ndarray, t0: float, t1: float,
                speed_mps: float, usable: bool) -> None:
        """One window into the gain fit, where the IMU is a raw one (ImuGainFit.observe)."""
        if self.source == SOURCE_RAW:
            self.fit.observe(imu_raw_mps2, fix_times, speeds, t0, t1, speed_mps, usable)
