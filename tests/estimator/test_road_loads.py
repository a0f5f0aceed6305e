"""Road loads and rotating masses: the coast-down fit (paired directions cancel wind and grade), the force with both,
the calibration's [road_loads] (round trip, used by Fx, the config's coefficients winning over them)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from test_estimator import _run

from slipdaq.config import Config, parse_config
from slipdaq.config import TestConfig as Day
from slipdaq.config.calibration import Calibration, Learned, merged, parse_calibration, show, summary, to_toml
from slipdaq.estimator import EstimatorParams
from slipdaq.estimator.force import RoadLoads, longitudinal_force_n
from slipdaq.estimator.run_calibration import stored_road_loads
from slipdaq.maneuver.coast import CoastDetector, CoastRun
from slipdaq.maneuver.record import MANEUVER_COLUMNS, coast_record
from slipdaq.maneuver.test_set import TestSets as Sets
from slipdaq.sim.road_loads import RoadLoadTruth
from slipdaq.sinks.maneuver_text import maneuver_line
from support.estimator_params import params

MASS_KG, FACTOR = 1300.0, 1.04
CAR = RoadLoadTruth(f0_n=150.0, f2_n_per_mps2=0.40, rotating_mass_factor=FACTOR, wind_mps=3.0)
SIN_GRADE = 0.005
"""The outbound runs climb 0.5 % (M*g*sin = 64 N, 43 % of F0), the return runs descend it."""


def coast_rows(outbound: bool, t0_s: float, rng: np.random.Generator, noise_mps: float = 0.03
               ) -> tuple[list[dict[str, float]], list[tuple[float, float]]]:
    """Estimate rows (10 Hz) and courses of a cruise at 110 km/h, then a coast to 18 km/h: dV/dt = -(F_road(v) +-
    M*g*sin)/(M*k) by RK4 at 10 ms."""
    v, t, dt = 110.0 / 3.6, 0.0, 0.01
    grade_n = MASS_KG * 9.81 * SIN_GRADE * (1.0 if outbound else -1.0)

    def accel(speed: float) -> float:
        return -(CAR.force_n(speed, outbound) + grade_n) / (MASS_KG * FACTOR)

    rows: list[dict[str, float]] = []
    courses: list[tuple[float, float]] = []
    course = 90.0 if outbound else 270.0
    k = 0
    while v > 18.0 / 3.6:
        if k % 10 == 0:
            rows.append({"time_s": t0_s + t, "speed_mps": v + float(rng.normal(0.0, noise_mps))})
            courses.append((t0_s + t, course))
        if t >= 5.0:  # 5 s of cruise, then the coast
            k1 = accel(v)
            k2 = accel(v + 0.5 * dt * k1)
            k3 = accel(v + 0.5 * dt * k2)
            k4 = accel(v + dt * k3)
            v += dt * (k1 + 2 * k2 + 2 * k3 + k4) / 6.0
        t += dt
        k += 1
    return rows, courses


def feed(det: CoastDetector, rows: list[dict[str, float]], courses: list[tuple[float, float]]) -> list[CoastRun]:
    out = []
    for row, (tc, course) in zip(rows, courses):
        det.add_course(tc, course)
        run = det.add_estimate(row)
        if run is not None:
            out.append(run)
    return out


@pytest.fixture(scope="module")
def config() -> Config:
    return Config().with_overrides(vehicle={"mass_kg": MASS_KG, "rotating_mass_factor": FACTOR})


def test_coast_down_paired_directions_cancel_wind_and_grade(config: Config) -> None:
    rng = np.random.default_rng(3)
    det = CoastDetector(config)
    out_rows, out_courses = coast_rows(True, 0.0, rng)
    back_rows, back_courses = coast_rows(False, out_rows[-1]["time_s"] + 60.0, rng)
    first = feed(det, out_rows, out_courses)
    second = feed(det, back_rows, back_courses)
    assert len(first) == 1 and len(second) == 1
    alone, paired = first[0], second[0]
    # the outbound run alone: its F0 carries the grade's +64 N, its F1 the tailwind's -2*F2*w = -2.4 N/(m/s)
    assert alone.runs_paired == 0 and alone.reasons and "opposite direction" in alone.reasons[0]
    assert alone.loads[0] - 150.0 > 40.0
    assert alone.loads[1] == pytest.approx(-2.4, abs=0.8)
    # the pair: wind and grade cancel (F0 keeps F2*w^2 = 3.6 N)
    assert paired.runs_paired == 2 and not paired.reasons
    assert paired.loads[0] == pytest.approx(153.6, rel=0.03)
    assert paired.loads[1] == pytest.approx(0.0, abs=0.5)
    assert paired.loads[2] == pytest.approx(0.40, rel=0.03)
    assert paired.loads_lo[2] < paired.loads[2] < paired.loads_hi[2]
    assert paired.speed_from_kmh >= 100.0 and 20.0 <= paired.speed_to_kmh < 21.0
    record = coast_record(paired, 7, 0.0, ("FL", "FR", "RL", "RR")).as_row()
    assert record["kind"] == "coast" and record["valid"] is True and record["coast_runs_paired"] == 2
    assert record["road_load_f2_n_per_mps2"] == paired.loads[2]
    line = maneuver_line(coast_record(paired, 7, 0.0, ("FL", "FR", "RL", "RR")))
    assert line.startswith("maneuver #7 coast") and "runs paired" in line and "F0 15" in line and line.endswith("valid")
    names = {c.name for g in MANEUVER_COLUMNS for c in g.columns}
    assert {"road_load_f0_n_lo", "road_load_f1_n_per_mps_hi", "road_load_f2_n_per_mps2", "coast_runs_paired"} <= names


def test_coast_down_same_direction_not_paired(config: Config) -> None:
    rng = np.random.default_rng(4)
    det = CoastDetector(config)
    rows1, courses1 = coast_rows(True, 0.0, rng)
    rows2, courses2 = coast_rows(True, rows1[-1]["time_s"] + 60.0, rng)
    runs = feed(det, rows1, courses1) + feed(det, rows2, courses2)
    assert [r.runs_paired for r in runs] == [0, 0]
    assert all(r.loads[0] - 150.0 > 40.0 for r in runs)  # both climb: the grade stays in F0


def test_no_coast_when_braked_or_too_slow(config: Config) -> None:
    rng = np.random.default_rng(5)
    det = CoastDetector(config)
    rows, courses = coast_rows(True, 0.0, rng)
    mid = rows[len(rows) // 2]["time_s"]
    out = []
    for row, (tc, course) in zip(rows, courses):
        if abs(row["time_s"] - mid) < 0.05:
            det.add_brake(row["time_s"], 1.0)  # a touch of the brake half way down
        det.add_course(tc, course)
        out.append(det.add_estimate(row))
    assert not any(out)
    slow = Config().with_overrides(test={"coast_from_kmh": 120.0})
    det = CoastDetector(slow)
    assert not any(det.add_estimate(r) for r in rows)  # the coast starts below coast_from_kmh


def test_force_with_rotating_masses_and_road_loads() -> None:
    # braking at 0.5 m/s^2 at 20 m/s: 1300 * 1.04 * -0.5 + 150 + 2 * 20 + 0.4 * 400 = -676 + 150 + 40 + 160
    loads = RoadLoads(150.0, 2.0, 0.40)
    assert longitudinal_force_n(1300.0, -0.5, 20.0, 0.0, 0.012, 0.7, 1.2, 1.04, loads) == pytest.approx(-326.0)
    # the config's coefficients: 1300 * 1.03 * 1 + 0.01 * 1300 * 9.81 + 0.6 * 0.6 * 100
    assert longitudinal_force_n(1300.0, 1.0, 10.0, 0.0, 0.01, 0.6, 1.2, 1.03) == pytest.approx(1339.0 + 127.53 + 36.0)
    # factor 1 and no road loads: M*a, exactly
    assert longitudinal_force_n(1300.0, 2.0, 30.0, 0.0, 0.0, 0.0, 1.2) == 2600.0
    # a coast: the tires carry nothing when a = -F_road/(M*k)
    a = -loads.force_n(25.0) / (1300.0 * 1.04)
    assert longitudinal_force_n(1300.0, a, 25.0, 0.0, 0.0, 0.0, 1.2, 1.04, loads) == pytest.approx(0.0, abs=1e-9)


def _stored(config: Config) -> Calibration:
    return merged(None, Learned(road_loads=(152.0, -0.3, 0.41, 2)), config, "coast.mcap", "2026-11-28T03:00:00Z")


def test_calibration_road_loads_round_trip(config: Config) -> None:
    cal = _stored(config)
    back = parse_calibration(to_toml(cal))
    assert back == cal and back.road_loads is not None
    assert back.road_loads.road_load_f0_n == 152.0 and back.road_loads.road_load_f2_n_per_mps2 == 0.41
    assert back.road_loads.runs_paired == 2 and back.road_loads.learned_from == "coast.mcap"
    assert "[road_loads]" in to_toml(cal) and "road loads F0 152.0 N" in summary(cal) and "road loads" in show(cal, "x")
    # a later run that measured none keeps them; one that measured new ones replaces them
    assert merged(back, Learned(), config, "other.mcap").road_loads == back.road_loads
    newer = merged(back, Learned(road_loads=(140.0, 0.0, 0.39, 4)), config, "new.mcap")
    assert newer.road_loads is not None and newer.road_loads.road_load_f0_n == 140.0


def test_config_coefficients_win_over_the_calibration(config: Config) -> None:
    cal = _stored(config)
    assert stored_road_loads(cal, EstimatorParams.from_config(config)) == RoadLoads(152.0, -0.3, 0.41)
    assert stored_road_loads(None, EstimatorParams.from_config(config)) is None
    for key, value in (("drag_area_m2", 0.65), ("rolling_resistance_coeff", 0.011)):  # either above 0: they win
        text = f"[vehicle]\n{key} = {value}\n"
        assert stored_road_loads(cal, EstimatorParams.from_config(parse_config(text, "x.toml"))) is None
    # 0 (the default, which a log's stored config spells out): the calibration's
    zero = parse_config("[vehicle]\nrolling_resistance_coeff = 0.0\ndrag_area_m2 = 0.0\n", "x.toml")
    assert stored_road_loads(cal, EstimatorParams.from_config(zero)) == RoadLoads(152.0, -0.3, 0.41)
    logged = parse_config(config.to_toml(), "log.toml")  # every key written out, as a log stores it
    assert stored_road_loads(cal, EstimatorParams.from_config(logged)) == RoadLoads(152.0, -0.3, 0.41)


def test_fx_uses_the_calibrations_road_loads() -> None:
    """A constant 20 m/s: Fx = F0 + F1*v + F2*v^2 = 152 - 6 + 164 = 310 N from the calibration, 0 without it."""
    cal = _stored(Config())
    p = params(r_ref_m=0.3)
    slips = {"FL": 0.0, "FR": 0.0, "RL": 0.0, "RR": 0.0}
    with_loads = [e for e in _run(p, lambda t: np.full_like(t, 20.0), slips, stored=cal) if 1.0 < e.time_s < 5.0]
    without = [e for e in _run(p, lambda t: np.full_like(t, 20.0), slips) if 1.0 < e.time_s < 5.0]
    assert with_loads and without
    assert all(e.force_n == pytest.approx(152.0 - 0.3 * 20.0 + 0.41 * 400.0, abs=1e-6) for e in with_loads)
    assert all(e.wheels["FL"].force_n == pytest.approx(155.0, abs=1e-6) for e in with_loads)  # front-driven
    assert all(e.force_n == 0.0 for e in without)
    overridden = params(r_ref_m=0.3, road_loads_configured=True)
    assert all(e.force_n == 0.0 for e in _run(overridden, lambda t: np.full_like(t, 20.0), slips, stored=cal)
               if 1.0 < e.time_s < 5.0)
    assert math.isclose(cal.road_loads.road_load_f0_n, 152.0)  # type: ignore[union-attr]


HEAVY = RoadLoadTruth(f0_n=400.0, f2_n_per_mps2=1.0, rotating_mass_factor=1.04, wind_mps=3.0)
"""A car that coasts from 110 to 18 km/h in about 50 s (the whole scenario in 141 s)."""


@pytest.fixture(scope="module")
def coast_down_log() -> tuple[Config, list]:
    from slipdaq.config import load_config, packaged_config_path
    from slipdaq.sim.emit import SimSettings, generate

    cfg = load_config(packaged_config_path()).with_overrides(vehicle={"rotating_mass_factor": 1.04})
    events = generate(cfg, "coast-down", "paved", SimSettings(seed=2, gps_latency_s=0.08, gps_noise_mps=0.03,
                                                                    wpt_rate_hz=50.0), 141.0, road_loads=HEAVY)
    return cfg, [e.record for e in events if e.record is not None]


@pytest.mark.slow
def test_coast_down_through_the_pipeline_live_and_replay_alike(coast_down_log: tuple[Config, list]) -> None:
    """The simulated coast-down scenario through the pipeline: two coast records, the second paired, F0 and F2 within
    5 % (F0 with F2*w^2 = 9 N of wind); the records the same with the summaries on a thread (live) and at once
    (replay); the estimator's learned road loads are the paired ones."""
    from concurrent.futures import ThreadPoolExecutor

    from slipdaq.pipeline import Pipeline
    from slipdaq.sinks import CollectingSink

    cfg, records = coast_down_log
    sync = CollectingSink()
    pipeline = Pipeline(cfg, [sync])
    pipeline.run(records)
    coasts = [m for m in sync.maneuvers if m.kind == "coast"]
    assert [m.coast_runs_paired for m in coasts] == [0, 2]
    assert [m.valid for m in coasts] == [False, True]
    paired = coasts[1]
    assert paired.road_load_f0_n == pytest.approx(409.0, rel=0.05)
    assert paired.road_load_f2_n_per_mps2 == pytest.approx(1.0, rel=0.05)
    assert paired.road_load_f0_n_lo < paired.road_load_f0_n < paired.road_load_f0_n_hi  # type: ignore[operator]
    learned = pipeline.estimator.learned().road_loads
    assert learned == (paired.road_load_f0_n, paired.road_load_f1_n_per_mps, paired.road_load_f2_n_per_mps2, 2)
    threaded = CollectingSink()
    with ThreadPoolExecutor(max_workers=1) as pool:
        Pipeline(cfg, [threaded], maneuver_executor=pool).run(records)
    assert [m.as_row() for m in threaded.maneuvers] == [m.as_row() for m in sync.maneuvers]


def test_driven_wheel_radius_corrected_for_the_force_it_carries() -> None:
    """Cruise windows of a driven wheel carrying 500 N at Cx = 100 kN (slip 0.5 %): 2*pi*N = d*(1 + s)/r0. The plain
    ratio gives r0/(1 + s), 1.5 mm small; with the force and Cx, r0."""
    from slipdaq.estimator.radius import RadiusCalibration

    r0, force, cx = 0.3, 500.0, 100_000.0
    plain, corrected = RadiusCalibration(), RadiusCalibration(cx_n=cx)
    for k in range(60):
        d = 12.0 + 0.1 * k
        arc = d * (1.0 + force / cx) / r0
        plain.add(d, arc)
        corrected.add(d, arc, road_n=force)
    assert plain.radius_m == pytest.approx(r0 / 1.005, rel=1e-12)
    assert corrected.radius_m == pytest.approx(r0, rel=1e-12)
    assert corrected.standard_error_m == plain.standard_error_m


def test_a_log_from_before_the_rotating_masses_replays_without_them() -> None:
    """A log stores its config with every key: one without rotating_mass_factor ran with M*a (factor 1.0); a log of
    this version keeps what it ran with."""
    from slipdaq.config import parse_logged_config

    assert parse_logged_config("[vehicle]\nmass_kg = 1500.0\n").vehicle.rotating_mass_factor == 1.0
    now = Config().with_overrides(vehicle={"rotating_mass_factor": 1.05})
    assert parse_logged_config(now.to_toml()).vehicle.rotating_mass_factor == 1.05
    assert parse_logged_config(Config().to_toml()).vehicle.rotating_mass_factor == 1.03


def test_a_coast_procedure_sets_the_paired_road_loads(config: Config) -> None:
    """A `[[test.procedure]] kind = "coast"`: the unpaired first coast is excluded (invalid), the pair's is its run;
    the set gives the road loads' statistics, F0 its main figure."""
    rng = np.random.default_rng(3)
    det = CoastDetector(config)
    out_rows, out_courses = coast_rows(True, 0.0, rng)
    back_rows, back_courses = coast_rows(False, out_rows[-1]["time_s"] + 60.0, rng)
    (alone,), (paired,) = feed(det, out_rows, out_courses), feed(det, back_rows, back_courses)
    test = Day.model_validate({"procedure": [
        {"name": "coast 100-20", "kind": "coast", "target_speed_kmh": 100.0, "runs": 1, "max_cv_percent": 5.0}]})
    wheels = ("FL", "FR", "RL", "RR")
    first, second = coast_record(alone, 1, 0.0, wheels, test), coast_record(paired, 2, 0.0, wheels, test)
    assert first.procedure == second.procedure == "coast 100-20"
    sets = Sets(test)
    sets.add(first)
    record = sets.add(second)
    assert record is not None and record["runs"] == [2] and record["complete"] and record["ok"]
    assert [e["index"] for e in record["excluded"]] == [1] and "invalid" in record["excluded"][0]["reason"]
    assert record["road_load_f0_n_n"] == 1 and record["road_load_f0_n_mean"] == second.road_load_f0_n
    assert record["road_load_f2_n_per_mps2_mean"] == second.road_load_f2_n_per_mps2
    slow = coast_record(replace(paired, speed_from_kmh=90.0), 3, 0.0, wheels, test)
    assert "start speed 90.0 km/h more than 2 km/h below 100 km/h" in sets.add(slow)["excluded"][-1]["reason"]
