"""Slip-driven simulator scenarios (brake-abs, brake-lock, launch-spin), the CAN sensors (IMU, brake switch,
reference speed) and the truth helpers of brake tests; the profile scenarios' output is unchanged."""

from __future__ import annotations

import hashlib
import itertools
import math
from functools import cache
from pathlib import Path

import cantools
import numpy as np
import pytest

from slipdaq import WHEELS
from slipdaq.config import Config, load_config
from slipdaq.records import CanFrame, NmeaLine
from slipdaq.sim import SCENARIOS
from slipdaq.sim.dynamics import DynamicVehicleSim, axle_loads_n
from slipdaq.sim.emit import SimEvent, SimSettings, generate
from slipdaq.sim.scenarios import (
    ABS_MIN_SPEED_MPS,
    ABS_RATE_HZ,
    BRAKE_TEST_SPEED_MPS,
    LAUNCH_SPEED_MPS,
    TRACTION_SLIP,
    AbsBraking,
    limiting_axle,
    vehicle_model,
)
from slipdaq.sim.sensors import SensorEncoder
from slipdaq.sim.truth import (
    brake_onset_time_s,
    mfdd_mps2,
    speed_at_onset_mps,
    stopping_distance_m,
    tire_peak,
    truth_series,
)
from slipdaq.sim.vehicle import CRUISE_BEFORE_BRAKE_S, ROADS, TruthSample, VehicleSim

CONFIG_PATH = Path(__file__).parents[2] / "config" / "slipdaq.toml"
START_UTC_S = SimSettings().start_utc_s
G = 9.81
DT_S = 0.001


@pytest.fixture(scope="module")
def cfg() -> Config:
    return load_config(CONFIG_PATH)


def sensors_config() -> Config:
    """The packaged config with sensors.dbc: IMU, brake switch and the reference speed on CAN."""
    return load_config(CONFIG_PATH).with_overrides(
        can={"dbc": ["wpt.dbc", "sensors.dbc"]},
        imu={"message": "IMU_ACCEL", "signal": "AccelX"},
        brake={"message": "BRAKE", "signal": "BrakePressed"},
        gps={"source": "can", "message": "REF_SPEED", "signal": "Speed", "valid_signal": "SpeedValid",
             "accuracy_signal": "SpeedAccuracy"},
    )


@cache
def run(scenario: str, road: str, duration_s: float) -> list[TruthSample]:
    """Truth at k*DT_S (exact instants, as the emitter asks for them)."""
    sim = vehicle_model(load_config(CONFIG_PATH), scenario, road)  # type: ignore[arg-type]
    out = [sim.state]
    for k in range(1, round(duration_s / DT_S) + 1):
        sim.advance_to(k * DT_S)
        out.append(sim.state)
    return out


def axle(sample: TruthSample, prefix: str, field: str) -> float:
    return sum(getattr(w, field) for name, w in sample.wheels.items() if name.startswith(prefix))


# --- model ------------------------------------------------------------------------------------------------------


def test_scenario_names_and_models(cfg: Config) -> None:
    assert SCENARIOS == ("accelerate", "brake", "cycle", "test-day", "highway", "brake-abs", "brake-abs-all",
                         "brake-lock", "launch-spin", "coast-down")
    assert all(isinstance(vehicle_model(cfg, s, "paved"), VehicleSim) for s in SCENARIOS[:5])  # type: ignore[arg-type]
    assert all(isinstance(vehicle_model(cfg, s, "sand"), DynamicVehicleSim) for s in SCENARIOS[5:])  # type: ignore[arg-type]
    with pytest.raises(ValueError):
        vehicle_model(cfg, "drift", "paved")  # type: ignore[arg-type]


@pytest.mark.parametrize("road", ["paved", "sand"])
def test_tire_peak_truth(road: str) -> None:
    peak = tire_peak(road)
    grid = np.linspace(0.0, 0.6, 60001)
    mu = np.array([ROADS[road].force_n(float(s), 1.0) for s in grid])
    assert peak.mu_peak == pytest.approx(mu.max(), rel=1e-6)
    assert peak.slip_at_mu_peak == pytest.approx(grid[mu.argmax()], abs=2e-5)
    low, high = {"paved": (1.0, 1.2), "sand": (0.5, 0.6)}[road]
    assert low <= peak.mu_peak <= high and 0.10 <= peak.slip_at_mu_peak <= 0.20


@pytest.mark.parametrize("road", ["paved", "sand"])
def test_loads_sum_to_weight_and_shift_forward_when_braking(cfg: Config, road: str) -> None:
    v = cfg.vehicle
    weight_n = v.mass_kg * G
    static_front_n = weight_n * v.front_axle_load_share
    braked = 0
    for s in run("brake-abs", road, 9.0):
        assert sum(w.fz_n for w in s.wheels.values()) == pytest.approx(weight_n, rel=1e-12)
        assert s.wheels["FL"].fz_n == s.wheels["FR"].fz_n and s.wheels["RL"].fz_n == s.wheels["RR"].fz_n
        transfer_n = v.mass_kg * abs(s.accel_mps2) * v.cg_height_m / v.wheelbase_m
        if s.accel_mps2 < 0.0:
            assert axle(s, "F", "fz_n") - static_front_n == pytest.approx(transfer_n, abs=1e-6)
            braked += 1
        assert axle(s, "F", "fz_n") >= static_front_n - 1e-6
    assert braked > 2000
    assert axle_loads_n(v, -G)[0] * 2 == pytest.approx(static_front_n + v.mass_kg * G * v.cg_height_m / v.wheelbase_m)


@pytest.mark.parametrize("road", ["paved", "sand"])
def test_abs_cycles_the_limiting_axle_around_the_peak(cfg: Config, road: str) -> None:
    samples = run("brake-abs", road, 9.0)
    peak = ROADS[road].peak_slip
    limiting = limiting_axle(ROADS[road].mu, cfg.vehicle)
    assert limiting == "rear"  # with brake_front_share 0.7 and 60 % of the load in front the rear reaches its peak first
    lim, other = ("RL", "FL") if limiting == "rear" else ("FL", "RL")
    abs_phase = [s for s in samples if s.brake_pressed and s.speed_mps >= ABS_MIN_SPEED_MPS + 0.3
                 and s.time_s >= CRUISE_BEFORE_BRAKE_S + 0.3]
    slips = np.array([s.wheels[lim].slip for s in abs_phase])
    beyond = slips < -peak
    crossings = int(np.count_nonzero(beyond[1:] & ~beyond[:-1]))  # into the unstable branch, once per cycle
    duration_s = abs_phase[-1].time_s - abs_phase[0].time_s
    assert 5.0 <= crossings / duration_s <= 10.0
    assert crossings / duration_s == pytest.approx(ABS_RATE_HZ, abs=0.5)
    assert slips.min() <= -1.5 * peak and slips.max() >= -0.6 * peak
    assert slips.max() < 0.0
    other_slips = np.array([s.wheels[other].slip for s in abs_phase])
    assert np.all(other_slips >= -peak) and np.all(other_slips < 0.0)  # the other axle stays on the stable branch
    mu_lim = np.array([s.wheels[lim].mu for s in abs_phase])
    assert -mu_lim.min() == pytest.approx(ROADS[road].mu, rel=1e-3)  # the peak is reached in every cycle's rise


@pytest.mark.parametrize("road", ["paved", "sand"])
def test_abs_force_split_is_the_brake_share(cfg: Config, road: str) -> None:
    share = cfg.vehicle.brake_front_share
    samples = [s for s in run("brake-abs", road, 9.0) if s.brake_pressed and s.speed_mps > ABS_MIN_SPEED_MPS + 0.1]
    assert len(samples) > 2000
    for s in samples[1:]:  # the onset instant itself has no force yet
        front_n, rear_n = axle(s, "F", "force_n"), axle(s, "R", "force_n")
        assert front_n < 0.0 and rear_n < 0.0
        assert front_n / (front_n + rear_n) == pytest.approx(share, rel=1e-9)
        assert front_n + rear_n == pytest.approx(s.force_n) == pytest.approx(cfg.vehicle.mass_kg * s.accel_mps2)
        for w in s.wheels.values():
            assert w.force_n == pytest.approx(ROADS[road].force_n(w.slip, w.fz_n), rel=1e-12)
            assert w.mu == pytest.approx(w.force_n / w.fz_n)


def test_abs_onset_ramp_and_lock_below_the_abs_speed(cfg: Config) -> None:
    samples = run("brake-abs", "paved", 9.0)
    onset = next(s for s in samples if s.brake_pressed)
    assert onset.time_s == pytest.approx(CRUISE_BEFORE_BRAKE_S, abs=DT_S / 2)
    assert onset.speed_mps == pytest.approx(BRAKE_TEST_SPEED_MPS, rel=1e-12)
    ramp = [s.wheels["RL"].slip for s in samples if onset.time_s <= s.time_s <= onset.time_s + 0.2]
    assert ramp[0] == 0.0 and all(b < a for a, b in zip(ramp, ramp[1:]))  # slip grows from 0
    slow = [s for s in samples if 0.0 < s.speed_mps < ABS_MIN_SPEED_MPS - 1.1]  # ABS off, the lock ramp done
    assert slow and all(w.slip == -1.0 and w.omega_radps == 0.0 for s in slow for w in s.wheels.values())
    stopped = [s for s in samples if s.time_s > onset.time_s and s.speed_mps == 0.0]
    assert stopped[-1].time_s - stopped[0].time_s >= 2.0
    assert all(s.force_n == 0.0 and s.accel_mps2 == 0.0 and s.brake_pressed for s in stopped)
    assert len({s.distance_m for s in stopped}) == 1


def test_brake_lock_slides_at_minus_one(cfg: Config) -> None:
    samples = run("brake-lock", "paved", 9.0)
    tire = ROADS["paved"]
    onset_s = brake_onset_time_s(samples)
    assert onset_s == pytest.approx(CRUISE_BEFORE_BRAKE_S, abs=DT_S / 2)
    locked = next(s for s in samples if s.wheels["FL"].slip == -1.0)
    assert 0.3 <= locked.time_s - onset_s <= 0.5
    ramp = [s for s in samples if onset_s <= s.time_s < locked.time_s]
    assert min(s.wheels["FL"].mu for s in ramp) == pytest.approx(-tire.mu, rel=1e-3)  # through the peak
    sliding_mu = tire.force_n(-1.0, 1.0)
    assert -sliding_mu < tire.mu
    moving = [s for s in samples if s.time_s >= locked.time_s and s.speed_mps > 0.0]
    for s in moving:
        assert all(w.slip == -1.0 and w.omega_radps == 0.0 for w in s.wheels.values())
        assert all(w.mu == pytest.approx(sliding_mu, rel=1e-12) for w in s.wheels.values())
        assert s.accel_mps2 == pytest.approx(sliding_mu * G, rel=1e-12)  # every wheel slides: a = mu_slide*g
    angles = [[w.angle_rad for w in s.wheels.values()] for s in moving]
    assert angles[0] == pytest.approx(angles[-1], abs=1e-9)  # locked wheels do not turn
    assert mfdd_mps2(samples) == pytest.approx(-sliding_mu * G, rel=1e-6)
    assert min(s.speed_mps for s in samples) == 0.0


@pytest.mark.parametrize("scenario", ["brake-abs", "brake-lock"])
@pytest.mark.parametrize("road", ["paved", "sand"])
def test_brake_truth_helpers(scenario: str, road: str) -> None:
    samples = run(scenario, road, 9.0)
    onset_s = brake_onset_time_s(samples)
    assert onset_s is not None and speed_at_onset_mps(samples) == pytest.approx(BRAKE_TEST_SPEED_MPS, rel=1e-12)
    moving = [s for s in samples if s.time_s >= onset_s]
    time_s = np.array([s.time_s for s in moving])
    speed = np.array([s.speed_mps for s in moving])
    integral_m = float(np.sum(np.diff(time_s) * (speed[1:] + speed[:-1]) / 2.0))  # trapezoid of V dt
    distance = stopping_distance_m(samples)
    assert distance == pytest.approx(integral_m, abs=0.01)
    v0 = BRAKE_TEST_SPEED_MPS
    assert distance > v0**2 / (2 * G * ROADS[road].mu)  # no better than every tire at its peak all the time
    mfdd = mfdd_mps2(samples)
    assert mfdd is not None and 0.5 * ROADS[road].mu * G < mfdd < ROADS[road].mu * G
    vb, ve = 0.8 * v0, 0.1 * v0
    in_window = (speed <= vb) & (speed >= ve)
    mean_decel = -float(np.sum(np.array([s.accel_mps2 for s in moving])[in_window] * speed[in_window])
                        / np.sum(speed[in_window]))  # distance-weighted mean deceleration = MFDD
    assert mfdd == pytest.approx(mean_decel, rel=0.01)
    series = truth_series(samples[::10], START_UTC_S)  # the helpers on truth_series arrays, 10 ms apart
    assert brake_onset_time_s(series) == pytest.approx(START_UTC_S + onset_s)
    assert stopping_distance_m(series) == pytest.approx(distance, abs=1e-9)
    assert mfdd_mps2(series) == pytest.approx(mfdd, rel=0.01)
    assert series["brake_pressed"].dtype == bool and series["fz_FL"].shape == series["speed_mps"].shape


def test_brake_truth_helpers_without_braking() -> None:
    samples = run("launch-spin", "sand", 2.0)
    assert brake_onset_time_s(samples) is None and stopping_distance_m(samples) is None
    assert mfdd_mps2(samples) is None and speed_at_onset_mps(samples) is None


@pytest.mark.parametrize("road", ["paved", "sand"])
def test_launch_spin_passes_the_peak_then_cruises(cfg: Config, road: str) -> None:
    samples = run("launch-spin", road, 16.0)
    peak = ROADS[road].peak_slip
    front = np.array([s.wheels["FL"].slip for s in samples])  # driven_axle = "front"
    assert front.max() >= 1.8 * peak
    assert np.count_nonzero(front > peak) * DT_S >= 2.5  # seconds spinning past the peak
    assert all(s.wheels[w].slip == 0.0 and s.wheels[w].force_n == 0.0 for s in samples for w in ("RL", "RR"))
    spinning = [s for s in samples if s.wheels["FL"].slip > 1.5 * peak]
    assert all(s.wheels["FL"].mu < ROADS[road].mu for s in spinning)  # past the peak: less force than at it
    assert samples[0].speed_mps == 0.0 and not any(s.brake_pressed for s in samples)
    assert samples[-1].speed_mps == pytest.approx(LAUNCH_SPEED_MPS, abs=0.05)
    assert abs(samples[-1].wheels["FL"].slip) < 0.002
    if road == "sand":  # traction control holds TRACTION_SLIP once the spin is over, until near the target speed
        assert front[round(6.5 / DT_S)] == pytest.approx(TRACTION_SLIP)
    speeds = [s.speed_mps for s in samples]
    assert speeds == sorted(speeds)


@pytest.mark.parametrize("scenario", ["brake-abs", "launch-spin"])
def test_wheel_angles_follow_omega(cfg: Config, scenario: str) -> None:
    sim = vehicle_model(cfg, scenario, "sand", r0_offset_m={"FL": 0.002, "RR": -0.001})
    sim.advance_to(4.0)
    for _ in range(300):
        before = sim.state
        after = sim.step(DT_S)
        for w in WHEELS:
            a, b = before.wheels[w], after.wheels[w]
            assert b.omega_radps == pytest.approx(after.speed_mps * (1.0 + b.slip) / b.r0_m)
            assert (b.angle_rad - a.angle_rad) / DT_S == pytest.approx((a.omega_radps + b.omega_radps) / 2, rel=1e-9)


def test_limiting_axle_follows_the_brake_balance(cfg: Config) -> None:
    front_heavy = cfg.vehicle.model_copy(update={"brake_front_share": 0.9})
    assert limiting_axle(1.0, front_heavy) == "front"
    assert limiting_axle(1.0, cfg.vehicle) == "rear"
    controller = AbsBraking(ROADS["paved"], front_heavy)
    assert controller.limiting_axle == "front"
    sim = DynamicVehicleSim(cfg.model_copy(update={"vehicle": front_heavy}), controller, "paved")
    sim.advance_to(4.0)
    s = sim.state
    assert s.wheels["FL"].slip < -0.4 * ROADS["paved"].peak_slip and s.wheels["RL"].slip >= -ROADS["paved"].peak_slip
    assert axle(s, "F", "force_n") / s.force_n == pytest.approx(0.9)


# --- emitted records ------------------------------------------------------------------------------------------------

SENSOR_SETTINGS = SimSettings(imu_rate_hz=100.0, brake_rate_hz=50.0, ref_speed_rate_hz=20.0,
                              ref_speed_latency_s=0.05, can_jitter_s=0.0005, wpt_rate_hz=50.0, gps_rate_hz=0.0)


@cache
def sensor_events() -> list[SimEvent]:
    return list(generate(sensors_config(), "brake-abs", "paved", SENSOR_SETTINGS, 8.0))


def decoded(events: list[SimEvent], name: str) -> list[tuple[float, dict[str, float]]]:
    """(sim time of the frame's stamp, decoded signals) of the frames of message `name`."""
    db = cantools.database.load_string(sensors_config().load_dbc_text(), database_format="dbc", strict=False)
    msg = db.get_message_by_name(name)
    return [(ev.record.timestamp_s - START_UTC_S, msg.decode(ev.record.data, decode_choices=False))
            for ev in events if isinstance(ev.record, CanFrame) and ev.record.arbitration_id == msg.frame_id]


def truth_at(events: list[SimEvent]) -> dict[int, TruthSample]:
    return {round(ev.truth.time_s * 100): ev.truth for ev in events if ev.truth is not None}


def test_imu_frames_carry_the_true_acceleration() -> None:
    evs = sensor_events()
    truth = truth_at(evs)
    frames = decoded(evs, "IMU_ACCEL")
    assert len(frames) == 800
    residuals = []
    for k, (stamp_s, values) in enumerate(frames):
        assert k / 100 <= stamp_s < k / 100 + SENSOR_SETTINGS.can_jitter_s  # sampled at k/rate, CAN jitter after
        residuals.append(values["AccelX"] - truth[k].accel_mps2)
        assert values["AccelY"] == 0.0
    r = np.array(residuals)
    noise = SENSOR_SETTINGS.imu_noise_mps2
    assert abs(r.mean()) < 4 * noise / math.sqrt(len(r)) + 0.0005
    assert r.std() == pytest.approx(noise, rel=0.1)
    assert min(truth[k].accel_mps2 for k in truth) < -7.0  # the braking is in there


def test_brake_frames_carry_the_pedal() -> None:
    evs = sensor_events()
    truth = truth_at(evs)
    frames = decoded(evs, "BRAKE")
    assert len(frames) == 400
    for k, (stamp_s, values) in enumerate(frames):
        assert 2 * k / 100 <= stamp_s < 2 * k / 100 + SENSOR_SETTINGS.can_jitter_s
        assert values["BrakePressed"] == int(truth[2 * k].brake_pressed)
        assert values["BrakePressure"] == 0.0
    assert {v["BrakePressed"] for _, v in frames} == {0, 1}


def test_reference_speed_frames_are_late_and_noisy() -> None:
    evs = sensor_events()
    truth = truth_at(evs)
    frames = decoded(evs, "REF_SPEED")
    latency_s = SENSOR_SETTINGS.ref_speed_latency_s
    assert len(frames) == 159  # measured at k/20 s, the last one's arrival (7.95 s + 50 ms) is past the end
    residuals = []
    for k, (stamp_s, values) in enumerate(frames):
        assert k / 20 + latency_s <= stamp_s < k / 20 + latency_s + SENSOR_SETTINGS.can_jitter_s
        residuals.append(values["Speed"] / 3.6 - truth[5 * k].speed_mps)
        assert values["SpeedValid"] == 1
        assert values["SpeedAccuracy"] == pytest.approx(SENSOR_SETTINGS.ref_speed_noise_mps)
    r = np.array([x for x, (_, v) in zip(residuals, frames) if v["Speed"] > 0.0])
    assert np.abs(r).max() < 5 * SENSOR_SETTINGS.ref_speed_noise_mps
    assert r.std() == pytest.approx(SENSOR_SETTINGS.ref_speed_noise_mps, rel=0.25)


def test_imu_sign_and_unit_are_applied_inversely(cfg: Config) -> None:
    config = sensors_config().with_overrides(imu={"message": "IMU_ACCEL", "signal": "AccelX", "unit": "g", "sign": -1})
    frame = SensorEncoder(config).imu_frame(0.0, 4.903325)
    db = cantools.database.load_string(config.load_dbc_text(), database_format="dbc", strict=False)
    assert db.decode_message(frame.arbitration_id, frame.data)["AccelX"] == pytest.approx(-0.5, abs=0.001)


def test_sensors_only_when_enabled_and_named(cfg: Config) -> None:
    def ids(config: Config, settings: SimSettings) -> set[int]:
        evs = generate(config, "brake-lock", "paved", settings, 1.0)
        return {ev.record.arbitration_id for ev in evs if isinstance(ev.record, CanFrame)}

    wpt_ids = ids(cfg, SimSettings())
    assert len(wpt_ids) == 4
    assert ids(cfg, SENSOR_SETTINGS) == wpt_ids  # rates set, but the config names no sensor
    assert ids(sensors_config(), SimSettings()) == wpt_ids  # sensors named, no rate set
    assert ids(sensors_config(), SENSOR_SETTINGS) == wpt_ids | {768, 769, 770}


def test_sensors_do_not_disturb_the_other_streams() -> None:
    """With the sensors on, the WPT frames, NMEA lines and truth are those of a run without them (their own random
    generators; rates on the truth's 100 Hz grid, so the model is stepped at the same instants)."""
    base = SimSettings(can_jitter_s=0.0005, gps_latency_s=0.03)
    with_sensors = SimSettings(can_jitter_s=0.0005, gps_latency_s=0.03, imu_rate_hz=100.0, brake_rate_hz=50.0,
                               ref_speed_rate_hz=10.0)
    config = sensors_config()
    plain = [ev for ev in generate(config, "brake-abs", "sand", base, 5.0)]
    mixed = [ev for ev in generate(config, "brake-abs", "sand", with_sensors, 5.0)
             if not (isinstance(ev.record, CanFrame) and ev.record.arbitration_id in (768, 769, 770))]
    assert [(ev.time_s, ev.record) for ev in plain] == [(ev.time_s, ev.record) for ev in mixed]
    truth = [ev.truth.speed_mps for ev in plain if ev.truth is not None]
    assert truth == pytest.approx([ev.truth.speed_mps for ev in mixed if ev.truth is not None], abs=1e-9)


def test_sensor_frames_are_held_by_a_can_stall() -> None:
    settings = SimSettings(imu_rate_hz=100.0, brake_rate_hz=50.0, can_stall=(4.0, 0.3))
    evs = list(generate(sensors_config(), "brake-abs", "paved", settings, 5.0))
    stamps = [ev.record.timestamp_s - START_UTC_S for ev in evs
              if isinstance(ev.record, CanFrame) and ev.record.arbitration_id in (769, 770)]
    assert not any(4.0 <= t < 4.3 for t in stamps)
    assert sum(4.3 <= t < 4.301 for t in stamps) == 30 + 15 + 2  # the IMU and brake frames of the stall, then 4.3's
    times = [ev.time_s for ev in evs]
    assert times == sorted(times)


# --- the profile scenarios are unchanged ------------------------------------------------------------------------

HEAD_DIGESTS = {  # the first 6000 events with SimSettings(can_jitter_s=0.0005), computed with the code before the
    # slip-driven scenarios and CAN sensors were added
    ("accelerate", "paved"): "7cca03cae0fbaa5c94b21606345cef1f",
    ("accelerate", "sand"): "cb2e6e382b8220dd638f142f6cae9b4e",
    ("brake", "paved"): "eb3c85e9528f24b1bf554201d6c0a82c",
    ("brake", "sand"): "b0615264c82afc714be75417945b0d47",
    ("cycle", "paved"): "b25e6e3eb98bc94c0c9a00e57d117f49",
    ("cycle", "sand"): "b836e3aff67b80b9d2d7cadd16d182ea",
}


def event_line(ev: SimEvent) -> str:
    r, t = ev.record, ev.truth
    if isinstance(r, CanFrame):
        return f"C {ev.time_s:.9f} {r.timestamp_s:.6f} {r.arbitration_id} {r.data.hex()}"
    if isinstance(r, NmeaLine):
        return f"N {ev.time_s:.9f} {r.timestamp_s:.6f} {r.line}"
    assert t is not None
    values = [t.time_s, t.speed_mps, t.accel_mps2, t.force_n, t.distance_m]
    for w in sorted(t.wheels):
        x = t.wheels[w]
        values += [x.slip, x.omega_radps, x.angle_rad, x.r0_m, x.force_n, x.cx_n]
    return "T " + " ".join(f"{v:.10g}" for v in values)


@pytest.mark.parametrize(("scenario", "road"), sorted(HEAD_DIGESTS))
def test_profile_scenarios_emit_what_they_did(cfg: Config, scenario: str, road: str) -> None:
    h = hashlib.sha256()
    for ev in itertools.islice(generate(cfg, scenario, road, SimSettings(can_jitter_s=0.0005), None), 6000):  # type: ignore[arg-type]
        h.update((event_line(ev) + "\n").encode())
    assert h.hexdigest()[:32] == HEAD_DIGESTS[(scenario, road)]


def test_profile_scenarios_truth_has_the_new_fields(cfg: Config) -> None:
    sim = VehicleSim(cfg, "cycle", "paved")
    driving, braking = sim.step(5.0), sim.step(7.5)
    assert not driving.brake_pressed and braking.brake_pressed and braking.accel_mps2 < 0.0
    for s in (driving, braking):
        assert sum(w.fz_n for w in s.wheels.values()) == pytest.approx(cfg.vehicle.mass_kg * G)
        assert all(w.mu == pytest.approx(w.force_n / w.fz_n) for w in s.wheels.values())


# --- command line and demo ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("verb", ["simulate", "demo"])
@pytest.mark.parametrize("scenario", ["brake-abs", "brake-lock", "launch-spin", "cycle"])
def test_cli_accepts_the_scenarios(verb: str, scenario: str) -> None:
    from slipdaq.cli import build_parser

    assert build_parser().parse_args([verb, "--scenario", scenario]).scenario == scenario


def test_demo_names_the_sensors_for_the_new_scenarios() -> None:
    from slipdaq.live.demo import demo_config, demo_settings

    plain = demo_config("/dev/null", "chan", "cycle")
    assert plain.can.dbc == "wpt.dbc" and plain.imu.message is None and demo_settings("cycle") == SimSettings()
    cfg = demo_config("/dev/null", "chan", "brake-abs")
    assert cfg.can.dbc == ["wpt.dbc", "sensors.dbc"]
    assert (cfg.imu.message, cfg.imu.signal, cfg.brake.message, cfg.brake.signal) == \
        ("IMU_ACCEL", "AccelX", "BRAKE", "BrakePressed")
    assert cfg.gps.source == "serial" and cfg.gps.port == "/dev/null"
    encoder = SensorEncoder(cfg)
    assert encoder.imu is not None and encoder.brake is not None and encoder.reference is None
    abs_settings = demo_settings("brake-abs")
    assert (abs_settings.imu_rate_hz, abs_settings.brake_rate_hz, abs_settings.wpt_rate_hz) == (100.0, 50.0, 500.0)
    assert demo_settings("launch-spin").wpt_rate_hz == SimSettings().wpt_rate_hz
