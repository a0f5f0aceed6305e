"""The simulator's MTi ([imu] source = "serial"): its forward acceleration as Xsens MTData2 messages (PacketCounter,
SampleTimeFine, UTCTime, Acceleration, FreeAcceleration), offline as records and live on a pseudo-terminal
(`slipdaq demo --imu serial`); the daemon logs them on /imu/raw and the estimator takes exactly the simulated
acceleration (to the MTi's Float32)."""

from __future__ import annotations

import asyncio
import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from slipdaq.cli import main
from slipdaq.decode.xbus import XbusDecoder, forward_accel_mps2
from slipdaq.live.demo import demo_config, demo_settings, run_demo_async
from slipdaq.logformat.reader import iter_estimates, iter_topic
from slipdaq.logformat.topics import TOPIC_IMU_RAW, TOPIC_SENSORS
from slipdaq.pipeline import Pipeline
from slipdaq.records import XbusBytes
from slipdaq.sim.emit import generate
from slipdaq.sim.vehicle import TruthSample
from slipdaq.sim.xbus_encode import GRAVITY_MPS2
from slipdaq.sinks import CollectingSink

IMU_RATE_HZ = 100.0


def f32(x: float) -> float:
    return float(np.float32(x))


def truth_at(truth: list[TruthSample]) -> dict[int, float]:
    """The simulated acceleration at each IMU instant k / IMU_RATE_HZ (the truth's 100 Hz instants)."""
    return {round(tr.time_s * IMU_RATE_HZ): tr.accel_mps2 for tr in truth}


def test_the_simulator_sends_the_imu_as_mti_messages_the_estimator_takes_exactly() -> None:
    """Every IMU sample is one MTData2 message: its counter, its sim time in 10 kHz ticks, its UTC, the simulated
    acceleration forward (gravity on z) and in ENU (heading east), to Float32. Through the pipeline, the estimator's
    IMU samples are those accelerations and each window's acceleration their mean over the window."""
    cfg = demo_config("/dev/null", "chan", "cycle", imu_port="/dev/ttyMTI")
    settings = replace(demo_settings("cycle", "serial"), imu_noise_mps2=0.0, can_jitter_s=0.0005, seed=4)
    events = list(generate(cfg, "cycle", "paved", settings, 20.0))
    accel = truth_at([e.truth for e in events if e.truth is not None])
    records = [e.record for e in events if isinstance(e.record, XbusBytes)]
    assert len(records) == 20 * IMU_RATE_HZ
    decoder = XbusDecoder()
    for k, record in enumerate(records):
        p = decoder.decode(record)
        assert p is not None and p.packet_counter == k and p.sample_time_fine == round(k / IMU_RATE_HZ * 10_000)
        assert p.utc_time_s == pytest.approx(settings.start_utc_s + k / IMU_RATE_HZ, abs=1e-6)
        a = accel[k]
        assert p.acceleration_mps2 == (f32(a), 0.0, f32(GRAVITY_MPS2))
        assert p.free_acceleration_mps2 == (f32(a), f32(a * math.cos(math.radians(90.0))), 0.0)
    assert decoder.other_messages == decoder.error_messages == decoder.noise_records == 0

    sink = CollectingSink()
    Pipeline(cfg, [sink]).run(e.record for e in events if e.record is not None)
    samples = [s for s in sink.sensors if s.kind == "imu_accel"]
    assert [s.value for s in samples] == [f32(accel[k]) for k in range(len(records))]
    times = np.array([s.time_s for s in samples])
    values = np.array([s.value for s in samples])
    moving = [e for e in sink.estimates if e.speed_mps > 5 and e.accel_mps2 is not None]
    assert moving and all(e.accel_source == "imu" for e in moving)
    for e in moving:
        t0, t1 = e.time_s - 0.5 * e.window_s, e.time_s + 0.5 * e.window_s
        assert e.accel_mps2 == pytest.approx(float(np.mean(values[(times >= t0) & (times <= t1)])), abs=1e-12)


def test_demo_with_the_imu_on_serial_logs_the_mti_and_takes_its_acceleration(tmp_path: Path) -> None:
    """`slipdaq demo --imu serial`: the MTi's messages on a real pseudo-terminal at 100 Hz; the daemon logs them on
    /imu/raw, each message's acceleration is the simulated one at its sample time (SampleTimeFine), the estimator's
    IMU samples are those messages' in order, the moving windows take Fx from them, and `replay` gives the same
    estimates."""
    truth: list[TruthSample] = []
    settings = replace(demo_settings("cycle", "serial"), imu_noise_mps2=0.0)
    with open(tmp_path / "status.txt", "w") as status:
        result, _err, cfg = asyncio.run(run_demo_async(6.0, "cycle", "paved", tmp_path, status_stream=status,
                                                       imu="serial", settings=settings, truth=truth))
    assert cfg.imu.source == "serial" and cfg.imu.port is not None
    accel = truth_at(truth)
    decoder = XbusDecoder()
    packets = [decoder.decode(XbusBytes(0.0, bytes.fromhex(d["data"])))
               for _t, _ns, d in iter_topic(result.log_path, (TOPIC_IMU_RAW,))]
    mti = [p for p in packets if p is not None]
    assert len(mti) >= 0.9 * 5.5 * IMU_RATE_HZ and decoder.noise_records == 0
    for p in mti:
        assert p.sample_time_fine is not None
        assert forward_accel_mps2(p, "x", 1) == f32(accel[round(p.sample_time_fine / 10_000 * IMU_RATE_HZ)])
    taken = [d["value"] for _t, _ns, d in iter_topic(result.log_path, (TOPIC_SENSORS,)) if d["kind"] == "imu_accel"]
    assert taken == [forward_accel_mps2(p, "x", 1) for p in mti]
    rows = list(iter_estimates(result.log_path))
    moving = [r for r in rows if r["speed_mps"] > 5 and r["force_n"] is not None]
    assert moving and sum(r["accel_source"] == "imu" for r in moving) >= 0.8 * len(moving)
    again = tmp_path / "again.mcap"
    assert main(["replay", str(result.log_path), "-o", str(again), "--no-calibration"]) == 0
    assert [json.dumps(r) for r in iter_estimates(again)] == [json.dumps(r) for r in rows]
