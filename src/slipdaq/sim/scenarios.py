"""The scenarios' drivers: per-wheel slip commands of the slip-driven scenarios, and the vehicle model per name.

brake-abs   cruise at BRAKE_TEST_SPEED_MPS, then ABS braking to standstill. The brake force splits front/rear by
            vehicle.brake_front_share; the limiting axle (the first to reach its tire's peak, with load transfer)
            has its slip cycled by ABS around the peak slip; the other axle carries its share of the total force.
brake-abs-all  the same cruise and ABS braking, every wheel's slip cycled by ABS around the peak, each wheel a quarter
            cycle after the one before (ABS controls each wheel): every tire carries mu(s)*Fz, whatever the hydraulic
            split.
brake-lock  the same cruise, then every wheel's slip ramps through the peak to -1 (locked) until standstill.
launch-spin from standstill the driven wheels spin far past the peak, then traction control holds a few percent of
            slip up to LAUNCH_SPEED_MPS, then cruise.
coast-down  two coast-downs (coast.py) in opposite directions, with road loads (COAST_DOWN_CAR unless given).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Literal, get_args

from slipdaq import WHEELS
from slipdaq.config import Config, VehicleConfig
from slipdaq.sim import ProfileScenario, Scenario, SlipScenario
from slipdaq.sim.coast import CoastDown
from slipdaq.sim.dynamics import DynamicVehicleSim, SlipCommand, SlipController
from slipdaq.sim.road_loads import COAST_DOWN_CAR, RoadLoadTruth
from slipdaq.sim.vehicle import CRUISE_BEFORE_BRAKE_S, ROADS, STANDSTILL_S, Road, SteppedModel, TireModel, VehicleSim

BRAKE_TEST_SPEED_MPS = 80.0 / 3.6
"""Cruise speed before the brake-abs and brake-lock stops (80 km/h)."""
LAUNCH_SPEED_MPS = 60.0 / 3.6
"""Speed launch-spin accelerates to and cruises at (60 km/h)."""

BRAKE_ONSET_S = 0.2
"""brake-abs: the limiting axle's slip grows from 0 to the ABS cycle's low end in this time."""
ABS_RATE_HZ = 7.0
"""ABS cycles per second."""
ABS_SLIP_LOW, ABS_SLIP_HIGH = 0.5, 1.6
"""The ABS cycle's slip range, in units of the tire's peak slip."""
ABS_RISE_SHARE = 0.75
"""Share of an ABS cycle with the pressure (and |slip|) rising; in the rest it is released (a sawtooth)."""
ABS_MIN_SPEED_MPS = 2.0
"""Below this speed ABS stops cycling and the wheels lock (ramp to s = -1 in ABS_LOCK_RAMP_S)."""
ABS_LOCK_RAMP_S = 0.1
LOCK_ONSET_S = 0.4
"""brake-lock: time for every wheel's slip to ramp from 0 to -1."""
SPIN_SLIP = 0.35
"""launch-spin: the driven wheels' slip while they spin (well past the peak on either road)."""
SPIN_RAMP_S = 0.3
SPIN_S = 3.0
"""launch-spin: how long the wheels spin at SPIN_SLIP."""
TRACTION_SLIP = 0.05
"""launch-spin: the slip traction control holds once it catches the spin."""
TRACTION_BLEND_S = 0.5
"""launch-spin: time for the slip to fall from SPIN_SLIP to the traction control's."""
TRACTION_GAIN_PER_MPS = 0.025
"""launch-spin: s = min(TRACTION_SLIP, gain*(LAUNCH_SPEED_MPS - V)), so the speed settles at LAUNCH_SPEED_MPS."""

Axle = Literal["front", "rear"]


def _axle_index(axle: str) -> list[int]:
    return [i for i, w in enumerate(WHEELS) if axle == "all" or w.startswith(axle[0].upper())]


def limiting_axle(mu: float, vehicle: VehicleConfig) -> Axle:
    """The axle whose tires reach their peak force first as braking grows (deceleration z in g):
    front: b_f*z = mu*(k_f + z*h/L) -> z_f = mu*k_f/(b_f - mu*h/L) (never when b_f <= mu*h/L);
    rear:  b_r*z = mu*(k_r - z*h/L) -> z_r = mu*k_r/(b_r + mu*h/L); an axle without brake force never limits."""
    transfer = mu * vehicle.cg_height_m / vehicle.wheelbase_m
    b_front, b_rear = vehicle.brake_front_share, 1.0 - vehicle.brake_front_share
    k_front = vehicle.front_axle_load_share
    z_front = mu * k_front / (b_front - transfer) if b_front > 0.0 and b_front > transfer else math.inf
    z_rear = mu * (1.0 - k_front) / (b_rear + transfer) if b_rear > 0.0 else math.inf
    return "front" if z_front <= z_rear else "rear"


def abs_cycle(phase: float) -> float:
    """|slip| in units of the peak slip over one ABS cycle (phase in [0, 1)): a sawtooth rising from ABS_SLIP_LOW to
    ABS_SLIP_HIGH over ABS_RISE_SHARE of the cycle (pressure build), falling back in the rest (release)."""
    span = ABS_SLIP_HIGH - ABS_SLIP_LOW
    if phase < ABS_RISE_SHARE:
        return ABS_SLIP_LOW + span * phase / ABS_RISE_SHARE
    return ABS_SLIP_HIGH - span * (phase - ABS_RISE_SHARE) / (1.0 - ABS_RISE_SHARE)


class AbsBraking:
    """brake-abs: cruise CRUISE_BEFORE_BRAKE_S (or onset_s) at BRAKE_TEST_SPEED_MPS (or speed_mps), then ABS braking
    (SlipController). The brake is pressed from onset_s on (slip 0 at that instant, then the onset ramp)."""

    def __init__(self, tire: TireModel, vehicle: VehicleConfig, speed_mps: float | None = None,
                 onset_s: float | None = None) -> None:
        self.tire = tire
        self.initial_speed_mps = BRAKE_TEST_SPEED_MPS if speed_mps is None else speed_mps
        self.onset_s = CRUISE_BEFORE_BRAKE_S if onset_s is None else onset_s
        self.limiting_axle = limiting_axle(tire.mu, vehicle)
        other_axle = "rear" if self.limiting_axle == "front" else "front"
        self._limiting = _axle_index(self.limiting_axle)
        self._other = _axle_index(other_axle)
        front_share = vehicle.brake_front_share
        limiting_share = front_share if self.limiting_axle == "front" else 1.0 - front_share
        self._other_per_limiting = (1.0 - limiting_share) / limiting_share
        """Force on the other axle per unit of force on the limiting axle: b_other/b_limiting."""
        self._last = [0.0] * len(WHEELS)
        self._cutout: tuple[float, list[float]] | None = None
        """(time, slips) when ABS stopped cycling (speed below ABS_MIN_SPEED_MPS)."""

    def limiting_slip(self, time_s: float) -> float:
        """The limiting axle's slip: onset ramp to -ABS_SLIP_LOW*peak in BRAKE_ONSET_S, then the ABS cycle."""
        tau = time_s - self.onset_s
        if tau <= 0.0:
            return 0.0
        if tau < BRAKE_ONSET_S:
            return -ABS_SLIP_LOW * self.tire.peak_slip * tau / BRAKE_ONSET_S
        phase = ((tau - BRAKE_ONSET_S) * ABS_RATE_HZ) % 1.0
        return -abs_cycle(phase) * self.tire.peak_slip

    def _before_or_locked(self, time_s: float, speed_mps: float) -> SlipCommand | None:
        """Before the onset: no brake; below ABS_MIN_SPEED_MPS (from then on): every wheel ramps from its last slip
        to lock in ABS_LOCK_RAMP_S; else None (ABS at work)."""
        if time_s < self.onset_s:
            return SlipCommand([0.0] * len(WHEELS), False)
        if self._cutout is None and speed_mps < ABS_MIN_SPEED_MPS:
            self._cutout = (time_s, list(self._last))
        if self._cutout is not None:
            start_s, slips = self._cutout
            k = min(1.0, (time_s - start_s) / ABS_LOCK_RAMP_S)
            return SlipCommand([s + (-1.0 - s) * k for s in slips], True)
        return None

    def command(self, time_s: float, speed_mps: float, fz_n: Sequence[float]) -> SlipCommand:
        """Limiting axle: limiting_slip(t); other axle: Fx = Fx_limiting*b_other/b_limiting split evenly, its slip from
        the inverse tire curve (stable branch). Below ABS_MIN_SPEED_MPS every wheel ramps to lock."""
        held = self._before_or_locked(time_s, speed_mps)
        if held is not None:
            return held
        slips = [0.0] * len(WHEELS)
        s_limiting = self.limiting_slip(time_s)
        limiting_n = 0.0
        for i in self._limiting:
            slips[i] = s_limiting
            limiting_n += self.tire.force_n(s_limiting, fz_n[i])
        wheel_n = limiting_n * self._other_per_limiting / len(self._other)
        for i in self._other:
            slips[i] = self.tire.slip_for_force(wheel_n, fz_n[i])
        self._last = slips
        return SlipCommand(slips, True)


class AbsBrakingAll(AbsBraking):
    """brake-abs-all: as AbsBraking, but every wheel's slip cycles around the peak, wheel k a quarter cycle after
    wheel k - 1 (the onset ramp the same for all)."""

    def command(self, time_s: float, speed_mps: float, fz_n: Sequence[float]) -> SlipCommand:
        held = self._before_or_locked(time_s, speed_mps)
        if held is not None:
            return held
        tau = time_s - self.onset_s
        if tau < BRAKE_ONSET_S:
            slips = [-ABS_SLIP_LOW * self.tire.peak_slip * tau / BRAKE_ONSET_S] * len(WHEELS)
        else:
            phase = (tau - BRAKE_ONSET_S) * ABS_RATE_HZ
            slips = [-abs_cycle((phase + i / len(WHEELS)) % 1.0) * self.tire.peak_slip for i in range(len(WHEELS))]
        self._last = slips
        return SlipCommand(slips, True)


class LockedBraking:
    """brake-lock: cruise CRUISE_BEFORE_BRAKE_S, then every wheel's slip ramps 0 -> -1 in LOCK_ONSET_S and stays
    locked (SlipController)."""

    def __init__(self, speed_mps: float | None = None, onset_s: float | None = None) -> None:
        self.initial_speed_mps = BRAKE_TEST_SPEED_MPS if speed_mps is None else speed_mps
        self.onset_s = CRUISE_BEFORE_BRAKE_S if onset_s is None else onset_s

    def command(self, time_s: float, speed_mps: float, fz_n: Sequence[float]) -> SlipCommand:
        tau = time_s - self.onset_s
        if tau < 0.0:
            return SlipCommand([0.0] * len(WHEELS), False)
        return SlipCommand([-min(1.0, tau / LOCK_ONSET_S)] * len(WHEELS), True)


class LaunchSpin:
    """launch-spin: STANDSTILL_S at rest, the driven wheels' slip ramps to SPIN_SLIP (SPIN_RAMP_S) and stays SPIN_S,
    then blends (TRACTION_BLEND_S) into traction control s = min(TRACTION_SLIP, gain*(LAUNCH_SPEED_MPS - V)); the
    other wheels roll free (SlipController)."""

    def __init__(self, vehicle: VehicleConfig) -> None:
        self.initial_speed_mps = 0.0
        self.start_s = STANDSTILL_S
        self._driven = _axle_index(vehicle.driven_axle)

    def driven_slip(self, time_s: float, speed_mps: float) -> float:
        tau = time_s - self.start_s
        if tau <= 0.0:
            return 0.0
        if tau < SPIN_RAMP_S:
            return SPIN_SLIP * tau / SPIN_RAMP_S
        tau -= SPIN_RAMP_S + SPIN_S
        if tau < 0.0:
            return SPIN_SLIP
        traction = min(TRACTION_SLIP, max(0.0, TRACTION_GAIN_PER_MPS * (LAUNCH_SPEED_MPS - speed_mps)))
        return traction + (SPIN_SLIP - traction) * max(0.0, 1.0 - tau / TRACTION_BLEND_S)

    def command(self, time_s: float, speed_mps: float, fz_n: Sequence[float]) -> SlipCommand:
        slips = [0.0] * len(WHEELS)
        s = self.driven_slip(time_s, speed_mps)
        for i in self._driven:
            slips[i] = s
        return SlipCommand(slips, False)


def slip_controller(scenario: SlipScenario, tire: TireModel, vehicle: VehicleConfig,
                    brake_speed_mps: float | None = None, brake_onset_s: float | None = None,
                    road_loads: RoadLoadTruth | None = None) -> SlipController:
    """The controller of a slip-driven scenario; the brake scenarios' cruise speed and onset time (None: their
    defaults, BRAKE_TEST_SPEED_MPS and CRUISE_BEFORE_BRAKE_S); coast-down: its driver knows the car's road loads."""
    if scenario == "brake-abs":
        return AbsBraking(tire, vehicle, brake_speed_mps, brake_onset_s)
    if scenario == "brake-abs-all":
        return AbsBrakingAll(tire, vehicle, brake_speed_mps, brake_onset_s)
    if scenario == "brake-lock":
        return LockedBraking(brake_speed_mps, brake_onset_s)
    if scenario == "launch-spin":
        return LaunchSpin(vehicle)
    if scenario == "coast-down":
        return CoastDown(tire, vehicle, road_loads or COAST_DOWN_CAR)
    raise ValueError(f"unknown slip scenario {scenario!r}: expected one of {', '.join(get_args(SlipScenario))}")


def vehicle_model(
    config: Config, scenario: Scenario, road: Road, r0_offset_m: float | Mapping[str, float] = 0.0,
    max_step_s: float = 0.001, brake_speed_mps: float | None = None, brake_onset_s: float | None = None,
    road_loads: RoadLoadTruth | None = None,
) -> SteppedModel:
    """The kinematic model for a profile scenario (accelerate, brake, cycle), the slip-driven one otherwise (the brake
    scenarios' cruise speed and onset: slip_controller); road_loads: the car's road loads and rotating masses (none
    unless given; coast-down: COAST_DOWN_CAR unless given)."""
    if scenario in get_args(ProfileScenario):
        return VehicleSim(config, scenario, road, r0_offset_m, max_step_s=max_step_s,  # type: ignore[arg-type]  # checked just above
                          road_loads=road_loads)
    if scenario not in get_args(SlipScenario):
        raise ValueError(f"unknown scenario {scenario!r}")
    if road not in ROADS:
        raise ValueError(f"unknown road {road!r}: expected paved or sand")
    if scenario == "coast-down" and road_loads is None:
        road_loads = COAST_DOWN_CAR
    controller = slip_controller(scenario, ROADS[road], config.vehicle,  # type: ignore[arg-type]  # checked above
                                 brake_speed_mps, brake_onset_s, road_loads)
    return DynamicVehicleSim(config, controller, road, r0_offset_m, max_step_s, road_loads)
