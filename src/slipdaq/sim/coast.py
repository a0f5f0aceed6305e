"""The coast-down scenario's driver (SAE J2263, WLTP GTR 15 annex 4): two coast-downs in opposite directions.

    cruise at COAST_FROM_MPS for COAST_CRUISE_S (outbound), coast (no drive, no brake: slips 0) down to COAST_END_MPS,
    turn (the return course), accelerate back to COAST_FROM_MPS, cruise, coast again, then brake to a stop.
The driver asks for an acceleration a_t (rate-limited to DRIVER_JERK_MPS3); the tires' force for it is
Fx = M*k*a_t + F_road(v) (road_loads.py), split over the driven wheels (or by the brake share), each wheel's slip from
the inverse tire curve at its load.
"""

from __future__ import annotations

from collections.abc import Sequence

from slipdaq import WHEELS
from slipdaq.config import VehicleConfig
from slipdaq.sim.dynamics import SlipCommand
from slipdaq.sim.road_loads import RoadLoadTruth
from slipdaq.sim.vehicle import TireModel

COAST_FROM_MPS = 110.0 / 3.6
COAST_END_MPS = 18.0 / 3.6
"""Each coast runs down to this speed (below the 20 km/h a coast maneuver needs)."""
COAST_CRUISE_S = 12.0
"""The cruise before each coast (the first one also lets the estimator settle)."""
RETURN_ACCEL_MPS2 = 2.0
STOP_DECEL_MPS2 = 3.0
SPEED_GAIN_PER_S = 0.8
"""Speed hold: a_t = gain*(target - V), capped at the stage's level."""
DRIVER_JERK_MPS3 = 4.0

STAGES = ("cruise", "coast", "accelerate", "cruise", "coast", "brake")


class CoastDown:
    """SlipController of the coast-down scenario (module docstring)."""

    def __init__(self, tire: TireModel, vehicle: VehicleConfig, road_loads: RoadLoadTruth) -> None:
        self.tire = tire
        self.loads = road_loads
        self.mass_kg = vehicle.mass_kg
        self.initial_speed_mps = COAST_FROM_MPS
        driven = vehicle.driven_axle
        self._driven = [i for i, w in enumerate(WHEELS) if driven == "all" or w.startswith(driven[0].upper())]
        self._brake_share = [(vehicle.brake_front_share if w.startswith("F") else 1.0 - vehicle.brake_front_share)
                             / 2.0 for w in WHEELS]
        self.stage = 0
        self._stage_start_s = 0.0
        self._time_s = 0.0
        self._accel_mps2 = 0.0
        """The driver's rate-limited acceleration demand at _time_s."""

    def _advance(self, time_s: float, speed_mps: float) -> None:
        """Move to the next stage when this one is done (on the speed at the step's start), and rate-limit a_t."""
        name = STAGES[self.stage] if self.stage < len(STAGES) else "brake"
        done = (name == "cruise" and time_s - self._stage_start_s >= COAST_CRUISE_S) \
            or (name == "coast" and speed_mps <= COAST_END_MPS) \
            or (name == "accelerate" and speed_mps >= COAST_FROM_MPS - 0.3)
        if done and self.stage < len(STAGES) - 1:
            self.stage += 1
            self._stage_start_s = time_s
            name = STAGES[self.stage]
        if name == "cruise":
            target = max(-0.5, min(0.5, SPEED_GAIN_PER_S * (COAST_FROM_MPS - speed_mps)))
        elif name == "accelerate":
            target = min(RETURN_ACCEL_MPS2, SPEED_GAIN_PER_S * (COAST_FROM_MPS - speed_mps) + 0.5)
        elif name == "brake":
            target = -STOP_DECEL_MPS2
        else:
            target = 0.0
        step = DRIVER_JERK_MPS3 * (time_s - self._time_s)
        self._accel_mps2 = max(self._accel_mps2 - step, min(self._accel_mps2 + step, target))
        self._time_s = time_s

    @property
    def outbound(self) -> bool:
        """The first cruise and coast are outbound; from the turn on, the return course."""
        return self.stage < 2

    def command(self, time_s: float, speed_mps: float, fz_n: Sequence[float]) -> SlipCommand:
        if time_s > self._time_s:
            self._advance(time_s, speed_mps)
        name = STAGES[self.stage]
        if name == "coast" or speed_mps <= 0.0:
            return SlipCommand([0.0] * len(WHEELS), name == "brake", self.outbound)
        fx_n = self.loads.tire_force_n(self.mass_kg, self._accel_mps2, speed_mps, self.outbound)
        slips = [0.0] * len(WHEELS)
        if fx_n >= 0.0 and name != "brake":
            for i in self._driven:
                slips[i] = self.tire.slip_for_force(fx_n / len(self._driven), fz_n[i])
            return SlipCommand(slips, False, self.outbound)
        for i in range(len(WHEELS)):
            slips[i] = self.tire.slip_for_force(min(0.0, fx_n) * self._brake_share[i], fz_n[i])
        return SlipCommand(slips, True, self.outbound)
