"""Coast-downs decided online, and the road loads fitted to them (SAE J2263 / J1263, WLTP GTR 15 annex 4). Pure.

A coast: no brake (no pressed brake sample since it began) and no drive force, from at least [test] coast_from_kmh down
to coast_to_kmh. Online: estimate rows (on GPS) come in order; a run is open while the speed does not rise more than
RISE_TOLERANCE_MPS above its lowest so far (a cruise before the coast is in it), and is decided at the first row below
coast_to_kmh. Its fit span begins where the speed has fallen START_DROP_MPS below the run's highest and ends at the
last row at or above coast_to_kmh. It is a coast when that span starts at coast_from_kmh or above and each of its
speed blocks (BLOCK_DROP_MPS of speed each) has MIN_BLOCK_ROWS rows or more and decelerates by less than
MAX_DECEL_MPS2 (else: braking) and lasts less than MAX_BLOCK_S (longer: the driver held the speed); else it makes no
record.

Fit, per run: M*k*dV/dt = -(F0 + F1*V + F2*V^2) (M*k: the equivalent mass, [vehicle] rotating_mass_factor k),
integrated from the span's start (the integral method: every row, no differentiated speed):
    V(t_i) = V0 - (F0*t_i + F1*int(V dt) + F2*int(V^2 dt))/(M*k)      (integrals by the trapezoid rule)
linear in (V0, F0, F1, F2): least squares, with the coefficients' covariance s^2*(X'X)^-1. A wind w along the road
adds -+2*F2*w to F1 and F2*w^2 to F0, a grade +-M*g*sin to F0: runs in opposite directions (GPS course 180 +-
COURSE_TOLERANCE_DEG apart) are paired, and the road loads are the mean of the paired runs' coefficients (each pair's
wind and grade terms cancel; F2*w^2 stays in F0), with 95 % intervals from their covariances. A run paired with none
gives its own fit (invalid: wind and grade not cancelled).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from slipdaq.config import Config

RISE_TOLERANCE_MPS = 0.3
"""A speed this far above the run's lowest ends the run (the driver accelerates)."""
START_DROP_MPS = 0.5
BLOCK_DROP_MPS = 1.0
MAX_DECEL_MPS2 = 1.5
MAX_BLOCK_S = 40.0
MIN_BLOCK_ROWS = 5
COURSE_TOLERANCE_DEG = 20.0
"""Two runs are in opposite directions when their courses differ by 180 degrees within this."""
Z95 = 1.959963984540054
Triple = tuple[float, float, float]


def _triple(values: Any) -> Triple:
    a, b, c = (float(x) for x in values)
    return a, b, c


@dataclass(frozen=True)
class CoastFit:
    """One run's road loads (F0 [N], F1 [N/(m/s)], F2 [N/(m/s)^2]) and their covariance."""

    coefficients: Triple
    covariance: tuple[Triple, Triple, Triple]
    course_deg: float | None
    """The run's mean GPS course; None: the fixes gave none."""


@dataclass(frozen=True)
class CoastRun:
    """A decided coast: its span, its own fit and the road loads it gives with the runs paired so far."""

    t_start_s: float
    t_end_s: float
    speed_from_kmh: float
    speed_to_kmh: float
    fit: CoastFit
    loads: Triple
    loads_lo: Triple
    loads_hi: Triple
    runs_paired: int
    """Runs the loads average, in pairs of opposite directions (0: this run's own fit)."""
    reasons: tuple[str, ...]


def coast_check(times_s: np.ndarray, speeds_mps: np.ndarray) -> str | None:
    """Why V(t) is not a coast (a block of BLOCK_DROP_MPS lost too fast: braking; too slowly: driven), or None."""
    start, n = 0, len(speeds_mps)
    while start < n:
        end = start
        while end < n and speeds_mps[start] - speeds_mps[end] < BLOCK_DROP_MPS:
            end += 1
        t, v = times_s[start:end + 1], speeds_mps[start:end + 1]
        near = f"near {float(np.mean(v)) * 3.6:.0f} km/h"
        if len(t) < MIN_BLOCK_ROWS and end < n:
            return f"{BLOCK_DROP_MPS:.0f} m/s of speed lost in {len(t)} rows {near} (braking)"
        if t[-1] - t[0] > MAX_BLOCK_S:
            return f"the speed held {t[-1] - t[0]:.0f} s {near} (driven)"
        if len(t) >= MIN_BLOCK_ROWS and float(np.polyfit(t - t.mean(), v, 1)[0]) < -MAX_DECEL_MPS2:
            return f"decelerating faster than {MAX_DECEL_MPS2} m/s^2 {near} (braking)"
        start = end + 1
    return None


def fit_road_loads(times_s: np.ndarray, speeds_mps: np.ndarray, equivalent_mass_kg: float
                   ) -> tuple[Triple, np.ndarray] | str:
    """(F0, F1, F2) and their covariance from one coast's V(t) (module docstring), or why it is not a coast."""
    why = coast_check(times_s, speeds_mps)
    if why is not None:
        return why
    if len(times_s) < 20:
        return "too few rows to fit"
    dt = np.diff(times_s)
    mid = 0.5 * (speeds_mps[1:] + speeds_mps[:-1])
    mid2 = 0.5 * (speeds_mps[1:] ** 2 + speeds_mps[:-1] ** 2)
    integrals = [np.concatenate(([0.0], np.cumsum(dt * k))) for k in (np.ones_like(mid), mid, mid2)]
    x = np.column_stack([np.ones_like(times_s)] + [-i / equivalent_mass_kg for i in integrals])
    coef, *_ = np.linalg.lstsq(x, speeds_mps, rcond=None)
    resid = speeds_mps - x @ coef
    s2 = float(resid @ resid) / (len(times_s) - 4)
    cov = s2 * np.linalg.inv(x.T @ x)[1:, 1:]
    return _triple(coef[1:]), cov


def mean_course_deg(courses: list[float]) -> float | None:
    if not courses:
        return None
    rad = np.radians(courses)
    return float(np.degrees(math.atan2(float(np.mean(np.sin(rad))), float(np.mean(np.cos(rad))))) % 360.0)


def opposite(a_deg: float | None, b_deg: float | None) -> bool:
    """The courses differ by 180 degrees within COURSE_TOLERANCE_DEG."""
    if a_deg is None or b_deg is None:
        return False
    diff = abs((a_deg - b_deg) % 360.0 - 180.0)
    return diff <= COURSE_TOLERANCE_DEG


def paired_loads(pairs: list[tuple[CoastFit, CoastFit]]) -> tuple[Triple, Triple, Triple]:
    """(mean, low, high) of the paired runs' coefficients: the mean over every run, its variance the sum of the runs'
    variances over the number of runs squared."""
    fits = [f for pair in pairs for f in pair]
    coef = np.mean([f.coefficients for f in fits], axis=0)
    var = np.sum([np.diag(np.array(f.covariance)) for f in fits], axis=0) / len(fits) ** 2
    half = Z95 * np.sqrt(var)
    return _triple(coef), _triple(coef - half), _triple(coef + half)


class CoastDetector:
    """Estimate rows, brake samples and GPS courses in (time order each); decided CoastRuns out (add_estimate)."""

    def __init__(self, config: Config) -> None:
        self.from_mps = config.test.coast_from_kmh / 3.6
        self.to_mps = config.test.coast_to_kmh / 3.6
        self.equivalent_mass_kg = config.vehicle.mass_kg * config.vehicle.rotating_mass_factor
        self._times: list[float] = []
        self._speeds: list[float] = []
        self._lowest, self._highest = math.inf, -math.inf
        self._last_pressed_s = -math.inf
        self._courses: list[tuple[float, float]] = []
        self.runs: list[CoastFit] = []
        """Every coast fitted so far, in order."""
        self.pairs: list[tuple[CoastFit, CoastFit]] = []

    def add_brake(self, time_s: float, value: float) -> None:
        if value:
            self._last_pressed_s = max(self._last_pressed_s, time_s)

    def add_course(self, time_s: float, course_deg: float | None) -> None:
        if course_deg is not None and self._times:
            self._courses.append((time_s, course_deg))

    def _restart(self) -> None:
        self._times, self._speeds, self._courses = [], [], []
        self._lowest, self._highest = math.inf, -math.inf

    def add_estimate(self, row: dict[str, Any]) -> CoastRun | None:
        """One estimate row; the coast it decides, if any."""
        return self.add(row.get("time_s"), row.get("speed_mps"), row.get("source", "gps"))

    def add(self, t: float | None, v: float | None, source: str | None) -> CoastRun | None:
        """One estimate's time_s, speed_mps and source (its row's values); the coast it decides, if any."""
        if t is None or v is None or source != "gps" \
                or self._last_pressed_s >= (self._times[0] if self._times else t) - 0.5:
            self._restart()
            return None
        if v > self._lowest + RISE_TOLERANCE_MPS:
            self._restart()
        self._times.append(t)
        self._speeds.append(v)
        self._lowest = min(self._lowest, v)
        self._highest = max(self._highest, v)
        if v >= self.to_mps:
            return None
        run = self._decide() if self._highest >= self.from_mps else None
        self._restart()
        return run

    def _decide(self) -> CoastRun | None:
        times, speeds = np.array(self._times), np.array(self._speeds)
        top = int(np.argmax(speeds))
        below = np.flatnonzero(speeds[top:] < speeds[top] - START_DROP_MPS)
        if not below.size:
            return None
        i0 = top + int(below[0])
        i1 = len(speeds) - 2  # the last row at or above coast_to (the newest one is below)
        if speeds[i0] < self.from_mps or i1 <= i0:
            return None
        t, v = times[i0:i1 + 1], speeds[i0:i1 + 1]
        span = (float(t[0]), float(t[-1]), float(v[0]) * 3.6, float(v[-1]) * 3.6)
        fitted = fit_road_loads(t, v, self.equivalent_mass_kg)
        if isinstance(fitted, str):  # not a coast after all
            return None
        coef, cov = fitted
        course = mean_course_deg([c for tc, c in self._courses if span[0] <= tc <= span[1]])
        fit = CoastFit(coef, (_triple(cov[0]), _triple(cov[1]), _triple(cov[2])), course)
        partner = next((r for r in reversed(self.runs) if opposite(r.course_deg, course)
                        and not any(r is x for p in self.pairs for x in p)), None)
        self.runs.append(fit)
        if partner is not None:
            self.pairs.append((partner, fit))
        if self.pairs:
            loads, lo, hi = paired_loads(self.pairs)
            return CoastRun(*span, fit, loads, lo, hi, 2 * len(self.pairs), ())
        half = Z95 * np.sqrt(np.diag(cov))
        why = "no GPS course" if course is None else "no run in the opposite direction yet (wind and grade not " \
                                                       "cancelled)"
        return CoastRun(*span, fit, coef, _triple(np.array(coef) - half), _triple(np.array(coef) + half), 0, (why,))
