"""The simulated car's road loads and rotating masses (truth; none by default, so that a model without them is the
plain Fx = M*a one):

    F_road(v) = F0 + F1*v + F2*v_air*|v_air|,  v_air = v - w*d     (w: the wind along the road, d = +1 on the
                                                                    outbound course, -1 on the return one)
    Fx_tires = M*k*a + F_road(v)                                    (k: the wheels' and driveline's equivalent mass
                                                                    per unit of M, SAE J2263)
so that a coast (no drive, no brake: Fx_tires = 0) decelerates at a = -F_road(v)/(M*k).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class RoadLoadTruth:
    f0_n: float = 0.0
    f1_n_per_mps: float = 0.0
    f2_n_per_mps2: float = 0.0
    """Air drag rho/2*Cd*A, on the speed relative to the air."""
    rotating_mass_factor: float = 1.0
    wind_mps: float = 0.0
    """The wind along the road, blowing the way the outbound runs go (a tailwind on them, a headwind back)."""

    def force_n(self, speed_mps: float, outbound: bool = True) -> float:
        """F_road(v) on the outbound (or return) course."""
        v_air = speed_mps - (self.wind_mps if outbound else -self.wind_mps)
        return self.f0_n + self.f1_n_per_mps * speed_mps + self.f2_n_per_mps2 * v_air * abs(v_air)

    def tire_force_n(self, mass_kg: float, accel_mps2: float, speed_mps: float, outbound: bool = True) -> float:
        """Fx_tires = M*k*a + F_road(v) (no road load at a standstill)."""
        road = self.force_n(speed_mps, outbound) if speed_mps > 0.0 else 0.0
        return mass_kg * self.rotating_mass_factor * accel_mps2 + road


COAST_DOWN_CAR = RoadLoadTruth(f0_n=150.0, f2_n_per_mps2=0.40, rotating_mass_factor=1.04, wind_mps=3.0)
"""The coast-down scenario's car when none is given: the SAE J2263-sized loads of a compact car, a 3 m/s wind."""
