"""The MTi's forward acceleration without gravity (decode/mti_accel.py): Acceleration less g by the orientation
(Quaternion, RotationMatrix, EulerAngles), FreeAcceleration on the heading; the real captures (Acceleration with
EulerAngles) and the same captures re-encoded with FreeAcceleration in place of Acceleration (no real capture here
carries FreeAcceleration) each give one sample per packet."""

from __future__ import annotations

import csv
import dataclasses
import math
from pathlib import Path
from types import SimpleNamespace

import pytest

from slipdaq.cli import main
from slipdaq.config import load_config
from slipdaq.decode.mti_accel import (
    GRAVITY_MPS2,
    MtiAccel,
    forward_without_gravity,
    rotation_from_euler,
    rotation_from_quaternion,
    rotation_of,
)
from slipdaq.decode.xbus import MID_MTDATA2, MtiPacket, XbusDecoder, XbusFramer, xbus_message
from slipdaq.logformat.reader import iter_estimates, iter_topic
from slipdaq.logformat.topics import TOPIC_SENSORS
from slipdaq.pipeline import Pipeline
from slipdaq.records import XbusBytes
from slipdaq.sim.emit import SimSettings, generate
from slipdaq.sim.logs import write_drive_logs
from slipdaq.sim.xbus_encode import XDI_ACCELERATION, XDI_FREE_ACCELERATION, encode_item, encode_packet, utc_time
from slipdaq.sinks import CollectingSink
from slipdaq.sources.xbus_file import iter_xbus_capture
from support.paths import CONFIG, DATA

CAPTURES = DATA / "xsens-mti"

SIN10, COS10 = 0.17364817766693033, 0.984807753012208
"""sin and cos of 10 degrees."""


def test_gravity_comes_out_of_a_hand_computed_pitched_sensor() -> None:
    """A sensor pitched 10 degrees (R = Ry(10 deg), ENU) accelerating 3 m/s^2 along its x axis reads the specific
    force f = (3 - g sin 10, 0, g cos 10) = (1.297093, 0, 9.657665) (g = 9.80665); its orientation as EulerAngles,
    Quaternion (cos 5, 0, sin 5, 0) or RotationMatrix (sent column by column) gives back 3 on x, 0 on y and z."""
    g = GRAVITY_MPS2
    f = (1.297093, 0.0, 9.657665)
    half = math.radians(5.0)
    rows = ((COS10, 0.0, SIN10), (0.0, 1.0, 0.0), (-SIN10, 0.0, COS10))
    columns = tuple(rows[i][j] for j in range(3) for i in range(3))
    for orientation in ({"euler_angles_deg": (0.0, 10.0, 0.0)},
                        {"quaternion": (math.cos(half), 0.0, math.sin(half), 0.0)},
                        {"rotation_matrix": columns}):
        packet = MtiPacket(0.0, acceleration_mps2=f, orientation_frame="ENU", **orientation)  # type: ignore[arg-type]
        rot = rotation_of(packet)
        assert rot is not None
        for i in range(3):
            assert rot[i] == pytest.approx(rows[i], abs=1e-12)
        assert forward_without_gravity(packet, "x", 1, None) == pytest.approx((3.0, "imu-orientation"), abs=2e-6)
        assert forward_without_gravity(packet, "x", -1, None) == pytest.approx((-3.0, "imu-orientation"), abs=2e-6)
        for axis in ("y", "z"):
            assert forward_without_gravity(packet, axis, 1, None)[0] == pytest.approx(0.0, abs=2e-6)  # type: ignore
    # NED: a level sensor's z points down and reads -g; yaw 90 in ENU (x north) with FreeAcceleration 2 m/s^2 north
    level = MtiPacket(0.0, acceleration_mps2=(0.0, 0.0, -g), euler_angles_deg=(0.0, 0.0, 0.0), orientation_frame="NED")
    assert forward_without_gravity(level, "z", 1, None) == pytest.approx((0.0, "imu-orientation"), abs=1e-12)
    north = MtiPacket(0.0, free_acceleration_mps2=(0.0, 2.0, 0.0), euler_angles_deg=(0.0, 0.0, 90.0),
                      orientation_frame="ENU")
    assert forward_without_gravity(north, "x", 1, None) == pytest.approx((2.0, "imu-free"), abs=1e-12)
    # no orientation: FreeAcceleration on the GNSS course (45: north-east), none without a course
    bare = MtiPacket(0.0, free_acceleration_mps2=(1.0, 1.0, 0.3))
    assert forward_without_gravity(bare, "x", 1, 45.0) == pytest.approx((math.sqrt(2.0), "imu-free"), abs=1e-12)
    assert forward_without_gravity(bare, "x", 1, None) is None
    # Acceleration alone: as sent
    assert forward_without_gravity(MtiPacket(0.0, acceleration_mps2=(1.5, 0.0, g)), "x", 1, None) == (1.5, "imu")
    assert rotation_from_quaternion((1.0, 0.0, 0.0, 0.0)) == rotation_from_euler(0.0, 0.0, 0.0)


def _free_capture(path: Path, keep_orientation: bool) -> tuple[bytes, list[tuple[float, float, float]]]:
    """The capture re-encoded (sim/xbus_encode.encode_packet) with FreeAcceleration in place of Acceleration: its
    value a_L = R f - g*up from the packet's Acceleration and EulerAngles, in the same number format; without
    EulerAngles where keep_orientation is false. Returns the bytes and each packet's a_L."""
    out = bytearray()
    free: list[tuple[float, float, float]] = []
    decoder = XbusDecoder()
    for r in iter_xbus_capture(path):
        p = decoder.decode(r)
        if p is None:
            out += r.data
            continue
        rot = rotation_of(p)
        if p.acceleration_mps2 is None or rot is None:
            out += r.data
            continue
        f = p.acceleration_mps2
        a_l = tuple(sum(rot[i][j] * f[j] for j in range(3)) - (GRAVITY_MPS2 if i == 2 else 0.0) for i in range(3))
        ids = tuple(x ^ XDI_ACCELERATION ^ XDI_FREE_ACCELERATION if x & 0xFFF0 == XDI_ACCELERATION else x
                    for x in p.identifiers if keep_orientation or x & 0xFFF0 != 0x2030)
        q = dataclasses.replace(p, acceleration_mps2=None, free_acceleration_mps2=a_l, identifiers=ids,
                                euler_angles_deg=p.euler_angles_deg if keep_orientation else None)
        out += encode_packet(q)
        free.append(a_l)  # type: ignore[arg-type]
    return bytes(out), free


def _pipeline_samples(records: list[XbusBytes], axis: str) -> tuple[list[float], list[str], int]:
    """The pipeline's imu_accel samples of the records, their sources, and the packets among them that carry
    Acceleration or FreeAcceleration (the others: the GNSS's PVT packets)."""
    cfg = load_config(CONFIG).with_overrides(imu={"source": "serial", "port": "/dev/ttyUSB1", "axis": axis})
    sink = CollectingSink()
    pipeline = Pipeline(cfg, [sink])
    sources: list[str] = []
    for r in records:
        n = len(sink.sensors)
        pipeline.process(r)
        sources += [pipeline.xbus.source] * (len(sink.sensors) - n)
    decoder = XbusDecoder()
    inertial = sum(p is not None and (p.acceleration_mps2 or p.free_acceleration_mps2) is not None
                   for p in map(decoder.decode, records))
    assert decoder.packets == pipeline.xbus.decoder.packets
    return [s.value for s in sink.sensors], sources, inertial


@pytest.mark.parametrize("capture", ["1", "2", "3"])
def test_real_captures_with_acceleration_or_free_acceleration_give_one_sample_per_packet(
        capture: str, tmp_path: Path) -> None:
    """The real capture (Acceleration, EulerAngles) and the same packets with FreeAcceleration in place of
    Acceleration, imported from a file: one sample per inertial packet each (the GNSS's PVT packets carry neither);
    the FreeAcceleration on the orientation's heading is the oriented Acceleration's forward part (the sensor's x lay
    level: to 0.01 m/s^2)."""
    path = CAPTURES / capture / "output.bin"
    oriented, sources, packets = _pipeline_samples(list(iter_xbus_capture(path)), "x")
    assert packets >= 95 and len(oriented) == packets
    assert sources.count("imu-orientation") >= packets - 1  # the first packet carries no EulerAngles
    data, _free = _free_capture(path, keep_orientation=True)
    assert data != path.read_bytes()
    (tmp_path / "free.bin").write_bytes(data)
    freed, free_sources, free_packets = _pipeline_samples(list(iter_xbus_capture(tmp_path / "free.bin")), "x")
    assert free_packets == packets and len(freed) == packets
    decoder = XbusDecoder()
    decoded = [p for r in iter_xbus_capture(tmp_path / "free.bin") if (p := decoder.decode(r)) is not None]
    assert sum(p.acceleration_mps2 is None and p.free_acceleration_mps2 is not None for p in decoded) >= packets - 1
    pairs = [(a, b) for a, b, s_a, s_b in zip(oriented, freed, sources, free_sources)
             if s_a == "imu-orientation" and s_b == "imu-free"]
    assert len(pairs) >= packets - 1
    assert max(abs(a - b) for a, b in pairs) < 0.01


def test_free_acceleration_without_orientation_takes_the_course() -> None:
    """FreeAcceleration without orientation (the capture lay still: its VelocityXYZ gives no course): no sample before a
    course is known, then its projection on the course (MtiAccel.course_deg, which the pipeline sets from the fixes)."""
    data, free = _free_capture(CAPTURES / "1" / "output.bin", keep_orientation=False)
    framer, decoder = XbusFramer(), XbusDecoder()
    records = [r for r in framer.feed(data, 0.0) + framer.flush()
               if (p := decoder.decode(r)) is not None and p.free_acceleration_mps2 is not None]
    assert len(records) == len(free) >= 95
    mti = MtiAccel(SimpleNamespace(source="serial", axis="x", sign=1))
    assert all(mti.sample(r) is None for r in records[:10])
    mti.course_deg = 30.0
    got = [s[1] for r in records[10:] if (s := mti.sample(r)) is not None]
    s30, c30 = math.sin(math.radians(30.0)), math.cos(math.radians(30.0))
    assert got == pytest.approx([a[0] * s30 + a[1] * c30 for a in free[10:]], abs=1e-5)  # Float32 and its formats
    assert mti.source == "imu-free"


def test_import_of_a_free_acceleration_capture_feeds_the_estimator(tmp_path: Path) -> None:
    """A simulated drive heading east, its acceleration as an MTi's FreeAcceleration only (no Acceleration, no
    orientation: ENU, (a, 0, 0)): `import --imu-xbus` takes it on the NMEA course (imu-free), one sample per packet
    from the first course on, the moving windows' Fx from it, and `export --imu-csv` writes those samples."""
    cfg_path = tmp_path / "slipdaq.toml"
    cfg_path.write_text(CONFIG.read_text() + '\n[imu]\nsource = "serial"\nport = "/dev/ttyUSB1"\naxis = "x"\n')
    (tmp_path / "wpt.dbc").write_text((CONFIG.parent / "wpt.dbc").read_text())
    cfg = load_config(cfg_path)
    settings = SimSettings(gps_latency_s=0.0, gps_noise_mps=0.02, can_jitter_s=0.0005, seed=5, heading_deg=90.0)
    events = list(generate(cfg, "cycle", "paved", settings, 20.0))
    truth = write_drive_logs(events, tmp_path / "drive.log", tmp_path / "drive.nmea")
    capture = bytearray()
    for k, tr in enumerate(truth):
        items = [encode_item(0x1020, k), encode_item(0x1060, round(tr.time_s * 10_000)),
                 encode_item(0x1010, utc_time(settings.start_utc_s + tr.time_s)),
                 encode_item(XDI_FREE_ACCELERATION, (tr.accel_mps2, 0.0, 0.0))]
        capture += xbus_message(MID_MTDATA2, b"".join(items))
    (tmp_path / "mti.bin").write_bytes(bytes(capture))
    log = tmp_path / "raw.mcap"
    assert main(["import", "--config", str(cfg_path), "--can", str(tmp_path / "drive.log"), "--nmea",
                 str(tmp_path / "drive.nmea"), "--imu-xbus", str(tmp_path / "mti.bin"), "-o", str(log),
                 "--no-calibration"]) == 0
    imu = [(d["time_s"], d["value"]) for _t, _t2, d in iter_topic(log, (TOPIC_SENSORS,)) if d["kind"] == "imu_accel"]
    sent = {round(settings.start_utc_s + tr.time_s, 3): tr.accel_mps2 for tr in truth}
    first_moving = next(tr.time_s for tr in truth if tr.speed_mps >= 2.5)
    assert len(imu) >= len(truth) - round(first_moving * 100) - 2  # the truth at 100 Hz: one packet each
    assert all(abs(v - sent[round(t, 3)]) < 1e-5 for t, v in imu)  # Float32, on the course of 90 degrees
    rows = list(iter_estimates(log))
    moving = [r for r in rows if r["speed_mps"] > 5 and r["force_n"] is not None]
    assert moving and sum(r["accel_source"] == "imu-free" for r in moving) >= 0.9 * len(moving)
    out = tmp_path / "imu.csv"
    assert main(["export", str(log), "--imu-csv", str(out)]) == 0
    with open(out, newline="") as f:
        assert [float(r["accel_mps2"]) for r in csv.DictReader(f)] == [v for _t, v in imu]
