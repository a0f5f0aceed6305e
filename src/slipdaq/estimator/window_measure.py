"""One window's measurements, common to the four wheels (docs/method.md): its centre t_c at the fix time, the GPS
distance and speed over it, the acceleration (the IMU's mean, else the GPS central difference), the force and its
share per tire, the wheels' arcs 2*pi*N, and whether it was disturbed; and the Estimate they make with the wheels'."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from slipdaq.estimator.force import AltitudeGrade, RoadLoads, longitudinal_force_n, tire_forces
from slipdaq.estimator.gps_track import GpsTrack, integrate_speed_m
from slipdaq.estimator.imu_gain import SOURCE_CALIBRATED, SOURCE_RAW, ImuCorrection
from slipdaq.estimator.latency import LatencyEstimate
from slipdaq.estimator.params import EstimatorParams
from slipdaq.estimator.phase import PHASE_ACCEL_MPS2, phase_of
from slipdaq.estimator.ring import SeriesRing
from slipdaq.estimator.wheel_revolutions import WheelWindows
from slipdaq.records import Estimate, WheelEstimate

IMU_MAX_GAP_S = 0.1
"""A window's IMU samples may end this long before its end (their frames arrive with the wheels'), and have no
interval longer than this, for its acceleration to come from the IMU."""
UNCALIBRATED_R0 = ("tire_size", "other_wheels")
"""r0 sources that make a window's quality 'uncalibrated' (its own radius not measured)."""


@dataclass(frozen=True, slots=True)
class Window:
    t_c: float
    t0: float
    t1: float
    speed_mps: float
    """GPS distance / W, else the fix's speed."""
    accel_mps2: float | None
    accel_source: str
    force_n: float | None
    tire_force_n: dict[str, float]
    """Per wheel (empty without a force)."""
    arcs: dict[str, float | None]
    """Per wheel: 2*pi*N over the window, None where missing."""
    weight: float
    """From the GPS's stated speed accuracy."""
    d_gps_m: float | None
    """The GPS distance, None where the fixes do not cover the window."""
    d_slip_m: float | None
    """The GPS distance slip is taken against: None also where an unknown latency makes a speed change unusable."""
    disturbed: bool
    latency_unknown: bool
    imu_raw_mps2: float | None = None
    """The IMU's mean as it read (before an ImuCorrection), None without the IMU."""

    def estimate(self, wheels: dict[str, WheelEstimate], lat: LatencyEstimate, window_s: float,
                 uncalibrated: bool | None = None) -> Estimate:
        """uncalibrated: as radius_uncalibrated says of the wheels (None: of `wheels`; given for an estimate without
        its wheels)."""
        if uncalibrated is None:
            uncalibrated = radius_uncalibrated((we.slip, we.r0_source) for we in wheels.values())
        if self.disturbed:
            quality = "disturbed"
        elif self.latency_unknown or uncalibrated:
            quality = "uncalibrated"
        else:
            quality = "ok"
        return Estimate(
            self.t_c, self.speed_mps, self.accel_mps2, self.force_n, window_s, wheels,
            phase=phase_of(self.speed_mps, self.accel_mps2),
            source="gps", gps_latency_s=lat.latency_s, latency_source=lat.source, quality=quality,
            accel_source=self.accel_source,
        )


def radius_uncalibrated(slips_and_sources: Iterable[tuple[float | None, str]]) -> bool:
    """Whether a wheel with a slip over the window (its slip, its r0's source) has no radius of its own
    (UNCALIBRATED_R0): the window's quality is then 'uncalibrated'."""
    return any(source in UNCALIBRATED_R0 for slip, source in slips_and_sources if slip is not None)


def measure_window(p: EstimatorParams, track: GpsTrack, grade: AltitudeGrade, windows: WheelWindows,
                   imu: SeriesRing, fix_arr: np.ndarray, i: int, lat: LatencyEstimate, imu_source: str = SOURCE_RAW,
                   correction: ImuCorrection | None = None, road_loads: RoadLoads | None = None) -> Window:
    """The window centred on fix i (fix_arr: the fixes' times, arrival less latency); imu_source: where the IMU's
    samples come from (accel_source); correction: applied to a raw IMU's mean (accel_source imu-calibrated);
    road_loads: the calibration's coast-down road loads, in place of the config's coefficients."""
    fix_times, speeds = fix_arr.tolist(), track.speed.values.tolist()
    t_c = fix_times[i]
    t0, t1 = t_c - 0.5 * p.window_s, t_c + 0.5 * p.window_s
    speed_c = speeds[i]
    imu_raw = accel = imu_accel(imu, t0, t1)
    accel_source = imu_source if accel is not None else "gps"
    if accel is not None and correction is not None and imu_source == SOURCE_RAW:
        accel, accel_source = correction.apply(accel), SOURCE_CALIBRATED
    if accel is None:
        accel = track.accel(fix_times, speeds, t_c)
    covered = track.covers(fix_times, t0, t1)
    d_gps = integrate_speed_m(fix_arr, track.speed.values, t0, t1) if covered else None
    speed = d_gps / p.window_s if d_gps is not None else speed_c
    gps_gap = covered and track.gap_in(fix_times, t0, t1)
    latency_unknown = lat.source == "none"
    # with the latency unknown, a window whose speed changes measures the latency, not the tire: no slip
    d_slip = None if latency_unknown and (accel is None or abs(accel) > PHASE_ACCEL_MPS2) else d_gps
    force = None
    if accel is not None:
        sin_grade = grade.sin_grade(track, fix_times, fix_arr, t_c, lat.latency_s) if p.grade_from_altitude else 0.0
        force = longitudinal_force_n(p.mass_kg, accel, speed, sin_grade, p.rolling_resistance_coeff,
                                     p.drag_area_m2, p.air_density_kgpm3, p.rotating_mass_factor, road_loads)
    per_tire = tire_forces(force, p.driven_axle, p.brake_front_share) if force is not None else {}
    arcs, gapped = windows.window(t0, t1)
    weight = track.weight(fix_times, t0, t1)
    return Window(t_c, t0, t1, speed, accel, accel_source, force, per_tire, arcs, weight, d_gps, d_slip,
                  bool(gapped) or gps_gap, latency_unknown, imu_raw)


def imu_accel(ring: SeriesRing, t0: float, t1: float) -> float | None:
    """The mean of the IMU's samples over [t0, t1] (Fx = M*a, eq. 3.8, from the IMU), or None unless they span the
    window within IMU_MAX_GAP_S."""
    if len(ring) < 2 or ring.first_time > t0 or ring.last_t < t1 - IMU_MAX_GAP_S:
        return None
    times = ring.times
    i0, i1 = int(times.searchsorted(t0)), int(times.searchsorted(t1, side="right"))
    if i1 - i0 < 2 or ring.longest_gap(t0, min(t1, ring.last_t)) > IMU_MAX_GAP_S:
        return None
    return float(np.mean(ring.values[i0:i1]))
