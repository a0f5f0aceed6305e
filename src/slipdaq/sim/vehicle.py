"""Pure vehicle + tire model: the ground truth the simulator emits. No I/O, no clock.

Kinematic model of the profile scenarios (the slip-driven one is in dynamics.py). Longitudinal dynamics only:
    speed V(t)      jerk-limited profile (acceleration ramps linearly to its level in 0.5 s and back)
    Fx = M*a        total longitudinal force, split over the tires (drive: driven wheels; brake: brake_front_share)
    Fx_i = D*sin(C*atan(B*s_i)),  D = mu*Fz_i,  B*C*D = Cx_i = cx_per_fz*Fz_i   (simplified Pacejka)
    s_i = (omega_i*r0_i - V)/V  ->  omega_i = V*(1 + s_i)/r0_i
    theta_i = integral(omega_i dt) = (x + integral(V*s_i dt)) / r0_i
with x the travelled distance (exact, from the profile) and integral(V*s_i dt) by the trapezoid rule per step.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

from slipdaq import WHEELS
from slipdaq.config import Config
from slipdaq.sim import ProfileScenario
from slipdaq.sim.road_loads import RoadLoadTruth

Scenario = ProfileScenario
"""The scenarios of this (kinematic) model."""
Road = Literal["paved", "sand"]

G_MPS2 = 9.81
FRONT_LOAD_SHARE = 0.6
"""Share of M*g on the front axle (static, no load transfer)."""
JERK_RAMP_S = 0.5
"""Time for the acceleration to ramp from 0 to its level (and back)."""
CRUISE_SPEED_MPS = 25.0
CYCLE_SPEED_MPS = 60.0 / 3.6
STANDSTILL_S = 2.0
CRUISE_BEFORE_BRAKE_S = 3.0
TEST_DAY_SPEEDS_MPS = (60.0 / 3.6, 33.0 / 3.6)
"""test-day: 0–60, 60–0, 0–33, 33–0 km/h, each run to its speed, held 3 s, braked to a stop ..."""
TEST_DAY_STANDSTILL_S = 4.0
"""... and a stop this long after each."""
HIGHWAY_SPEEDS_MPS = (110.0 / 3.6, 60.0 / 3.6, 110.0 / 3.6)
"""highway: runs to 110, 60 and 110 km/h from a stop, each held HIGHWAY_CRUISE_S, braked to a stop ..."""
HIGHWAY_CRUISE_S = 15.0
HIGHWAY_ACCEL_MPS2 = 2.0
HIGHWAY_DECEL_MPS2 = 3.0


@dataclass(frozen=True)
class TireModel:
    """Simplified Pacejka longitudinal curve Fx = D*sin(C*atan(B*s)), D = mu*Fz, slip stiffness Cx = B*C*D."""

    mu: float
    cx_per_fz: float
    """Initial slope per unit load: Cx = dFx/ds at s=0 = cx_per_fz*Fz."""
    C: float = 1.65

    @property
    def b(self) -> float:
        """Stiffness factor B = cx_per_fz/(C*mu), so that B*C*D = cx_per_fz*Fz."""
        return self.cx_per_fz / (self.C * self.mu)

    @property
    def peak_slip(self) -> float:
        """|s| at the force peak: C*atan(B*s) = pi/2 -> s = tan(pi/(2C))/B."""
        return math.tan(math.pi / (2.0 * self.C)) / self.b

    @classmethod
    def with_peak(cls, mu: float, peak_slip: float, c: float) -> TireModel:
        """The curve of shape C whose peak mu lies at peak_slip: B = tan(pi/(2C))/peak_slip, cx_per_fz = B*C*mu."""
        return cls(mu=mu, cx_per_fz=math.tan(math.pi / (2.0 * c)) / peak_slip * c * mu, C=c)

    def force_n(self, slip: float, fz_n: float) -> float:
        """Fx = D*sin(C*atan(B*s))."""
        return self.mu * fz_n * math.sin(self.C * math.atan(self.b * slip))

    def slip_for_force(self, fx_n: float, fz_n: float) -> float:
        """Inverse on the stable branch: s = tan(asin(Fx/D)/C)/B, clamped at the peak when |Fx| > D."""
        if fx_n == 0.0:
            return 0.0
        ratio = max(-1.0, min(1.0, fx_n / (self.mu * fz_n)))
        return math.tan(math.asin(ratio) / self.C) / self.b

    def stiffness_n(self, fz_n: float) -> float:
        """Slip stiffness Cx = B*C*D = cx_per_fz*Fz [N per unit slip]."""
        return self.cx_per_fz * fz_n


ROADS: dict[str, TireModel] = {
    "paved": TireModel(mu=1.0, cx_per_fz=20.0),
    "sand": TireModel(mu=0.6, cx_per_fz=8.0),
}
ACCEL_MPS2: dict[str, float] = {"paved": 2.8, "sand": 2.0}
DECEL_MPS2: dict[str, float] = {"paved": 5.5, "sand": 3.0}


@dataclass(frozen=True, slots=True)
class _Segment:
    """Constant-jerk piece: a = a0 + j*tau, v = v0 + a0*tau + j*tau^2/2, x = x0 + v0*tau + a0*tau^2/2 + j*tau^3/6."""

    start_s: float
    x0_m: float
    v0_mps: float
    a0_mps2: float
    jerk_mps3: float

    def at(self, tau_s: float) -> tuple[float, float, float]:
        """(x, v, a) at tau_s after the segment's start."""
        a0, j = self.a0_mps2, self.jerk_mps3
        x = self.x0_m + tau_s * (self.v0_mps + tau_s * (a0 / 2.0 + tau_s * j / 6.0))
        v = self.v0_mps + tau_s * (a0 + tau_s * j / 2.0)
        return x, max(0.0, v), a0 + j * tau_s


class SpeedProfile:
    """Piecewise constant-jerk speed profile; the last segment runs forever unless the profile is periodic."""

    def __init__(self, initial_speed_mps: float = 0.0) -> None:
        self.segments: list[_Segment] = []
        self.period_s: float | None = None
        self.period_distance_m = 0.0
        self._t_s = 0.0
        self._x_m = 0.0
        self._v_mps = initial_speed_mps
        self._starts: list[float] = []

    def _add(self, duration_s: float, a0_mps2: float, jerk_mps3: float) -> None:
        seg = _Segment(self._t_s, self._x_m, self._v_mps, a0_mps2, jerk_mps3)
        self.segments.append(seg)
        self._starts.append(self._t_s)
        self._x_m, self._v_mps, _ = seg.at(duration_s)
        self._t_s += duration_s

    def hold(self, duration_s: float) -> SpeedProfile:
        """Constant speed (or standstill) for duration_s."""
        self._add(duration_s, 0.0, 0.0)
        return self

    def change_speed(self, target_mps: float, level_mps2: float) -> SpeedProfile:
        """Jerk-limited change to target_mps: ramp to +-level in JERK_RAMP_S, hold, ramp back to 0 at the target.

        dv = a_peak*(ramp + hold); when dv is too small for a full ramp, a_peak = sqrt(|dv|*jerk) (no hold).
        """
        dv = target_mps - self._v_mps
        sign = 1.0 if dv >= 0 else -1.0
        jerk = level_mps2 / JERK_RAMP_S
        if abs(dv) >= level_mps2 * JERK_RAMP_S:
            a_peak, ramp_s = level_mps2, JERK_RAMP_S
            hold_s = abs(dv) / level_mps2 - JERK_RAMP_S
        else:
            a_peak = math.sqrt(abs(dv) * jerk)
            ramp_s, hold_s = a_peak / jerk, 0.0
        self._add(ramp_s, 0.0, sign * jerk)
        if hold_s > 0:
            self._add(hold_s, sign * a_peak, 0.0)
        self._add(ramp_s, sign * a_peak, -sign * jerk)
        self._v_mps = target_mps  # snap the rounding residue: exact target, never negative
        return self

    def forever(self) -> SpeedProfile:
        """End with a segment at the final speed that runs forever."""
        self._add(0.0, 0.0, 0.0)
        return self

    def repeat(self) -> SpeedProfile:
        """Make the profile periodic (it must end at its initial speed)."""
        self.period_s = self._t_s
        self.period_distance_m = self._x_m
        return self

    def at(self, time_s: float) -> tuple[float, float, float]:
        """(distance x [m], speed V [m/s], acceleration a [m/s^2]) at time_s >= 0."""
        laps = 0
        if self.period_s is not None:
            laps = int(time_s // self.period_s)
            time_s -= laps * self.period_s
        seg = self.segments[max(0, bisect_right(self._starts, time_s) - 1)]
        x, v, a = seg.at(time_s - seg.start_s)
        return x + laps * self.period_distance_m, v, a


def speed_profile(scenario: Scenario, road: Road) -> SpeedProfile:
    """The scenario's speed profile with the road's acceleration and braking levels."""
    accel, decel = ACCEL_MPS2[road], DECEL_MPS2[road]
    if scenario == "accelerate":
        return SpeedProfile(0.0).hold(STANDSTILL_S).change_speed(CRUISE_SPEED_MPS, accel).forever()
    if scenario == "brake":
        return SpeedProfile(CRUISE_SPEED_MPS).hold(CRUISE_BEFORE_BRAKE_S).change_speed(0.0, decel).forever()
    if scenario == "cycle":
        return (
            SpeedProfile(0.0)
            .hold(STANDSTILL_S)
            .change_speed(CYCLE_SPEED_MPS, accel)
            .hold(CRUISE_BEFORE_BRAKE_S)
            .change_speed(0.0, decel)
            .repeat()
        )
    if scenario == "test-day":
        profile = SpeedProfile(0.0).hold(STANDSTILL_S)
        for target_mps in TEST_DAY_SPEEDS_MPS:
            profile.change_speed(target_mps, accel).hold(CRUISE_BEFORE_BRAKE_S).change_speed(0.0, decel).hold(
                TEST_DAY_STANDSTILL_S)
        return profile.forever()
    if scenario == "highway":
        profile = SpeedProfile(0.0).hold(STANDSTILL_S)
        for target_mps in HIGHWAY_SPEEDS_MPS:
            profile.change_speed(target_mps, HIGHWAY_ACCEL_MPS2).hold(HIGHWAY_CRUISE_S).change_speed(
                0.0, HIGHWAY_DECEL_MPS2).hold(TEST_DAY_STANDSTILL_S)
        return profile.forever()
    raise ValueError(f"unknown scenario {scenario!r}: expected accelerate, brake, cycle, test-day or highway")


@dataclass(frozen=True, slots=True)
class TruthWheel:
    slip: float
    omega_radps: float
    angle_rad: float
    """Cumulative wheel angle since time 0."""
    r0_m: float
    force_n: float
    cx_n: float
    """Initial slope Cx of the tire curve at this wheel's static load."""
    fz_n: float = 0.0
    """Normal load Fz on this wheel at this instant."""
    mu: float = 0.0
    """The tire's friction used at this instant: force_n / fz_n."""


@dataclass(frozen=True, slots=True)
class TruthSample:
    time_s: float
    speed_mps: float
    accel_mps2: float
    force_n: float
    """Total longitudinal force Fx = M*a."""
    distance_m: float
    wheels: dict[str, TruthWheel]
    brake_pressed: bool = False
    """The driver's brake is applied."""
    outbound: bool = True
    """On the outbound course (the settings' heading); False: the return course, opposite (coast-down)."""


def static_loads_n(mass_kg: float) -> dict[str, float]:
    """Fz per wheel: FRONT_LOAD_SHARE of M*g on the front axle, the rest on the rear, split evenly left/right."""
    weight_n = mass_kg * G_MPS2
    front, rear = FRONT_LOAD_SHARE * weight_n / 2.0, (1.0 - FRONT_LOAD_SHARE) * weight_n / 2.0
    return {w: front if w.startswith("F") else rear for w in WHEELS}


def force_shares(driven_axle: str, brake_front_share: float) -> tuple[dict[str, float], dict[str, float]]:
    """(drive share, brake share) of Fx per wheel: Fx >= 0 evenly over the driven wheels; Fx < 0 by axle share."""
    driven = [w for w in WHEELS if driven_axle == "all" or w.startswith(driven_axle[0].upper())]
    drive = {w: (1.0 / len(driven) if w in driven else 0.0) for w in WHEELS}
    brake = {w: (brake_front_share if w.startswith("F") else 1.0 - brake_front_share) / 2.0 for w in WHEELS}
    return drive, brake


class SteppedModel:
    """What the emitter needs of a vehicle model (emit.generate): advance_to(time) in equal substeps of at most
    max_step_s (a subclass's _substep integrates one), the wheel angles theta_i = (x + integral(V*s_i dt))/r0_i, and
    the truth at the current time (its _build_state)."""

    max_step_s: float
    _time_s: float
    _x_m: float
    _slip_distance_m: list[float]
    _r0: list[float]
    _state: TruthSample | None
    _v_mps: float
    _slips: list[float]
    cx_n: dict[str, float]
    brake_onset_s: float | None = None
    """The instant the driver's brake is pressed, where the model knows it (the slip-driven brake scenarios)."""

    def _setup(self, config: Config, road: Road, r0_offset_m: float | Mapping[str, float], max_step_s: float) -> None:
        """What every model starts with: the road's tire, the mass, each wheel's r0 (the tire's radius plus its
        offset), time, distance and integral(V*s_i dt) at 0."""
        if road not in ROADS:
            raise ValueError(f"unknown road {road!r}: expected paved or sand")
        self.road = road
        self.tire = ROADS[road]
        self.mass_kg = config.vehicle.mass_kg
        self.max_step_s = max_step_s
        offsets = r0_offset_m if isinstance(r0_offset_m, Mapping) else dict.fromkeys(WHEELS, r0_offset_m)
        self.r0_m = {w: config.tire.radius_m + float(offsets.get(w, 0.0)) for w in WHEELS}
        self._r0 = [self.r0_m[w] for w in WHEELS]
        self._time_s = 0.0
        self._x_m = 0.0
        self._slip_distance_m = [0.0] * len(WHEELS)
        """integral(V*s_i dt) per wheel."""
        self._state = None

    def _truth_wheels(self, forces_n: list[float], fz_n: list[float]) -> dict[str, TruthWheel]:
        """Each wheel's truth now: omega_i = V*(1 + s_i)/r0_i, its angle, force, load and mu = Fx_i/Fz_i (0 unloaded)."""
        v = self._v_mps
        return {
            w: TruthWheel(slip=s, omega_radps=v * (1.0 + s) / r0, angle_rad=angle, r0_m=r0, force_n=fx,
                          cx_n=self.cx_n[w], fz_n=fz, mu=fx / fz if fz > 0.0 else 0.0)
            for w, s, r0, angle, fx, fz in zip(WHEELS, self._slips, self._r0, self.angles_rad(), forces_n, fz_n)
        }

    def _substep(self, t1_s: float) -> None:
        raise NotImplementedError

    def _build_state(self) -> TruthSample:
        raise NotImplementedError

    def advance_to(self, time_s: float) -> None:
        """Advance the model to time_s (no-op if already there) in equal substeps of at most max_step_s."""
        span_s = time_s - self._time_s
        if span_s <= 0.0:
            return
        n = max(1, math.ceil(span_s / self.max_step_s - 1e-9))
        t0 = self._time_s
        for k in range(1, n):
            self._substep(t0 + span_s * k / n)
        self._substep(time_s)
        self._state = None

    def step(self, dt_s: float) -> TruthSample:
        """Advance by dt_s and return the truth at the new time."""
        self.advance_to(self._time_s + dt_s)
        return self.state

    @property
    def time_s(self) -> float:
        return self._time_s

    def angles_rad(self) -> list[float]:
        """Cumulative wheel angles in WHEELS order: theta_i = (x + integral(V*s_i dt))/r0_i."""
        x = self._x_m
        return [(x + d) / r0 for d, r0 in zip(self._slip_distance_m, self._r0)]

    @property
    def state(self) -> TruthSample:
        """The truth at the current time (built on demand)."""
        if self._state is None:
            self._state = self._build_state()
        return self._state


class VehicleSim(SteppedModel):
    """Deterministic vehicle model: step(dt_s) advances the profile and integrates the wheel angles.

    Each advance is split into equal substeps of at most max_step_s for the trapezoid integral of V*s.
    Truth: static loads Fz (no load transfer), mu = Fx_i/Fz_i, brake_pressed while Fx < 0.
    """

    def __init__(
        self,
        config: Config,
        scenario: Scenario = "cycle",
        road: Road = "paved",
        r0_offset_m: float | Mapping[str, float] = 0.0,
        max_step_s: float = 0.001,
        road_loads: RoadLoadTruth | None = None,
    ) -> None:
        """road_loads: the tires carry Fx = M*k*a + F_road(v) (road_loads.py); None: Fx = M*a."""
        self._setup(config, road, r0_offset_m, max_step_s)
        self.road_loads = road_loads
        self.scenario = scenario
        self.profile = speed_profile(scenario, road)
        self.fz_n = static_loads_n(self.mass_kg)
        self.cx_n = {w: self.tire.stiffness_n(self.fz_n[w]) for w in WHEELS}
        drive, brake = force_shares(config.vehicle.driven_axle, config.vehicle.brake_front_share)
        self._drive = [drive[w] for w in WHEELS]
        self._brake = [brake[w] for w in WHEELS]
        self._fz = [self.fz_n[w] for w in WHEELS]
        self._drive_cases = self._load_cases(self._drive, self._fz)
        self._brake_cases = self._load_cases(self._brake, self._fz)
        self._zero_slips = [0.0] * len(WHEELS)
        self._x_m, self._v_mps, self._a_mps2 = self.profile.at(0.0)
        self._slips = self._slips_for(self._tire_force_n(self._a_mps2, self._v_mps))

    def _tire_force_n(self, accel_mps2: float, speed_mps: float) -> float:
        """The tires' total force: M*a, or with road loads M*k*a + F_road(v)."""
        if self.road_loads is None:
            return self.mass_kg * accel_mps2
        return self.road_loads.tire_force_n(self.mass_kg, accel_mps2, speed_mps)

    @staticmethod
    def _load_cases(shares: list[float], fz_n: list[float]) -> tuple[list[tuple[float, float]], list[int]]:
        """Distinct (force share, Fz) pairs and, per wheel, the index of its pair (same pair -> same slip)."""
        cases = list(dict.fromkeys(zip(shares, fz_n)))
        return cases, [cases.index(case) for case in zip(shares, fz_n)]

    def _slips_for(self, fx_n: float) -> list[float]:
        """s_i = slip_for_force(Fx*share_i, Fz_i), computed once per distinct (share, Fz)."""
        if fx_n == 0.0:
            return self._zero_slips
        cases, index = self._drive_cases if fx_n > 0 else self._brake_cases
        slip = self.tire.slip_for_force
        values = [slip(fx_n * share, fz) for share, fz in cases]
        return [values[i] for i in index]

    def _substep(self, t1_s: float) -> None:
        """Advance to t1_s: exact x, V, a from the profile; trapezoid for integral(V*s dt)."""
        x, v, a = self.profile.at(t1_s)
        slips = self._slips_for(self._tire_force_n(a, v))
        half_h, v0 = 0.5 * (t1_s - self._time_s), self._v_mps
        self._slip_distance_m = [
            d + half_h * (v0 * s0 + v * s1) for d, s0, s1 in zip(self._slip_distance_m, self._slips, slips)
        ]
        self._time_s, self._x_m, self._v_mps, self._a_mps2, self._slips = t1_s, x, v, a, slips


    def _build_state(self) -> TruthSample:
        fx = self._tire_force_n(self._a_mps2, self._v_mps)
        shares = self._drive if fx >= 0 else self._brake
        v = self._v_mps
        wheels = self._truth_wheels([fx * k for k in shares], self._fz)
        return TruthSample(self._time_s, v, self._a_mps2, fx, self._x_m, wheels, brake_pressed=fx < 0.0)
