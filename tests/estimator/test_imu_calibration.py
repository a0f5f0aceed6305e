"""The acceleration without gravity from an IMU without orientation (estimator/imu_gain.py): a simulated drive whose
body pitches 1.5 degrees per g on a 1-degree grade (sim/pitch.py), its CAN IMU's gain and offset estimated against
the GNSS speed, kept in the calibration and applied (accel_source imu-calibrated); the simulated MTi's pitched
messages (Quaternion, Acceleration, FreeAcceleration) give the acceleration without gravity (imu-orientation)."""

from __future__ import annotations

import dataclasses
import io
import math
from pathlib import Path

import numpy as np
import pytest

from slipdaq.config import Config, load_config
from slipdaq.config.calibration import Learned, load_calibration, merged, save_calibration, show, usable
from slipdaq.decode.mti_accel import forward_without_gravity, rotation_of
from slipdaq.decode.xbus import XbusDecoder
from slipdaq.estimator.imu_gain import ImuGainFit
from slipdaq.logformat.schemas import SCHEMAS
from slipdaq.logformat.topics import TOPIC_ESTIMATE
from slipdaq.offline.run import Rows, process
from slipdaq.records import XbusBytes
from slipdaq.records.columns import ACCEL_SOURCES, ESTIMATE_COLUMNS
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.pitch import GRAVITY_MPS2, BodyPitch
from slipdaq.sim.truth import truth_series
from slipdaq.sim.xbus_encode import SimulatedMti
from support.paths import CONFIG

IMU = {"message": "IMU_ACCEL", "signal": "AccelX"}
PITCH_DEG_PER_G, GRADE_DEG = 1.5, 1.0
TRUE_GAIN = 1.0 + math.radians(PITCH_DEG_PER_G) * math.cos(math.radians(GRADE_DEG))
"""d(a*cos(theta) + g*sin(theta + grade))/da at a = 0, theta = pitch_deg_per_g * a/g."""
TRUE_OFFSET_MPS2 = GRAVITY_MPS2 * math.sin(math.radians(GRADE_DEG))


@pytest.fixture(scope="module")
def cfg() -> Config:
    # the simulated car has no rotating masses: its force is M*a (the force checks below compare with that)
    return load_config(CONFIG).with_overrides(can={"dbc": ["wpt.dbc", "sensors.dbc"]}, imu=IMU,
                                              vehicle={"rotating_mass_factor": 1.0})


@pytest.fixture(scope="module")
def pitched_drive(cfg: Config):
    settings = SimSettings(gps_latency_s=0.05, gps_noise_mps=0.03, can_jitter_s=0.0005, imu_rate_hz=100.0, seed=3,
                           pitch_deg_per_g=PITCH_DEG_PER_G, grade_deg=GRADE_DEG)
    records, truth = [], []
    for ev in generate(cfg, "cycle", "paved", settings, 60.0):
        if ev.record is not None:
            records.append(ev.record)
        if ev.truth is not None:
            truth.append(ev.truth)
    return records, truth_series(truth, settings.start_utc_s)


def _force_error_n(rows: list[dict], ts: dict, mass_kg: float) -> float:
    """RMS of Fx - M * (the true acceleration's mean over the window) over the moving windows."""
    e = [r["force_n"] - mass_kg * float(np.mean(np.interp(np.linspace(r["time_s"] - 0.25, r["time_s"] + 0.25, 21),
                                                          ts["time_s"], ts["accel_mps2"])))
         for r in rows if r["force_n"] is not None and r["speed_mps"] > 5]
    return math.sqrt(sum(x * x for x in e) / len(e))


def test_the_can_imu_s_gain_and_offset_are_learned_kept_and_applied(cfg: Config, pitched_drive, tmp_path: Path) -> None:
    """1.5 degrees of pitch per g and a 1-degree grade, none of it in the config: the run learns the IMU's gain
    1 + k within 0.2 % (k within 8 %) and its offset g*sin(grade) within 0.01 m/s^2; the calibration keeps them with
    when and from which log (and not for another IMU); a run started from it takes imu-calibrated accelerations
    whose force is at least 3 times closer to M*a than the raw IMU's."""
    records, ts = pitched_drive
    raw = Rows()
    first = process(cfg, records, [raw], stream=io.StringIO())
    learned = first.estimator.learned()
    assert learned.imu_gain is not None
    gain, offset, windows = learned.imu_gain
    assert windows >= 300
    assert gain == pytest.approx(TRUE_GAIN, abs=0.002) and abs((gain - 1) / (TRUE_GAIN - 1) - 1) < 0.08
    assert offset == pytest.approx(TRUE_OFFSET_MPS2, abs=0.01)
    assert {r["accel_source"] for r in raw.rows if r["force_n"] is not None and r["speed_mps"] > 5} == {"imu"}

    cal = merged(None, learned, cfg, "drive.mcap", learned_at="2026-01-01T00:00:00Z")
    path = tmp_path / "calibration.toml"
    save_calibration(path, cal)
    back = load_calibration(path)
    assert back is not None and back.imu is not None and back.imu.gain == gain and back.imu.offset_mps2 == offset
    assert back.imu.reference == "can:IMU_ACCEL.AccelX" and back.imu.learned_from == "drive.mcap"
    assert "[imu]" in path.read_text() and "IMU can:IMU_ACCEL.AccelX  gain" in show(back, str(path))
    other = cfg.with_overrides(imu={"message": "IMU_ACCEL", "signal": "AccelY"})
    assert usable(back, other).imu is None and usable(back, cfg).imu == back.imu
    kept = merged(back, Learned(), cfg, "later.mcap")
    assert kept.imu == back.imu  # a run that learned none keeps the stored one

    corrected = Rows()
    process(cfg, records, [corrected], calibration=back, frozen=True, stream=io.StringIO())
    moving = [r for r in corrected.rows if r["force_n"] is not None and r["speed_mps"] > 5]
    assert moving and {r["accel_source"] for r in moving} == {"imu-calibrated"}
    before, after = _force_error_n(raw.rows, ts, cfg.vehicle.mass_kg), _force_error_n(moving, ts, cfg.vehicle.mass_kg)
    assert after < before / 3, (before, after)


def test_a_fit_needs_windows_spread_and_a_plausible_gain() -> None:
    """Fewer than 100 windows, or accelerations spread less than 1 m/s^2, or a gain 20 % off 1 (a wrong unit):
    nothing learned; a line a_imu = 1.03*a + 0.2 exactly: gain 1.03, offset 0.2."""
    fit = ImuGainFit()
    for k in range(99):
        a = 3.0 * math.sin(k * 0.3)
        fit.add(1.03 * a + 0.2, a)
    assert fit.result() is None
    fit.add(1.03 * 1.0 + 0.2, 1.0)
    got = fit.result()
    assert got is not None and got[0] == pytest.approx(1.03, abs=1e-12) and got[1] == pytest.approx(0.2, abs=1e-12)
    flat, wrong = ImuGainFit(), ImuGainFit()
    for k in range(200):
        a = math.sin(k * 0.3)
        flat.add(0.5 * a, 0.5 * a)
        wrong.add(9.81 * a, a)
    assert flat.result() is None and wrong.result() is None


def test_the_simulated_mti_pitches_and_its_orientation_takes_gravity_out() -> None:
    """The simulated MTi with 1.5 deg/g and a 1-degree grade sends a Quaternion; its Acceleration less gravity by it
    is a*cos(theta) on the forward axis (to Float32), its FreeAcceleration on the yaw's heading a*cos(grade); with
    neither pitch nor grade it sends what it sent before (no Quaternion)."""
    body = BodyPitch(PITCH_DEG_PER_G, GRADE_DEG)
    mti = SimulatedMti("x", 1, 1_767_225_600.0, 90.0, body)
    decoder = XbusDecoder()
    for k, a in enumerate((-9.0, -3.0, 0.0, 2.5)):
        p = decoder.decode(XbusBytes(0.0, mti.message(k * 0.01, a)))
        assert p is not None and p.quaternion is not None and rotation_of(p) is not None
        theta = math.radians(PITCH_DEG_PER_G * a / GRAVITY_MPS2)
        assert forward_without_gravity(p, "x", 1, None) == pytest.approx((a * math.cos(theta), "imu-orientation"),
                                                                            abs=2e-5)
        assert p.acceleration_mps2 is not None
        assert p.acceleration_mps2[0] == pytest.approx(body.forward_reading(a, a), abs=2e-5)
        stripped = XbusDecoder().decode(XbusBytes(0.0, mti.message(k * 0.01, a)))
        assert stripped is not None
        free_only = dataclasses.replace(stripped, acceleration_mps2=None)
        assert forward_without_gravity(free_only, "x", 1, None)[0] == pytest.approx(  # type: ignore[index]
            a * math.cos(math.radians(GRADE_DEG)), abs=2e-5)
    level = SimulatedMti("x", 1, 1_767_225_600.0, 90.0)
    p = XbusDecoder().decode(XbusBytes(0.0, level.message(0.0, 2.0)))
    assert p is not None and p.quaternion is None and p.acceleration_mps2 == (2.0, 0.0, np.float32(GRAVITY_MPS2))


def test_accel_source_is_declared_once() -> None:
    """The estimate's accel_source takes the five values in its column declaration, which the log's JSON Schema
    derives from (the two of before first: their MF4 codes unchanged)."""
    assert ACCEL_SOURCES[:2] == ("imu", "gps")
    assert set(ACCEL_SOURCES) == {"imu", "gps", "imu-orientation", "imu-free", "imu-calibrated"}
    column = next(c for g in ESTIMATE_COLUMNS for c in g.columns if c.name == "accel_source")
    assert column.values == ACCEL_SOURCES
    assert SCHEMAS[TOPIC_ESTIMATE]["properties"]["accel_source"]["enum"] == list(ACCEL_SOURCES)


def test_a_pitched_mti_s_orientation_takes_the_pitch_out_of_the_force(cfg: Config) -> None:
    """The simulated MTi on a body pitching 1.5 deg/g on a 1-degree grade: the windows take its Acceleration less
    gravity by its Quaternion (imu-orientation), and Fx is within 40 N RMS of M*a (the pitch and grade's g*sin
    would put about 250 N into it: the CAN IMU's raw row above)."""
    mti = cfg.with_overrides(imu={"source": "serial", "port": "/dev/ttyUSB1", "axis": "x"})
    settings = SimSettings(gps_latency_s=0.05, gps_noise_mps=0.03, can_jitter_s=0.0005, imu_rate_hz=100.0, seed=3,
                           pitch_deg_per_g=PITCH_DEG_PER_G, grade_deg=GRADE_DEG)
    records, truth = [], []
    for ev in generate(mti, "cycle", "paved", settings, 30.0):
        if ev.record is not None:
            records.append(ev.record)
        if ev.truth is not None:
            truth.append(ev.truth)
    ts = truth_series(truth, settings.start_utc_s)
    rows = Rows()
    process(mti, records, [rows], stream=io.StringIO())
    moving = [r for r in rows.rows if r["force_n"] is not None and r["speed_mps"] > 5]
    assert moving and sum(r["accel_source"] == "imu-orientation" for r in moving) >= 0.95 * len(moving)
    assert _force_error_n(moving, ts, mti.vehicle.mass_kg) < 40.0
