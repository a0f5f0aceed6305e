"""Slip-driven vehicle model: each wheel's slip is commanded (by a scenario's controller), the tire gives the force.
Pure: no I/O, no clock. Longitudinal dynamics only, per step of at most max_step_s:

    Fz_front_axle = M*g*k_f - M*a*h/L,  Fz_rear_axle = M*g - Fz_front_axle,  split evenly left/right
        (k_f = vehicle.front_axle_load_share, h = vehicle.cg_height_m, L = vehicle.wheelbase_m; braking, a < 0,
        loads the front)
    Fx_i = D*sin(C*atan(B*s_i)),  D = mu*Fz_i                  (the road's TireModel)
    a = sum(Fx_i)/M = g(a)                                     (Fz depends on a: fixed point, see _solve)
    with road loads (road_loads.py): a = (sum(Fx_i) - F_road(v))/(M*k)
    V1 = V0 + h*(a0 + a1)/2,  x1 = x0 + h*(V0 + V1)/2           (trapezoid)
    theta_i = (x + integral(V*s_i dt))/r0_i,  omega_i = V*(1 + s_i)/r0_i   (a locked wheel, s = -1, has omega = 0)

A moving vehicle whose speed reaches 0 stays stopped: slip 0, force 0, a = 0 (within the step it stops in, the
integrals run to the instant V = 0, by linear interpolation of V).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import NamedTuple, Protocol

from slipdaq import WHEELS
from slipdaq.config import Config, VehicleConfig
from slipdaq.sim.road_loads import RoadLoadTruth
from slipdaq.sim.vehicle import G_MPS2, Road, SteppedModel, TruthSample

AITKEN_MIN_DENOMINATOR = 1e-12
"""Below this |a2 - 2*a1 + a0| the fixed point is taken as reached (no extrapolation)."""


class SlipCommand(NamedTuple):
    slips: list[float]
    """Commanded slip per wheel, in WHEELS order."""
    brake_pressed: bool
    """The driver's brake is applied."""
    outbound: bool = True
    """On the outbound course (False: the return one, opposite)."""


class SlipController(Protocol):
    """A scenario's driver and wheel-slip control: the slip of each wheel at an instant."""

    @property
    def initial_speed_mps(self) -> float: ...

    def command(self, time_s: float, speed_mps: float, fz_n: Sequence[float]) -> SlipCommand:
        """The slips at time_s, given the speed at the step's start and the wheels' loads (WHEELS order)."""
        ...


def axle_loads_n(vehicle: VehicleConfig, accel_mps2: float) -> list[float]:
    """Fz per wheel (WHEELS order): Fz_front_axle = M*g*k_f - M*a*h/L, the rest on the rear, halves left/right."""
    mass_kg = vehicle.mass_kg
    weight_n = mass_kg * G_MPS2
    front_axle_n = weight_n * vehicle.front_axle_load_share - mass_kg * accel_mps2 * vehicle.cg_height_m / vehicle.wheelbase_m
    front_axle_n = min(weight_n, max(0.0, front_axle_n))
    front_n, rear_n = front_axle_n / 2.0, (weight_n - front_axle_n) / 2.0
    return [front_n if w.startswith("F") else rear_n for w in WHEELS]


class DynamicVehicleSim(SteppedModel):
    """The slip-driven model with VehicleSim's interface (advance_to, step, state, angles_rad, time_s)."""

    def __init__(
        self,
        config: Config,
        controller: SlipController,
        road: Road = "paved",
        r0_offset_m: float | Mapping[str, float] = 0.0,
        max_step_s: float = 0.001,
        road_loads: RoadLoadTruth | None = None,
    ) -> None:
        """road_loads: the car's road loads and rotating masses (None: a = sum(Fx_i)/M)."""
        self._setup(config, road, r0_offset_m, max_step_s)
        self.road_loads = road_loads
        self.controller = controller
        self.brake_onset_s: float | None = getattr(controller, "onset_s", None)
        self.vehicle = config.vehicle
        self._static_fz = axle_loads_n(self.vehicle, 0.0)
        self.cx_n = {w: self.tire.stiffness_n(fz) for w, fz in zip(WHEELS, self._static_fz)}
        """Initial slope Cx of each wheel's tire curve at its static load."""
        self._v_mps = controller.initial_speed_mps
        self._a_mps2 = 0.0  # _solve's first guess
        self._stopped = False
        self._outbound = True
        self._a_mps2, self._fz, self._slips, self._forces, self._brake = self._solve(0.0, self._v_mps)

    def _pass(self, time_s: float, speed_mps: float, accel_mps2: float) -> tuple[float, list[float], SlipCommand,
                                                                                list[float]]:
        """One pass of a = g(a): Fz(a) -> commanded s_i -> Fx_i(s_i, Fz_i) -> sum(Fx_i)/M."""
        fz = axle_loads_n(self.vehicle, accel_mps2)
        command = self.controller.command(time_s, speed_mps, fz)
        force = self.tire.force_n
        forces = [force(s, f) for s, f in zip(command.slips, fz)]
        if self.road_loads is not None:
            return self._road_loaded_accel(forces, speed_mps, command.outbound), fz, command, forces
        return math.fsum(forces) / self.mass_kg, fz, command, forces

    def _road_loaded_accel(self, forces: list[float], speed_mps: float, outbound: bool) -> float:
        """a = (sum(Fx_i) - F_road(v))/(M*k)."""
        loads = self.road_loads
        assert loads is not None
        road_n = loads.force_n(speed_mps, outbound) if speed_mps > 0.0 else 0.0
        return (math.fsum(forces) - road_n) / (self.mass_kg * loads.rotating_mass_factor)

    def _solve(self, time_s: float, speed_mps: float) -> tuple[float, list[float], list[float], list[float], bool]:
        accel, fz, slips, forces, command = self._solve_command(time_s, speed_mps)
        self._outbound = command.outbound
        return accel, fz, slips, forces, command.brake_pressed

    def _solve_command(self, time_s: float, speed_mps: float) -> tuple[float, list[float], list[float], list[float],
                                                                      SlipCommand]:
        """(a, Fz_i, s_i, Fx_i, brake) at time_s. From the last step's a0: a1 = g(a0), a2 = g(a1), Aitken's
        a* = a0 - (a1 - a0)^2/(a2 - 2*a1 + a0) (exact when g is affine, as with slips fixed in time and the other axle
        carrying a share of the limiting axle's force), then a final pass at a*. Stopped: s_i = 0, Fx_i = 0, a = 0."""
        if self._stopped:
            fz = self._static_fz
            zeros = [0.0] * len(WHEELS)
            return 0.0, fz, zeros, zeros, self.controller.command(time_s, 0.0, fz)
        a0 = self._a_mps2
        a1 = self._pass(time_s, speed_mps, a0)[0]
        a2 = self._pass(time_s, speed_mps, a1)[0]
        denominator = a2 - 2.0 * a1 + a0
        a_star = a0 - (a1 - a0) ** 2 / denominator if abs(denominator) > AITKEN_MIN_DENOMINATOR else a2
        accel, fz, command, forces = self._pass(time_s, speed_mps, a_star if math.isfinite(a_star) else a2)
        return accel, fz, command.slips, forces, command

    def _substep(self, t1_s: float) -> None:
        """Advance to t1_s: trapezoid for V, x and integral(V*s dt); a stop within the step ends the motion."""
        h = t1_s - self._time_s
        v0, a0, s0 = self._v_mps, self._a_mps2, self._slips
        accel, fz, slips, forces, brake = self._solve(t1_s, v0)
        v1 = 0.0 if self._stopped else v0 + 0.5 * h * (a0 + accel)
        moving_h = h
        if not self._stopped and v1 <= 0.0 and (v0 > 0.0 or accel < 0.0):
            moving_h = h * v0 / (v0 - v1) if v0 > 0.0 else 0.0  # V reaches 0 at this share of the step
            v1, self._stopped = 0.0, True
            accel, fz, slips, forces, brake = self._solve(t1_s, 0.0)
        half_h = 0.5 * moving_h
        self._x_m += half_h * (v0 + v1)
        self._slip_distance_m = [d + half_h * (v0 * a + v1 * b) for d, a, b in zip(self._slip_distance_m, s0, slips)]
        self._time_s, self._v_mps, self._a_mps2 = t1_s, v1, accel
        self._fz, self._slips, self._forces, self._brake = fz, slips, forces, brake

    @property
    def stopped(self) -> bool:
        """The vehicle has come to a standstill (and stays there)."""
        return self._stopped

    def _build_state(self) -> TruthSample:
        wheels = self._truth_wheels(self._forces, self._fz)
        total_n = math.fsum(self._forces)
        return TruthSample(self._time_s, self._v_mps, self._a_mps2, total_n, self._x_m, wheels,
                           brake_pressed=self._brake, outbound=self._outbound)
