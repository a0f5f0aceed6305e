"""Longitudinal force from the car's acceleration (docs/method.md):
  Fx = M*k*a + F_road(v) + M*g*sin(grade),   k = rotating_mass_factor (the wheels' and driveline's inertia)
  F_road = f_rr*M*g*cos(grade) + rho/2*CdA*v^2       (the config's coefficients, each off unless set), or
  F_road = F0 + F1*v + F2*v^2                         (the calibration's coast-down road loads, RoadLoads)
split per tire: evenly over the driven wheels when Fx >= 0, by the brake's front share when Fx < 0. The grade comes
from GPS altitude over the last 2 s (backward, so no wait for future fixes).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from slipdaq import WHEELS
from slipdaq.estimator.gps_track import GpsTrack, integrate_speed_m
from slipdaq.estimator.ring import SeriesRing

G_MPS2 = 9.81
GRADE_SPAN_S = 2.0
MAX_SIN_GRADE = 0.3
MIN_GRADE_DISTANCE_M = 5.0


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


class RoadLoads(NamedTuple):
    """A coast-down's road loads F_road(v) = F0 + F1*v + F2*v^2 [N]."""

    f0_n: float
    f1_n_per_mps: float
    f2_n_per_mps2: float

    def force_n(self, speed_mps: float) -> float:
        return self.f0_n + self.f1_n_per_mps * speed_mps + self.f2_n_per_mps2 * speed_mps * speed_mps


def longitudinal_force_n(mass_kg: float, accel_mps2: float, speed_mps: float, sin_grade: float,
                         rolling_resistance_coeff: float, drag_area_m2: float, air_density_kgpm3: float,
                         rotating_mass_factor: float = 1.0, road_loads: RoadLoads | None = None) -> float:
    """Fx = M*k*a + f_rr*M*g*cos + rho/2*CdA*v^2 + M*g*sin; with road_loads, F0 + F1*v + F2*v^2 in place of the
    f_rr and CdA terms."""
    inertia = mass_kg * rotating_mass_factor * accel_mps2
    if road_loads is not None:
        return inertia + road_loads.force_n(speed_mps) + mass_kg * G_MPS2 * sin_grade
    cos_grade = math.sqrt(1.0 - sin_grade * sin_grade)
    return (
        inertia
        + rolling_resistance_coeff * mass_kg * G_MPS2 * cos_grade
        + 0.5 * air_density_kgpm3 * drag_area_m2 * speed_mps * speed_mps
        + mass_kg * G_MPS2 * sin_grade
    )


class AltitudeGrade:
    """sin(grade) from the fixes' altitude: climb over the distance driven in the last GRADE_SPAN_S."""

    def __init__(self) -> None:
        self.altitude = SeriesRing(256)  # arrival time -> altitude

    def add(self, arrival_s: float, altitude_m: float) -> None:
        self.altitude.append(arrival_s, altitude_m)

    def sin_grade(self, track: GpsTrack, fix_times: list[float], fix_arr: np.ndarray, t_c: float,
                  latency_s: float) -> float:
        alt = self.altitude
        if len(alt) < 2:
            return 0.0
        alt_t = alt.times - latency_s
        t_a = t_c - GRADE_SPAN_S
        if alt_t[0] > t_a or alt_t[-1] < t_c or not track.covers(fix_times, t_a, t_c):
            return 0.0
        climb = float(np.interp(t_c, alt_t, alt.values) - np.interp(t_a, alt_t, alt.values))
        dist = integrate_speed_m(fix_arr, track.speed.values, t_a, t_c)
        return max(-MAX_SIN_GRADE, min(MAX_SIN_GRADE, climb / dist)) if dist > MIN_GRADE_DISTANCE_M else 0.0
