"""The vehicle's other sensors on CAN: the reference speed ([gps] source = "can"), the IMU ([imu]) and the brake
([brake]), decoded by the DBC (cantools) from the simulator's frames, through the pipeline, into the log and back;
and the report's brake-test and mu-slip figures against the simulator's truth."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cantools
import numpy as np
import pytest

from slipdaq.cli import main
from slipdaq.config import Config, ConfigError, load_config, parse_config
from slipdaq.decode.can_signals import STANDARD_GRAVITY_MPS2, SignalDecoder
from slipdaq.decode.can_wheels import DbcError
from slipdaq.logformat.reader import iter_estimates, iter_sensors, iter_topic
from slipdaq.logformat.topics import TOPIC_GPS
from slipdaq.offline.run import Rows, process, process_to_log
from slipdaq.records import CanFrame, CanFrameBatch
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.truth import (
    brake_onset_time_s,
    mfdd_mps2,
    slip_error,
    speed_at_onset_mps,
    stopping_distance_m,
    tire_peak,
    truth_series,
)
from support.paths import CONFIG

SENSORS = {"dbc": ["wpt.dbc", "sensors.dbc"]}
CAN_REFERENCE = {"source": "can", "message": "REF_SPEED", "signal": "Speed", "valid_signal": "SpeedValid",
                 "accuracy_signal": "SpeedAccuracy"}
IMU = {"message": "IMU_ACCEL", "signal": "AccelX"}
BRAKE = {"message": "BRAKE", "signal": "BrakePressed"}


@pytest.fixture(scope="module")
def base() -> Config:
    return load_config(CONFIG).with_overrides(can=SENSORS)


def _drive(cfg: Config, scenario: str, road: str, settings: SimSettings, duration_s: float):
    records, truth = [], []
    for ev in generate(cfg, scenario, road, settings, duration_s):  # type: ignore[arg-type]
        if ev.record is not None:
            records.append(ev.record)
        if ev.truth is not None:
            truth.append(ev.truth)
    return records, truth_series(truth, settings.start_utc_s)


def _frame(db: cantools.database.Database, name: str, t: float, **signals: float) -> CanFrame:
    msg = db.get_message_by_name(name)
    full = {s.name: 0 for s in msg.signals} | signals
    return CanFrame(t, msg.frame_id, bytes(msg.encode(full)))


# ---- decoding ----------------------------------------------------------------------------------------------------

def test_units_sign_validity_and_accuracy(base: Config) -> None:
    db = cantools.database.load_string(base.load_dbc_text(), "dbc")
    cfg = base.with_overrides(gps=CAN_REFERENCE, imu=IMU | {"sign": -1}, brake=BRAKE)
    frames = [
        _frame(db, "REF_SPEED", 1.0, Speed=72.0, SpeedValid=1, SpeedAccuracy=0.05),
        _frame(db, "IMU_ACCEL", 1.001, AccelX=2.5),
        _frame(db, "BRAKE", 1.002, BrakePressed=1),
        _frame(db, "REF_SPEED", 1.01, Speed=36.0, SpeedValid=0),
        CanFrame(1.02, db.get_message_by_name("IMU_ACCEL").frame_id, b"\x01"),  # too short: a bad frame
    ]
    dec = SignalDecoder(cfg)
    got = dec.decode(CanFrameBatch.from_frames(frames))
    assert [(i, s.kind) for i, s in got] == [(0, "reference_speed"), (1, "imu_accel"), (2, "brake"),
                                             (3, "reference_speed")]
    ref, imu, brake, invalid = (s for _, s in got)
    assert ref.value == pytest.approx(20.0) and ref.valid and ref.accuracy == pytest.approx(0.05)
    assert imu.value == pytest.approx(-2.5)  # mounted backwards
    assert brake.value == 1.0
    assert not invalid.valid and invalid.value == pytest.approx(10.0)
    assert dec.bad_frames == 1
    # units from the config override the DBC's: knots, and an acceleration in g
    kn = SignalDecoder(base.with_overrides(gps=CAN_REFERENCE | {"unit": "kn"}, imu=IMU | {"unit": "g"}))
    got = dict((s.kind, s.value) for _, s in kn.decode(CanFrameBatch.from_frames(frames[:2])))
    assert got["reference_speed"] == pytest.approx(72.0 * 1852 / 3600)
    assert got["imu_accel"] == pytest.approx(2.5 * STANDARD_GRAVITY_MPS2)


def test_config_errors_name_the_key(base: Config, tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="gps.message and gps.signal"):
        parse_config('[gps]\nsource = "can"\n')
    with pytest.raises(ConfigError, match="imu"):
        parse_config('[imu]\nmessage = "IMU_ACCEL"\n')
    with pytest.raises(DbcError, match="imu.signal: signal IMU_ACCEL.Nope not found"):
        SignalDecoder(base.with_overrides(imu={"message": "IMU_ACCEL", "signal": "Nope"}))
    with pytest.raises(DbcError, match="gps.message: message NOPE not found"):
        SignalDecoder(base.with_overrides(gps=CAN_REFERENCE | {"message": "NOPE"}))
    # the CLI's config check: one line naming every DBC
    toml = (CONFIG.read_text() + "\n").replace('dbc = "wpt.dbc"', 'dbc = ["wpt.dbc", "sensors.dbc"]')
    toml = toml.replace("[estimator]", '[imu]\nmessage = "IMU_ACCEL"\nsignal = "AccelZ"\n\n[estimator]')
    (tmp_path / "c.toml").write_text(toml)
    for name in ("wpt.dbc", "sensors.dbc"):
        (tmp_path / name).write_text((CONFIG.parent / name).read_text())
    rc = main(["simulate", "--config", str(tmp_path / "c.toml"), "--duration", "0.1"])
    assert rc == 2


def test_several_dbcs_are_one_text(base: Config) -> None:
    db = cantools.database.load_string(base.load_dbc_text(), "dbc")
    assert {m.name for m in db.messages} >= {"WPT_FL", "WPT_RR", "REF_SPEED", "IMU_ACCEL", "BRAKE"}


# ---- the reference speed on CAN ----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def can_reference_drive(base: Config):
    cfg = base.with_overrides(gps=CAN_REFERENCE)
    settings = SimSettings(gps_rate_hz=0.0, ref_speed_rate_hz=100.0, ref_speed_latency_s=0.02,
                           ref_speed_noise_mps=0.02, can_jitter_s=0.0005, seed=5)
    records, ts = _drive(cfg, "cycle", "paved", settings, 30.0)
    assert not any(not isinstance(r, CanFrame) for r in records)  # CAN only: no serial GPS at all
    return cfg, records, ts


def test_can_reference_speed_gives_windows_at_10_hz_within_target(can_reference_drive) -> None:
    cfg, records, ts = can_reference_drive
    rows = Rows()
    p = process(cfg.with_overrides(gps={"latency_s": 0.02}), records, [rows])
    assert p.fixes > 2500  # 100 Hz
    t = np.array([r["time_s"] for r in rows.rows])
    assert 280 <= len(t) <= 305 and np.median(np.diff(t)) == pytest.approx(0.1, abs=0.002)
    err = slip_error(rows.rows, ts)
    assert err.samples > 500 and err.rms_points < 0.12, err
    assert p.unknown_frames == 0  # the sensors' frames are not "unknown"
    # "auto": the wheels find the 20 ms (no UTC on CAN)
    auto = Rows()
    process(cfg, records, [auto])
    late = [r for r in auto.rows[150:]]
    assert {r["latency_source"] for r in late} == {"wheels"}
    assert np.median([r["gps_latency_s"] for r in late]) == pytest.approx(0.02, abs=0.006)
    assert slip_error(auto.rows, ts).rms_points < 0.15


def test_can_reference_is_logged_and_replays_bit_for_bit(can_reference_drive, tmp_path: Path) -> None:
    cfg, records, _ = can_reference_drive
    log = tmp_path / "ref.mcap"
    process_to_log(cfg, records[: len(records) // 2], log, "import")
    fixes = [d for _t, _x, d in iter_topic(log, (TOPIC_GPS,))]
    assert fixes and {f["sentence"] for f in fixes} == {"CAN"} and all(f["speed_accuracy_mps"] == pytest.approx(0.02)
                                                                       for f in fixes)
    sensors = list(iter_sensors(log))
    assert {s["kind"] for s in sensors} == {"reference_speed"} and len(sensors) == len(fixes)
    assert main(["replay", str(log), "-o", str(tmp_path / "again.mcap"), "--no-calibration"]) == 0
    assert list(iter_estimates(log)) == list(iter_estimates(tmp_path / "again.mcap"))


# ---- the IMU -----------------------------------------------------------------------------------------------------

def test_imu_gives_the_force_and_halves_its_error(base: Config) -> None:
    imu = base.with_overrides(imu=IMU)
    settings = SimSettings(gps_latency_s=0.05, gps_noise_mps=0.03, can_jitter_s=0.0005, imu_rate_hz=100.0, seed=9)
    records, ts = _drive(imu, "cycle", "paved", settings, 25.0)
    errors = {}
    for name, cfg in (("gps", base), ("imu", imu)):
        rows = Rows()
        process(cfg.with_overrides(gps={"latency_s": 0.05}), records, [rows])
        use = [r for r in rows.rows if r["force_n"] is not None and r["speed_mps"] > 5]
        sources = {r["accel_source"] for r in use}
        assert sources == {name}
        e = [r["force_n"] - cfg.vehicle.mass_kg * float(np.mean(np.interp(
            np.linspace(r["time_s"] - 0.25, r["time_s"] + 0.25, 21), ts["time_s"], ts["accel_mps2"]))) for r in use]
        errors[name] = math.sqrt(sum(x * x for x in e) / len(e))
    assert errors["imu"] < 0.5 * errors["gps"], errors


# ---- the brake signal and the report's figures against the truth ------------------------------------------------

@pytest.fixture(scope="module")
def abs_report(base: Config, tmp_path_factory: pytest.TempPathFactory):
    cfg = base.with_overrides(imu=IMU, brake=BRAKE)
    settings = SimSettings(wpt_rate_hz=500.0, can_jitter_s=0.0005, gps_latency_s=0.085, gps_noise_mps=0.03,
                           imu_rate_hz=100.0, brake_rate_hz=50.0, seed=7)
    records, ts = _drive(cfg, "brake-abs", "paved", settings, 14.0)
    d = tmp_path_factory.mktemp("abs")
    log = d / "abs.mcap"
    process_to_log(cfg, records, log, "import")
    assert main(["report", str(log), "-o", str(d / "report"), "--png"]) == 0
    summary = json.loads((d / "report" / "summary.json").read_text())
    return summary, ts, d


def test_brake_figures_against_the_truth(abs_report) -> None:
    summary, ts, d = abs_report
    rows = [r for r in summary["rows"] if r["phase"] == "brake"]
    assert len({r["maneuver"] for r in rows}) == 1 and len(rows) == 4
    r = rows[0]
    assert r["brake_speed_kmh"] == pytest.approx(speed_at_onset_mps(ts) * 3.6, abs=0.3)
    assert r["stopping_distance_m"] == pytest.approx(stopping_distance_m(ts), abs=0.5)
    assert r["mfdd_mps2"] == pytest.approx(mfdd_mps2(ts), rel=0.01)
    v0 = r["brake_speed_kmh"]
    assert r["stopping_distance_corrected_m"] == pytest.approx(r["stopping_distance_m"] * (80.0 / v0) ** 2)
    assert r["abs_cycles"] >= 10 and r["abs_frequency_hz"] == pytest.approx(7.0, rel=0.1)
    brake = summary["logs"][0]["maneuvers"][-1]["brake"]
    assert brake["onset_source"] == "brake signal"
    assert brake["onset_s"] == pytest.approx(brake_onset_time_s(ts), abs=0.021)  # a switch sampled at 50 Hz
    html = (d / "report" / "index.html").read_text()
    assert "Brake test" in html and "MFDD" in html


def test_mu_slip_peak_of_the_cycling_axle(abs_report) -> None:
    summary, _ts, d = abs_report
    peak = tire_peak("paved")
    rows = {r["wheel"]: r for r in summary["rows"] if r["phase"] == "brake"}
    for w in ("RL", "RR"):  # the limiting axle with brake_front_share 0.7: its wheels cycle around the peak
        assert rows[w]["mu_slip_model"] == "burckhardt"
        assert rows[w]["mu_peak"] == pytest.approx(peak.mu_peak, rel=0.05)
        assert rows[w]["slip_at_mu_peak"] == pytest.approx(peak.slip_at_mu_peak, abs=0.02)
    for w in ("FL", "FR"):  # below their peak throughout: none is invented
        assert rows[w]["mu_peak"] is None and rows[w]["slip_at_mu_peak"] is None
    assert (d / "report" / "abs" / "brake-mu-slip.png").stat().st_size > 5000


def test_brake_onset_without_a_brake_signal(base: Config) -> None:
    """No [brake]: the onset from the deceleration (the IMU's); the figures hold."""
    cfg = base.with_overrides(imu=IMU)
    settings = SimSettings(wpt_rate_hz=200.0, can_jitter_s=0.0005, gps_latency_s=0.085, imu_rate_hz=100.0, seed=3)
    records, ts = _drive(cfg, "brake-lock", "paved", settings, 12.0)
    rows = Rows()
    process(cfg, records, [rows])
    from slipdaq.report.summary import summarize_log

    s = summarize_log(rows.rows, {"config_toml": cfg.to_toml()}, rows.diagnostics, path="x", name="x", labels={},
                      fast=rows.fast, sensors=rows.sensors)
    brakes = [m.brake for m in s.maneuvers if m.phase == "brake"]
    assert len(brakes) == 1 and brakes[0] is not None
    b = brakes[0]
    assert b.onset_source == "deceleration"
    assert b.onset_s == pytest.approx(brake_onset_time_s(ts), abs=0.05)
    assert b.stopping_distance_m == pytest.approx(stopping_distance_m(ts), abs=1.0)
    assert b.abs_cycles == 0  # locked wheels do not cycle


# ---- the demo with the sensors on python-can's virtual bus -------------------------------------------------------

def test_demo_brake_abs_runs_live_with_the_sensors(tmp_path: Path) -> None:
    """`slipdaq demo --scenario brake-abs`: the simulator's IMU and brake switch on the virtual bus beside WPT frames
    at 500 Hz, the daemon decodes and logs them, the windows take Fx from the IMU and the high-rate slip follows
    the ABS cycles."""
    import asyncio

    from slipdaq.live.demo import run_demo_async
    from slipdaq.logformat.reader import iter_fast_slip

    with open(tmp_path / "status.txt", "w") as status:
        result, err, cfg = asyncio.run(run_demo_async(8.0, "brake-abs", "paved", tmp_path, status_stream=status,
                                                      status_every_s=2.0))
    assert cfg.imu.message == "IMU_ACCEL" and cfg.brake.message == "BRAKE"
    kinds = [s["kind"] for s in iter_sensors(result.log_path)]
    assert kinds.count("imu_accel") > 500 and kinds.count("brake") > 250 and "reference_speed" not in kinds
    rows = list(iter_estimates(result.log_path))
    moving = [r for r in rows if r["speed_mps"] > 5 and r["force_n"] is not None]
    assert moving and sum(r["accel_source"] == "imu" for r in moving) >= 0.9 * len(moving)
    fast = list(iter_fast_slip(result.log_path))
    assert len(fast) > 500
    rear = [r["slip_RL"] for r in fast if r["slip_RL"] is not None]
    assert min(rear) < -0.15 and max(rear) > -0.02  # beyond the tire's peak (11.6 %) and back: ABS cycles
    assert err.samples > 0 and err.rms_points < 0.5


def test_run_with_the_reference_on_can_reads_no_serial_port(base: Config, tmp_path: Path) -> None:
    """The live daemon with [gps] source = "can" on python-can's virtual bus: no serial port opened (gps.port names
    none that exists), every fix from the CAN reference, estimates from it."""
    import asyncio
    import os
    import time
    from dataclasses import replace as dc_replace

    import can

    from slipdaq.live.daemon import run_daemon
    from slipdaq.sim.realtime import play

    channel = f"slipdaq-test-ref-{os.getpid()}"
    cfg = base.with_overrides(can={"interface": "virtual", "channel": channel},
                              gps=CAN_REFERENCE | {"port": str(tmp_path / "no-such-port"), "latency_s": 0.02})
    log = tmp_path / "run.mcap"
    settings = SimSettings(gps_rate_hz=0.0, ref_speed_rate_hz=100.0, ref_speed_latency_s=0.02, seed=4)

    async def main() -> None:
        with can.Bus(interface="virtual", channel=channel, preserve_timestamps=True) as sim_bus, \
                can.Bus(interface="virtual", channel=channel) as daemon_bus:
            async def drive() -> None:
                while not log.exists():
                    await asyncio.sleep(0.02)
                run = dc_replace(settings, start_utc_s=time.time() + 0.1)
                await play(generate(cfg, "cycle", "paved", run, 7.0), bus=sim_bus, nmea_write=lambda b: None,
                           start_wall_s=run.start_utc_s, stamp_frames=True)

            async with asyncio.TaskGroup() as tg:
                task = tg.create_task(drive())
                result = await run_daemon(cfg, daemon_bus, log, duration_s=7.5, status_stream=open(os.devnull, "w"))
                task.cancel()
            assert result.nmea_lines == 0 and result.estimates > 40

    asyncio.run(main())
    fixes = [d for _t, _x, d in iter_topic(log, (TOPIC_GPS,))]
    assert len(fixes) > 500 and {f["sentence"] for f in fixes} == {"CAN"}
    events = [d for _t, _x, d in iter_topic(log, ("/diagnostics/events",))]
    assert not [e for e in events if e["source"] == "gps"]  # no serial GPS: nothing disconnected
    rows = list(iter_estimates(log))
    assert any(r["slip_FL"] is not None for r in rows)


def test_a_stored_latency_belongs_to_its_reference(base: Config, tmp_path: Path) -> None:
    """The latency a serial-GPS run stored is not used by a run whose reference is on CAN (another sensor, another
    latency), and stays in the file for the next serial run; the CAN run's own goes in with its reference."""
    from slipdaq.config.calibration import Learned, for_run, load_calibration, merged, save_calibration

    path = tmp_path / "calibration.toml"
    save_calibration(path, merged(None, Learned(latency=(0.085, 0.002, "utc"), r0={"FL": (0.3, 1e-4)}), base, "a"))
    assert load_calibration(path).latency.reference == "serial"  # type: ignore[union-attr]
    can_cfg = base.with_overrides(gps=CAN_REFERENCE)
    run = for_run(path, can_cfg)
    assert run.start is not None and run.start.latency is None and run.start.r0["FL"].radius_m == 0.3
    assert "not used" in run.note
    run.finish(Learned(), can_cfg, "b")  # it learned no latency: the serial one stays
    assert load_calibration(path).latency.latency_s == 0.085  # type: ignore[union-attr]
    run.finish(Learned(latency=(0.02, 0.001, "wheels")), can_cfg, "c")
    stored = load_calibration(path).latency
    assert stored is not None and stored.latency_s == 0.02 and stored.reference == "can:REF_SPEED.Speed"
    assert for_run(path, base).start.latency is None  # type: ignore[union-attr]  # and back: serial does not take it
    assert for_run(path, can_cfg).start.latency.latency_s == 0.02  # type: ignore[union-attr]
