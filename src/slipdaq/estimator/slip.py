"""Windowed longitudinal slip, effective rolling radius Re, force Fx and stiffness Cx (docs/method.md).

For a window [t_c - W/2, t_c + W/2] centred on GPS epoch c, at its fix time t_c = arrival time - GPS latency, where
the arrival time of a fix with a UTC time is that time plus the lower envelope of (arrival - UTC) over recent fixes
(latency.UtcLatency): the receiver's own clock, free of the delays with which sentences are read:
  d_gps = integral of GPS speed (piecewise linear between fixes)
  N     = rev(t1) - rev(t0)                                  wheel revolutions (counts/ppr, interpolated linearly)
  d_wpt = r0 * 2*pi * N                                      distance by wheel revolutions, r0 calibrated per wheel
  s     = (d_wpt - d_gps) / d_gps                            SAE slip: > 0 driving, < 0 braking
  Re    = d_gps / (2*pi*N)                                   = V / omega
  a(c)  = (v(c+1) - v(c-1)) / (t(c+1) - t(c-1))             central difference of GPS speed
  Fx    = M*a [+ f_rr*M*g + rho/2*CdA*v^2 + M*g*sin(grade)]  per tire: driven axle when Fx >= 0, brake share else
  Cx    = Fx_tire / s  per window (cx_slip_min <= |s| <= cx_slip_max), and a fitted Cx over the run (stiffness.py)

The parts, each with its own state: the GPS track (gps_track.py: reference speed, acceleration, weights), the
wheels' windows (windows.py), readiness (readiness.py: when wheel samples release an estimate), GPS latency
(latency.py), the run's calibration (run_calibration.py: stored and own radius, stiffness, latency), force
(force.py); one window's measurements (window.py) and each wheel's estimate over it (wheel_estimate.py).
SlipEstimator composes them and keeps their order. Pure: records in, estimates out, deterministic in the order
records are given. No clock, no I/O.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import replace

import numpy as np

from slipdaq import WHEELS
from slipdaq.config.calibration import Calibration, Learned
from slipdaq.estimator.fast_slip import FastSlipRows
from slipdaq.estimator.force import AltitudeGrade, RoadLoads, driven_wheels, tire_forces
from slipdaq.estimator.gps_lost import WheelClockEstimates
from slipdaq.estimator.gps_track import MAX_GPS_GAP_S, TIME_TOL_S, GpsTrack, integrate_speed_m, smooth_arrival
from slipdaq.estimator.imu_gain import SOURCE_RAW, ImuInput
from slipdaq.estimator.latency import LatencyEstimate, UtcLatency, WheelLatency, WheelLatencyRows
from slipdaq.estimator.linear_region import WindowSpread
from slipdaq.estimator.params import EstimatorParams
from slipdaq.estimator.phase import PHASE_ACCEL_MPS2, STANDSTILL_SPEED_MPS, phase_of
from slipdaq.estimator.readiness import (
    MODE_READY,
    MODE_WAIT,
    MODE_WHEELS,
    SCAN_GPS_LOST,
    SCAN_READY,
    head_ready,
    scan_samples,
)
from slipdaq.estimator.run_calibration import RunCalibration, driven_tire_force_n, stored_road_loads
from slipdaq.estimator.wheel_estimate import learn_wheel, wheel_estimate
from slipdaq.estimator.wheel_revolutions import WheelWindows, reference_slip, slip_from_distances
from slipdaq.estimator.window_measure import measure_window, radius_uncalibrated
from slipdaq.records import Estimate, GpsFix, SourceEvent, WheelSample
from slipdaq.records.fast_rows import FastSlipBatch

__all__ = ["EstimatorParams", "SlipEstimator", "PHASE_ACCEL_MPS2", "STANDSTILL_SPEED_MPS", "phase_of",
           "integrate_speed_m", "slip_from_distances", "tire_forces"]

WHEEL_INDEX = {w: i for i, w in enumerate(WHEELS)}
EPOCH_TOLERANCE_S = 0.005
"""A CAN reference's arrival jitter: a fix this much early still starts a window."""


class SlipEstimator:
    """Feed wheel samples and GPS fixes in record order; each call returns the estimates that became ready.

    An estimate is centred on every valid GPS epoch and is ready when GPS and every wheel that is reporting have
    samples past the window's end (or GPS is a further window past it, for a silent wheel).
    """

    def __init__(self, params: EstimatorParams, stored: Calibration | None = None, frozen: bool = False,
                 fast_rows: bool = True, wheels: bool = True) -> None:
        """stored: a calibration to start from (used until the run measures better, dropped where the run contradicts
        it); frozen: use the stored latency and radii throughout and learn none (the second pass of a replay);
        fast_rows=False: no high-rate slip rows (the first pass of a replay, which keeps none): the latency in use is
        still brought up to date at each fix, as making them does, so that the estimates and what the run learns
        stay the same; wheels=False: estimates without their wheels (a pass that keeps none: the first), each
        wheel's window still into its fits, so that what the run learns stays the same."""
        self.p = params
        self._track = GpsTrack()
        self._grade = AltitudeGrade()
        self._windows = WheelWindows()
        self._pending: deque[tuple[float, float]] = deque()  # epochs still to estimate: (arrival, UTC or NaN)
        self._utc = UtcLatency(params.max_latency_s)
        self._lag = WheelLatency(params.max_latency_s, slip_terms=params.driven_axle == "all")
        self._driven = driven_wheels(params.driven_axle)
        self._reference = tuple(w for w in WHEELS if w not in self._driven)
        self._lag_rows = WheelLatencyRows(self._lag, not self._reference, params.max_latency_s, params.window_s)
        self._cal = RunCalibration(params, stored, frozen, self._reference)
        self.road_loads = stored_road_loads(stored, params)
        """The calibration's road loads Fx uses (None: the config's coefficients)."""
        self.frozen = self._cal.frozen
        self._wheel_clock = WheelClockEstimates(params.window_s, self._reference, self._driven,
                                                params.min_speed_mps * params.window_s)
        self._last_center_s = -math.inf
        self._latency: LatencyEstimate | None = None
        self._utc_offset_s: float | None = None
        """The UTC offset of the latency in use (set with it)."""
        self.rejected_fixes = 0
        self._head: tuple[int, float, float] | None = None  # the head epoch's readiness constants (_head_consts)
        self._last_epoch_s = -math.inf
        self._imu = ImuInput((stored.imu.gain, stored.imu.offset_mps2)
                             if stored is not None and stored.imu is not None else None)
        """The IMU's samples, their source, a raw IMU's stored gain and offset and its gain fit (imu_gain.py)."""
        self._fast = FastSlipRows(params.fast_rate_hz, params.min_speed_mps) \
            if params.fast_rate_hz > 0 and fast_rows else None
        self._fast_skipped = params.fast_rate_hz > 0 and not fast_rows
        self._wheels = wheels
        self.fast_rows: list[FastSlipBatch] = []
        """The high-rate slip rows released and not yet taken (take_fast: the pipeline's, for /slip/fast), a batch per
        fix that released some."""

    # ---- latency ------------------------------------------------------------------------------------
    @property
    def latency(self) -> LatencyEstimate:
        """The GPS latency in use and, with it, the UTC offset (cached; they change only when a fix or an estimate
        comes)."""
        if self._latency is None:
            self._latency = self._cal.latency(self._utc, self._lag, self._track.last_t)
            self._utc_offset_s = self._utc.offset_s()
        return self._latency

    def host_time_s(self, utc_s: float) -> float | None:
        """A UTC instant on the host's clock, as a fix's UTC time is placed: UTC + offset - GPS latency (module
        docstring); None before a fix with a UTC time."""
        latency_s = self.latency.latency_s
        offset_s = self._utc_offset_s
        return None if offset_s is None or not math.isfinite(utc_s) else utc_s + offset_s - latency_s

    @property
    def events(self) -> list[SourceEvent]:
        """Stored values the run replaced, for /diagnostics/events (the pipeline takes them)."""
        return self._cal.events

    def take_events(self) -> list[SourceEvent]:
        return self._cal.take_events()

    def _invalidate(self) -> None:
        """A fix or an estimate changed what the latency and the head epoch's readiness depend on."""
        self._latency = None
        self._head = None

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
        last_t = np.array(self._windows.last_times(), dtype=np.float64)
        keep = np.empty(n, dtype=np.bool_)
        run = scan_samples()
        pos = 0
        while pos < n:
            mode, need, since = (self._head or self._head_consts()) if self._pending else (MODE_WAIT, 0.0, 0.0)
            k, why = run(wheel, time_s, pos, last_t, keep, self._track.last_t, mode, need, since)
            stop = min(k + 1, n)
            self._windows.append(wheel, time_s, revolutions, keep, pos, stop)
            if why == SCAN_READY:
                out += [(k, e) for e in self._drain()]
            elif why == SCAN_GPS_LOST:
                out += [(k, e) for e in self._gps_lost()]
            pos = stop
        return out

    def add_imu(self, time_s: float, accel_mps2: float, source: str = SOURCE_RAW) -> None:
        """One IMU sample (longitudinal acceleration, forward positive) on the host's clock; older than the last: dropped.
        source: imu (as the sensor read it: gravity and the body's pitch in it), imu-orientation or imu-free (gravity
        taken out, decode/mti_accel.py)."""
        kinematic = self._imu.add(time_s, accel_mps2, source)
        if kinematic is not None and self._fast is not None:
            self._fast.speed.add_imu(time_s, kinematic)

    def take_fast(self) -> FastSlipBatch:
        """The high-rate slip rows not yet taken, as one batch of columns (a sequence of FastSlip)."""
        rows, self.fast_rows = self.fast_rows, []
        return FastSlipBatch.concat(rows)

    def add_gps(self, fix: GpsFix) -> list[Estimate]:
        if not fix.valid or not math.isfinite(fix.speed_mps):
            self.rejected_fixes += 1
            return []
        a = fix.timestamp_s
        if a <= self._track.last_t:
            self.rejected_fixes += 1
            return []
        utc = fix.fix_time_utc_s
        if utc is not None and not math.isfinite(utc):
            utc = None  # a NaN or infinite UTC time is no UTC time
        self._utc.add(a, utc)
        utc_s = float(utc) if utc is not None else math.nan
        self._track.add(a, fix.speed_mps, utc_s,
                        fix.speed_accuracy_mps if fix.speed_accuracy_mps is not None else math.nan)
        self._invalidate()
        if fix.altitude_m is not None and self.p.grade_from_altitude:
            self._grade.add(a, fix.altitude_m)
        if a - self._last_epoch_s >= self.p.epoch_interval_s - EPOCH_TOLERANCE_S or self.p.epoch_interval_s == 0.0:
            self._pending.append((a, utc_s))
            self._last_epoch_s = a
        self._wheel_clock.next_s = None
        out = self._drain()
        if self._fast is not None:
            self._fast_fix(a, utc_s, fix.speed_mps, fix.speed_accuracy_mps)
        elif self._fast_skipped:
            self.latency  # noqa: B018  (evaluated where _fast_fix evaluates it: the stored latency's check)
        return out

    def _fast_fix(self, arrival_s: float, utc_s: float, speed_mps: float, accuracy_mps: float | None) -> None:
        """The fix into the vehicle-speed filter at its fix time; the high-rate slip rows that became ready."""
        assert self._fast is not None
        fix_s = smooth_arrival(arrival_s, utc_s, self._utc_offset_s) - self.latency.latency_s
        self._fast.speed.add_speed(fix_s, speed_mps, accuracy_mps if accuracy_mps is not None else math.nan)
        r0 = self._cal.r0_all()
        rows = self._fast.release(self._windows.rings, [r0[w][0] for w in WHEELS], fix_s)
        if rows is not None:
            self.fast_rows.append(rows)

    # ---- readiness ----------------------------------------------------------------------------------
    def _head_consts(self) -> tuple[int, float, float]:
        """The head epoch's readiness as (mode, need, since) (estimator/readiness.py), cached until a fix, an
        estimate or GPS loss."""
        lat = self.latency.latency_s
        arrival_s, utc_s = self._pending[0]
        half = 0.5 * self.p.window_s
        offset = self._utc_offset_s
        t1 = smooth_arrival(arrival_s, utc_s, offset) - lat + half
        gps_last = smooth_arrival(self._track.last_t, self._track.last_utc_s, offset) - lat  # on t1's time line
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

    def _drain(self) -> list[Estimate]:
        out: list[Estimate] = []
        while self._pending and head_ready(self._windows.last_times(), *(self._head or self._head_consts())):
            lat = self.latency
            rows = self._lag.rows
            out.append(self._estimate(self._pending.popleft()[0], lat))
            if self._lag.rows != rows:
                self._latency = None  # the estimate moved the wheels' latency fit
            self._head = None
        first = self._pending[0][0] if self._pending else self._track.last_t
        keep = first - self.p.max_latency_s - self.p.window_s - MAX_GPS_GAP_S - 2.0
        self._track.drop_before(keep)
        self._grade.altitude.drop_before = keep
        self._windows.drop_before(keep)
        self._imu.ring.drop_before = keep
        return out

    # ---- the estimate -------------------------------------------------------------------------------
    def _estimate(self, arrival_s: float, lat: LatencyEstimate) -> Estimate:
        p, track, cal = self.p, self._track, self._cal
        smooth = track.smooth_arrivals(self._utc_offset_s)
        i = int(track.speed.times.searchsorted(arrival_s))
        fix_arr = smooth - lat.latency_s
        imu = self._imu
        win = measure_window(p, track, self._grade, self._windows, imu.ring, fix_arr, i, lat, imu.source,
                             imu.correction, self.road_loads)
        if not self.frozen:
            imu.observe(win.imu_raw_mps2, fix_arr, track.speed.values, win.t0, win.t1, win.speed_mps,
                        lat.source != "none" and not win.disturbed)
        if p.gps_latency_s is None:
            self._lag_rows.observe(float(smooth[i]), float(track.speed.values[i]),
                                   [self._windows.by_wheel[w] for w in self._reference or WHEELS])
        cal.add_free_rolling(win.arcs, win.d_gps_m, win.accel_mps2, win.speed_mps, win.weight, lat.source != "none",
                             driven_tire_force_n(p, self.road_loads, win.force_n, len(self._driven)))
        cal.check_stored(track.last_t)
        r0 = cal.r0_all()
        spread = WindowSpread(self._windows.rings, win.t0, win.t1)
        self._last_center_s = win.t_c
        if not self._wheels:
            slips = [learn_wheel(p, cal.stiffness[w], win.arcs[w], r0[w][0], win.d_slip_m, win.tire_force_n.get(w),
                                 win.speed_mps, win.weight, spread) for w in WHEELS]
            return win.estimate({}, lat, p.window_s, radius_uncalibrated(zip(slips, (r0[w][1] for w in WHEELS))))
        slip_nd = reference_slip(win.arcs, r0, self._reference, self._driven, p.min_speed_mps * p.window_s)
        wheels = {w: wheel_estimate(p, cal.stiffness[w], win.arcs[w], r0[w], win.d_slip_m, win.tire_force_n.get(w),
                                    win.speed_mps, win.weight, slip_nd.get(w), cal.stored_cx.get(w),
                                    spread)
                  for w in WHEELS}
        return win.estimate(wheels, lat, p.window_s)

    def learned(self) -> Learned:
        """What this run measured itself (RunCalibration.learned); nothing for a frozen (second-pass) estimator."""
        if self.frozen:
            return Learned()
        lat = self.latency
        return replace(self._cal.learned(lat, self._utc_offset_s), imu_gain=self._imu.fit.result())

    def road_loads_measured(self, loads: RoadLoads, runs: int) -> None:
        """A coast-down's road loads (the maneuver's, over `runs` runs): the run's to save in its calibration (this
        run's Fx keeps the loads it started with)."""
        self._cal.road_loads_learned = (loads.f0_n, loads.f1_n_per_mps, loads.f2_n_per_mps2, runs)

    # ---- GPS lost: estimates on the wheels' clock -----------------------------------------------------
    def _gps_lost(self) -> list[Estimate]:
        """Epochs that will get no later fix are estimated with what there is; then the wheels' clock takes over."""
        out: list[Estimate] = []
        lat = self.latency
        while self._pending:
            out.append(self._estimate(self._pending.popleft()[0], lat))
        self._head = None
        clock = self._wheel_clock.due(self._windows, self._cal.r0_all(), self.latency, self._last_center_s,
                                      self._track.last_t)
        if clock:
            self._last_center_s = clock[-1].time_s
        return out + clock

    # ---- state for diagnostics ----------------------------------------------------------------------
    def status(self) -> dict[str, object]:
        lat = self.latency
        r0 = self._cal.r0_all()
        return {
            "gps_latency_s": lat.latency_s,
            "latency_source": lat.source,
            "gps_latency_utc_s": lat.utc_s,
            "gps_latency_wheels_s": self._lag.latency_s,
            "gps_latency_wheels_sigma_s": lat.wheels_sigma_s,
            "r0_m": {w: r0[w][0] for w in WHEELS},
            "r0_source": {w: r0[w][1] for w in WHEELS},
            "r0_se_m": {w: self._cal.radius[w].standard_error_m for w in WHEELS},
            "cx_fit_n": {w: self._cal.stiffness[w].cx_n for w in WHEELS},
            "cx_fit_conf": {w: self._cal.stiffness[w].confidence for w in WHEELS},
            "rejected_fixes": self.rejected_fixes,
        }
