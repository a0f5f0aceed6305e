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

The parts, each with its own state: the GPS track (gps_track.py: reference speed, acceleration, weights), the
wheels' windows (windows.py), readiness (readiness.py: when wheel samples release an estimate), GPS latency
(latency.py), free-rolling radius (radius.py), stiffness (stiffness.py) and force (force.py). SlipEstimator composes
them. Pure: records in, estimates out, deterministic in the order records are given. No clock, no I/O.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from slipdaq import WHEELS
from slipdaq.calibration import Calibration, Learned
from slipdaq.config import Config
from slipdaq.estimator.fast_slip import FastSlipRows
from slipdaq.estimator.force import AltitudeGrade, driven_wheels, longitudinal_force_n, tire_forces
from slipdaq.estimator.gps_lost import WheelClockEstimates
from slipdaq.estimator.gps_track import MAX_GPS_GAP_S, TIME_TOL_S, GpsTrack, integrate_speed_m, smooth_arrival
from slipdaq.estimator.latency import LatencyEstimate, UtcLatency, WheelLatency, WheelLatencyRows
from slipdaq.estimator.phase import PHASE_ACCEL_MPS2, STANDSTILL_SPEED_MPS, phase_of
from slipdaq.estimator.radius import RadiusCalibration, r0_per_wheel
from slipdaq.estimator.readiness import (
    MODE_READY,
    MODE_WAIT,
    MODE_WHEELS,
    SCAN_GPS_LOST,
    SCAN_READY,
    head_ready,
    scan_samples,
)
from slipdaq.estimator.ring import SeriesRing
from slipdaq.estimator.stiffness import StiffnessFit
from slipdaq.estimator.windows import WheelWindows, reference_slip, slip_from_distances
from slipdaq.records import Estimate, FastSlip, GpsFix, SourceEvent, WheelEstimate, WheelSample

__all__ = ["EstimatorParams", "SlipEstimator", "PHASE_ACCEL_MPS2", "STANDSTILL_SPEED_MPS", "phase_of",
           "integrate_speed_m", "slip_from_distances", "tire_forces"]

WHEEL_INDEX = {w: i for i, w in enumerate(WHEELS)}
STORED_LATENCY_SIGMA_S = 0.01
"""A stored latency without its sigma counts as this uncertain."""
UTC_LATENCY_SIGMA_S = 0.005
"""The UTC method's latency counts as this uncertain (NMEA times to 0.01 s, the host clock's own jitter)."""
LATENCY_TOLERANCE_S = 0.005
R0_TOLERANCE_M = 0.001
"""A radius changes by this much with tire temperature and pressure within a day (0.3 bar: about 1 mm), and a run's
own radius early on can be a few tenths of a mm off by more than its standard error says: not a contradiction."""
CX_CONFIDENT = 0.5
"""A stiffness fit this confident is stored."""
CX_CONTRADICTS = 0.8
CX_TOLERANCE = 0.2
"""A fit this confident contradicts a stored Cx when they differ by more than 3 sigma and CX_TOLERANCE: the fit's
confidence understates its spread from run to run (the same car and road: +-15 % within the first half minute), and
Cx changes with the road and the tire's temperature."""
UNCALIBRATED_R0 = ("tire_size", "other_wheels")
CAN_EPOCH_INTERVAL_S = 0.1
"""Windows of a reference speed on CAN are centred this far apart (EstimatorParams.epoch_interval_s)."""
EPOCH_TOLERANCE_S = 0.005
"""A CAN reference's arrival jitter: a fix this much early still starts a window."""
IMU_MAX_GAP_S = 0.1
"""A window's IMU samples may end this long before its end (their frames arrive with the wheels'), and have no
interval longer than this, for its acceleration to come from the IMU."""
"""r0 sources that make a window's quality 'uncalibrated' (its own radius not measured)."""


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
    fast_rate_hz: float
    """The high-rate slip's grid (0: none)."""
    epoch_interval_s: float
    """Reference fixes closer than this to the last estimated one make no window of their own (a CAN reference at
    100 Hz: windows at 10 Hz, as from a GPS receiver); 0: every fix."""

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
            grade_from_altitude=e.grade_from_altitude, fast_rate_hz=e.fast_rate_hz,
            epoch_interval_s=CAN_EPOCH_INTERVAL_S if cfg.gps.source == "can" else 0.0,
        ), **overrides)


class SlipEstimator:
    """Feed wheel samples and GPS fixes in record order; each call returns the estimates that became ready.

    An estimate is centred on every valid GPS epoch and is ready when GPS and every wheel that is reporting have
    samples past the window's end (or GPS is a further window past it, for a silent wheel).
    """

    def __init__(self, params: EstimatorParams, stored: Calibration | None = None, frozen: bool = False) -> None:
        """stored: a calibration to start from (used until the run measures better, dropped where the run contradicts
        it); frozen: use the stored latency and radii throughout and learn none (the second pass of a replay)."""
        self.p = params
        self.frozen = frozen and stored is not None
        self._stored_latency = (stored.latency.latency_s, stored.latency.sigma_s or STORED_LATENCY_SIGMA_S) \
            if stored is not None and stored.latency is not None and params.gps_latency_s is None else None
        self._stored_r0: dict[str, tuple[float, float]] = {w: (r.radius_m, r.se_m) for w, r in stored.r0.items()} \
            if stored is not None and params.calibrate_r0 else {}
        self._stored_cx: dict[str, tuple[float, float]] = \
            {w: (c.cx_n, c.confidence) for w, c in stored.cx.items()} if stored is not None else {}
        self.events: list[SourceEvent] = []
        """Stored values the run replaced, for /diagnostics/events (the pipeline takes them)."""
        self._track = GpsTrack()
        self._grade = AltitudeGrade()
        self._windows = WheelWindows()
        self._pending: deque[tuple[float, float]] = deque()  # epochs still to estimate: (arrival, UTC or NaN)
        self._utc = UtcLatency(params.max_latency_s)
        self._lag = WheelLatency(params.max_latency_s, slip_terms=params.driven_axle == "all")
        self._driven = driven_wheels(params.driven_axle)
        self._reference = tuple(w for w in WHEELS if w not in self._driven)
        self._lag_rows = WheelLatencyRows(self._lag, not self._reference, params.max_latency_s, params.window_s)
        self._radius = {w: RadiusCalibration() for w in WHEELS}
        self._stiffness = {w: StiffnessFit() for w in WHEELS}
        self._wheel_clock = WheelClockEstimates(params.window_s, self._reference, self._driven,
                                                params.min_speed_mps * params.window_s)
        self._last_center_s = -math.inf
        self._latency: LatencyEstimate | None = None
        self._utc_offset_s: float | None = None
        """The UTC offset of the latency in use (set with it)."""
        self.rejected_fixes = 0
        self._head: tuple[int, float, float] | None = None  # the head epoch's readiness constants (_head_consts)
        self._last_epoch_s = -math.inf
        self._imu = SeriesRing(1024)
        """IMU sample time -> longitudinal acceleration."""
        self._fast = FastSlipRows(params.fast_rate_hz, params.min_speed_mps) if params.fast_rate_hz > 0 else None
        self.fast_rows: list[FastSlip] = []
        """High-rate slip rows released, for /slip/fast (the pipeline takes them)."""

    # ---- latency ------------------------------------------------------------------------------------
    @property
    def latency(self) -> LatencyEstimate:
        """The GPS latency in use and, with it, the UTC offset (cached; they change only when a fix or an estimate
        comes)."""
        if self._latency is None:
            self._latency, self._utc_offset_s = self._current_latency(), self._utc.offset_s()
        return self._latency

    def _current_latency(self) -> LatencyEstimate:
        utc = self._utc.estimate()
        lag = self._lag
        wheels = lag.latency_s if lag.converged() else None
        if self.p.gps_latency_s is not None:
            return LatencyEstimate(self.p.gps_latency_s, "fixed", utc, wheels, lag.sigma_s)
        stored = self._stored_latency
        if stored is not None and self.frozen:
            return LatencyEstimate(stored[0], "stored", utc, wheels, lag.sigma_s)
        if wheels is not None and (utc is None or (abs(utc - wheels) > 3.0 * (lag.sigma_s or 0.0) + 0.02
                                                   and not lag.slip_terms)):
            # measured alignment beats an assumption about the host clock when the two disagree (not when it rests
            # on a model of the wheels' slip: every wheel driven)
            own = LatencyEstimate(wheels, "wheels", utc, wheels, lag.sigma_s)
            own_sigma = lag.sigma_s or 0.0
        elif utc is not None:
            own, own_sigma = LatencyEstimate(utc, "utc", utc, wheels, lag.sigma_s), UTC_LATENCY_SIGMA_S
        elif stored is not None:
            return LatencyEstimate(stored[0], "stored", utc, wheels, lag.sigma_s)
        else:
            return LatencyEstimate(0.0, "none", utc, wheels, lag.sigma_s)
        if stored is None:
            return own
        if abs(own.latency_s - stored[0]) > 3.0 * math.hypot(own_sigma, stored[1]) + LATENCY_TOLERANCE_S:
            self._replaced(f"GPS latency: stored {stored[0] * 1000:.1f} ms, this run {own.latency_s * 1000:.1f} ms "
                           f"({own.source})")
            self._stored_latency = None
            return own
        return own if own_sigma < stored[1] else LatencyEstimate(stored[0], "stored", utc, wheels, lag.sigma_s)

    def _replaced(self, detail: str) -> None:
        self.events.append(SourceEvent(self._track.last_t, "calibration", "replaced", detail))

    def take_events(self) -> list[SourceEvent]:
        events, self.events = self.events, []
        return events

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

    def add_imu(self, time_s: float, accel_mps2: float) -> None:
        """One IMU sample (longitudinal acceleration, forward positive) on the host's clock; older than the last: dropped."""
        if time_s > self._imu.last_t and math.isfinite(accel_mps2):
            self._imu.append(time_s, accel_mps2)
            if self._fast is not None:
                self._fast.speed.add_imu(time_s, accel_mps2)

    def take_fast(self) -> list[FastSlip]:
        rows, self.fast_rows = self.fast_rows, []
        return rows

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
        return out

    def _fast_fix(self, arrival_s: float, utc_s: float, speed_mps: float, accuracy_mps: float | None) -> None:
        """The fix into the vehicle-speed filter at its fix time; the high-rate slip rows that became ready."""
        assert self._fast is not None
        fix_s = smooth_arrival(arrival_s, utc_s, self._utc_offset_s) - self.latency.latency_s
        self._fast.speed.add_speed(fix_s, speed_mps, accuracy_mps if accuracy_mps is not None else math.nan)
        r0 = self._r0_all()
        self.fast_rows += self._fast.release(self._windows.rings, [r0[w][0] for w in WHEELS], fix_s)

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
        self._imu.drop_before = keep
        return out

    # ---- the estimate -------------------------------------------------------------------------------
    def _estimate(self, arrival_s: float, lat: LatencyEstimate) -> Estimate:
        p = self.p
        track = self._track
        smooth = track.smooth_arrivals(self._utc_offset_s)
        i = int(track.speed.times.searchsorted(arrival_s))
        latency_s = lat.latency_s
        fix_arr = smooth - latency_s
        fix_times, speeds = fix_arr.tolist(), track.speed.values.tolist()
        t_c = fix_times[i]
        t0, t1 = t_c - 0.5 * p.window_s, t_c + 0.5 * p.window_s
        speed_c = speeds[i]
        accel = self._imu_accel(t0, t1)
        accel_source = "imu" if accel is not None else "gps"
        if accel is None:
            accel = track.accel(fix_times, speeds, t_c)
        if p.gps_latency_s is None:
            self._lag_rows.observe(float(smooth[i]), speed_c, [self._windows.by_wheel[w] for w in self._reference or WHEELS])
        covered = track.covers(fix_times, t0, t1)
        d_gps = integrate_speed_m(fix_arr, track.speed.values, t0, t1) if covered else None
        speed = d_gps / p.window_s if d_gps is not None else speed_c
        gps_gap = covered and track.gap_in(fix_times, t0, t1)
        latency_unknown = lat.source == "none"
        # with the latency unknown, a window whose speed changes measures the latency, not the tire: no slip
        d_slip = None if latency_unknown and (accel is None or abs(accel) > PHASE_ACCEL_MPS2) else d_gps
        force = None
        if accel is not None:
            sin_grade = self._grade.sin_grade(track, fix_times, fix_arr, t_c, lat.latency_s) \
                if p.grade_from_altitude else 0.0
            force = longitudinal_force_n(p.mass_kg, accel, speed, sin_grade, p.rolling_resistance_coeff,
                                         p.drag_area_m2, p.air_density_kgpm3)
        per_tire = tire_forces(force, p.driven_axle, p.brake_front_share) if force is not None else {}
        arcs, gapped = self._windows.window(t0, t1)
        weight = track.weight(fix_times, t0, t1)
        if p.calibrate_r0 and not self.frozen and accel is not None and d_gps is not None \
                and speed >= p.r0_min_speed_mps:
            # While accelerating, the GPS latency must be known; at steady speed it does not matter.
            steady = abs(accel) <= PHASE_ACCEL_MPS2
            for w in WHEELS:
                arc = arcs[w]
                if arc is not None and self._free_rolling(w, accel) and (steady or lat.source != "none"):
                    self._radius[w].add(d_gps, arc, weight)
        if self._stored_r0 or self._stored_cx:
            self._check_stored()
        r0 = self._r0_all()
        slip_nd = self._reference_slip(arcs, r0)
        stored_cx = self._stored_cx
        wheels = {w: wheel_estimate(p, self._stiffness[w], arcs[w], r0[w], d_slip, per_tire.get(w), speed, weight,
                                    slip_nd.get(w), stored_cx.get(w))
                  for w in WHEELS}
        self._last_center_s = t_c
        if gapped or gps_gap:
            quality = "disturbed"
        elif latency_unknown or any(we.r0_source in UNCALIBRATED_R0 for we in wheels.values() if we.slip is not None):
            quality = "uncalibrated"
        else:
            quality = "ok"
        return Estimate(
            t_c, speed, accel, force, p.window_s, wheels,
            phase=phase_of(speed, accel),
            source="gps", gps_latency_s=lat.latency_s, latency_source=lat.source, quality=quality,
            accel_source=accel_source,
        )

    def _imu_accel(self, t0: float, t1: float) -> float | None:
        """The mean of the IMU's samples over [t0, t1] (Fx = M*a, eq. 3.8, from the IMU), or None unless they span the
        window within IMU_MAX_GAP_S."""
        ring = self._imu
        if len(ring) < 2 or ring.first_time > t0 or ring.last_t < t1 - IMU_MAX_GAP_S:
            return None
        times = ring.times
        i0, i1 = int(times.searchsorted(t0)), int(times.searchsorted(t1, side="right"))
        if i1 - i0 < 2 or ring.longest_gap(t0, min(t1, ring.last_t)) > IMU_MAX_GAP_S:
            return None
        return float(np.mean(ring.values[i0:i1]))

    def _free_rolling(self, w: str, accel: float) -> bool:
        """The tire carries little force: a non-driven wheel when not braking, any wheel when coasting."""
        thr = PHASE_ACCEL_MPS2
        return abs(accel) <= thr or (w in self._reference and accel >= -thr)

    def _r0_all(self) -> dict[str, tuple[float, str]]:
        p = self.p
        stored = {w: r for w, (r, _) in self._stored_r0.items()}
        return r0_per_wheel(self._radius, p.r_ref_m, p.r_ref_configured, p.calibrate_r0, stored, own=not self.frozen)

    def _check_stored(self) -> None:
        """Stored radii and stiffnesses that the run's own converged values contradict beyond both uncertainties
        are dropped (the run's own are used from then on), each with an event. Converged, not just usable: early in
        a run a radius's standard error understates its spread (overlapping windows), which made false alarms."""
        if self.frozen:
            return
        for w, (radius, se) in list(self._stored_r0.items()):
            cal = self._radius[w]
            own, own_se = cal.radius_m, cal.standard_error_m
            if own is not None and own_se is not None and cal.converged \
                    and abs(own - radius) > 3.0 * math.hypot(own_se, se) + R0_TOLERANCE_M:
                del self._stored_r0[w]
                self._replaced(f"r0 {w}: stored {radius * 1000:.2f} mm, this run {own * 1000:.2f} mm "
                               f"(+- {own_se * 1000:.2f} mm)")
        for w, (cx, conf) in list(self._stored_cx.items()):
            fit = self._stiffness[w]
            if fit.cx_n is not None and fit.confidence >= CX_CONTRADICTS and abs(fit.cx_n / cx - 1.0) > max(
                    3.0 * math.hypot(cx_relative_se(fit.confidence), cx_relative_se(conf)), CX_TOLERANCE):
                del self._stored_cx[w]
                self._replaced(f"Cx {w}: stored {cx / 1000:.1f} kN, this run {fit.cx_n / 1000:.1f} kN")

    def learned(self) -> Learned:
        """What this run measured itself: the latency by the wheels or UTC, the host clock's offset from UTC, the
        radii that converged (or replaced a stored one), the stiffness fits with confidence >= CX_CONFIDENT. Nothing
        for a frozen (second-pass) estimator."""
        if self.frozen:
            return Learned()
        lat = self.latency
        latency = None
        if lat.source == "wheels":
            latency = (lat.latency_s, lat.wheels_sigma_s, "wheels")
        elif lat.source == "utc":
            latency = (lat.latency_s, UTC_LATENCY_SIGMA_S, "utc")
        offset = self._utc_offset_s
        clock = offset - lat.latency_s if offset is not None and math.isfinite(offset) and lat.source != "none" \
            else None
        r0 = {}
        for w, cal in self._radius.items():
            radius, se = cal.radius_m, cal.standard_error_m
            if radius is not None and se is not None and (cal.converged or (cal.usable and w not in self._stored_r0)):
                r0[w] = (radius, se)
        cx = {w: (f.cx_n, f.confidence) for w, f in self._stiffness.items()
              if f.cx_n is not None and f.confidence >= CX_CONFIDENT}
        return Learned(latency, clock, r0, cx)

    def _reference_slip(self, arcs: dict[str, float | None], r0: dict[str, tuple[float, str]]) -> dict[str, float]:
        return reference_slip(arcs, r0, self._reference, self._driven, self.p.min_speed_mps * self.p.window_s)

    # ---- GPS lost: estimates on the wheels' clock -----------------------------------------------------
    def _gps_lost(self) -> list[Estimate]:
        """Epochs that will get no later fix are estimated with what there is; then the wheels' clock takes over."""
        out: list[Estimate] = []
        lat = self.latency
        while self._pending:
            out.append(self._estimate(self._pending.popleft()[0], lat))
        self._head = None
        clock = self._wheel_clock.due(self._windows, self._r0_all(), self.latency, self._last_center_s,
                                      self._track.last_t)
        if clock:
            self._last_center_s = clock[-1].time_s
        return out + clock

    # ---- state for diagnostics ----------------------------------------------------------------------
    def status(self) -> dict[str, object]:
        lat = self.latency
        r0 = self._r0_all()
        return {
            "gps_latency_s": lat.latency_s,
            "latency_source": lat.source,
            "gps_latency_utc_s": lat.utc_s,
            "gps_latency_wheels_s": self._lag.latency_s,
            "gps_latency_wheels_sigma_s": lat.wheels_sigma_s,
            "r0_m": {w: r0[w][0] for w in WHEELS},
            "r0_source": {w: r0[w][1] for w in WHEELS},
            "r0_se_m": {w: self._radius[w].standard_error_m for w in WHEELS},
            "cx_fit_n": {w: self._stiffness[w].cx_n for w in WHEELS},
            "cx_fit_conf": {w: self._stiffness[w].confidence for w in WHEELS},
            "rejected_fixes": self.rejected_fixes,
        }


def cx_relative_se(confidence: float) -> float:
    """The relative standard error of a fitted Cx from its confidence (stiffness.py: 1 - 10 * relative SE)."""
    return (1.0 - confidence) / 10.0


def wheel_estimate(
    p: EstimatorParams, fit: StiffnessFit, arc: float | None, r0: tuple[float, str], d_gps: float | None,
    force: float | None, speed: float, weight: float = 1.0, slip_nd: float | None = None,
    stored_cx: tuple[float, float] | None = None,
) -> WheelEstimate:
    """One wheel's slip, Re, Cx over the window (arc: 2*pi*N; d_gps: the GPS distance); feeds its stiffness fit.
    The fitted Cx reported is the run's own, else the stored one."""
    r0_m, r0_source = r0
    cx_fit: float | None
    cx_conf: float | None
    cx_fit, cx_conf = (fit.cx_n, fit.confidence) if fit.cx_n is not None or stored_cx is None else stored_cx
    if arc is None:
        return WheelEstimate(None, None, r0_m, None, force, None, r0_source, None, cx_fit, cx_conf)
    d_wpt = r0_m * arc
    wheel_speed = d_wpt / p.window_s
    if d_gps is None or d_gps < p.min_speed_mps * p.window_s or arc <= 0:
        return WheelEstimate(None, None, r0_m, None, force, wheel_speed, r0_source, slip_nd, cx_fit, cx_conf)
    slip = slip_from_distances(d_wpt, d_gps)
    re = d_gps / arc
    cx = None
    if force is not None and force != 0 and p.cx_slip_min <= abs(slip) <= p.cx_slip_max and force / slip > 0:
        cx = force / slip
    if force is not None and speed >= p.fit_min_speed_mps and abs(slip) <= p.cx_slip_max:
        fit.add(force, arc / d_gps, weight)
    if fit.cx_n is not None or stored_cx is None:
        cx_fit, cx_conf = fit.cx_n, (fit.confidence if fit.cx_n is not None else None)
    return WheelEstimate(slip, re, r0_m, cx, force, wheel_speed, r0_source, slip_nd, cx_fit, cx_conf)
