"""The simulator's road loads, wind and rotating masses: none by default (the truth as before), the tires' force
M*k*a + F_road(v) with them, and the coast-down scenario's coasts decelerating at -F_road(v)/(M*k)."""

from __future__ import annotations

import pytest

from slipdaq.config import Config
from slipdaq.sim.road_loads import COAST_DOWN_CAR, RoadLoadTruth
from slipdaq.sim.scenarios import vehicle_model


def test_no_road_loads_by_default_and_the_same_truth(cfg: Config) -> None:
    plain = vehicle_model(cfg, "cycle", "paved")
    neutral = vehicle_model(cfg, "cycle", "paved", road_loads=RoadLoadTruth())
    for _ in range(150):
        a, b = plain.step(0.1), neutral.step(0.1)
        assert a == b  # F_road 0 and k 1: the same slips, forces and angles, exactly


def test_tires_carry_the_equivalent_mass_and_the_road_loads(cfg: Config) -> None:
    car = RoadLoadTruth(f0_n=150.0, f1_n_per_mps=1.0, f2_n_per_mps2=0.4, rotating_mass_factor=1.04, wind_mps=3.0)
    sim = vehicle_model(cfg, "highway", "paved", road_loads=car)
    seen = 0
    for _ in range(600):
        s = sim.step(0.1)
        if s.speed_mps > 1.0:
            v_air = s.speed_mps - 3.0  # the tailwind: below 3 m/s the air pushes the car
            expected = cfg.vehicle.mass_kg * 1.04 * s.accel_mps2 + 150.0 + s.speed_mps + 0.4 * v_air * abs(v_air)
            assert s.force_n == pytest.approx(expected, rel=1e-12, abs=1e-9)
            seen += 1
    assert seen > 300
    assert car.force_n(20.0, outbound=False) == pytest.approx(150.0 + 20.0 + 0.4 * 23.0**2)  # the headwind back


def test_coast_down_scenario_coasts_on_its_road_loads(cfg: Config) -> None:
    sim = vehicle_model(cfg, "coast-down", "paved")
    mass_eq = cfg.vehicle.mass_kg * COAST_DOWN_CAR.rotating_mass_factor
    courses, coasting = set(), 0
    for _ in range(3200):
        s = sim.step(0.1)
        courses.add(s.outbound)
        if sim.controller.stage in (1, 4) and s.speed_mps > 6.0:  # type: ignore[attr-defined]
            assert not s.brake_pressed and s.force_n == 0.0 and all(w.slip == 0.0 for w in s.wheels.values())
            expected = -COAST_DOWN_CAR.force_n(s.speed_mps, s.outbound) / mass_eq
            assert s.accel_mps2 == pytest.approx(expected, rel=1e-4)  # a at the last step's start speed
            coasting += 1
        if sim.stopped:  # type: ignore[attr-defined]
            break
    assert courses == {True, False} and coasting > 2000 and sim.stopped  # type: ignore[attr-defined]
