"""The seed's IMU, an Xsens MTi on a serial port, live in the VM: `slipdaq run` with `[imu] source = "serial"` on
vcan0, hardware in the loop. VM only.

One daemon run (forked by zygote.py, at hil_support.DAEMON_NICE): the simulator's `brake` drive (3 s at 90 km/h,
braking at 5.5 m/s^2 to a stop) sent by wpt_sender.py --drive as in test_foxglove_vcan.py (WPT frames on a raw CAN
socket at 25 Hz per wheel, the 10 Hz NMEA on one pseudo-terminal) and, on a second pseudo-terminal, the simulator's
MTi ([imu] source = "serial": MTData2 messages at 100 Hz, PacketCounter, SampleTimeFine, UTCTime, Acceleration and
FreeAcceleration of the drive's forward acceleration; slipdaq.sim.xbus_encode), each written when due.

Asserted: every byte the sender wrote to the MTi's port is in the log's /imu/raw, in order; every message's
acceleration reached the estimator (/can/sensors imu_accel, each message's value); the windows while the car
moves take their force from the IMU; and `slipdaq replay` of the log gives the live estimates (live = replay, with the
MTi's records too). No timing is asserted: the emulated VM keeps real time loosely.

Skipped where the kernel has no SocketCAN or no vcan0 (the host): run it with tests/hil/run_vm.sh -k mti.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from hil_support import (
    Daemon,
    DaemonResult,
    Zygote,
    bind_pytest,
    can_unavailable_reason,
    replay_differences,
    report,
    sender_result,
    start_sender,
    write_config,
    write_drive,
    write_nmea,
)

_reason = can_unavailable_reason()
if _reason:
    pytest.skip(_reason, allow_module_level=True)

RATE_HZ = 25.0
SCENARIO = "brake"
DURATION_S = 12.0
MTI_RATE_HZ = 100.0
GPS_LINK, MTI_LINK = "/tmp/hil-gps-mti", "/tmp/hil-mti"


@dataclass
class Run:
    result: DaemonResult
    sender: dict[str, Any]
    messages: list[bytes]
    """The MTi messages the sender had to write, in order."""
    accel_mps2: list[float]
    """Each one's forward acceleration."""
    replay_diffs: list[str]


def _drive(d: Path) -> tuple[Path, list[bytes], list[float]]:
    """The simulator's drive as wpt_sender.py's --drive, --nmea and --mti files (its MTi's messages: [imu] source =
    "serial", slipdaq.sim.xbus_encode.SimulatedMti), the config with the MTi; the messages and their forward
    accelerations as slipdaq decodes them."""
    from slipdaq.config import load_config
    from slipdaq.decode.xbus import XbusDecoder, forward_accel_mps2
    from slipdaq.records import NmeaLine, XbusBytes
    from slipdaq.sim.emit import SimSettings, generate

    cfg_path = write_config(d, GPS_LINK)
    cfg_path.write_text(cfg_path.read_text() + f'\n[imu]\nsource = "serial"\nport = "{MTI_LINK}"\naxis = "x"\n')
    cfg = load_config(cfg_path)
    settings = SimSettings(wpt_rate_hz=0.0, gps_rate_hz=10.0, imu_rate_hz=MTI_RATE_HZ, seed=1)  # frames: the sender's
    truth, nmea, mti_lines, messages, accels = [], [], [], [], []
    decoder = XbusDecoder()
    for ev in generate(cfg, SCENARIO, "paved", settings, duration_s=DURATION_S):
        if ev.truth is not None:
            truth.append(ev.truth)
        elif isinstance(ev.record, NmeaLine):
            nmea.append((ev.time_s, ev.record.line))
        elif isinstance(ev.record, XbusBytes):
            packet = decoder.decode(ev.record)
            accel = forward_accel_mps2(packet, cfg.imu.axis, cfg.imu.sign) if packet is not None else None
            assert accel is not None, ev.record
            messages.append(ev.record.data)
            accels.append(accel)
            mti_lines.append(f"{ev.time_s:.6f} {ev.record.data.hex()}\n")
    assert len(messages) >= 0.9 * MTI_RATE_HZ * DURATION_S, len(messages)
    write_drive(d / "drive.json", truth, cfg.wpt.pulses_per_rev, settings.start_count)
    write_nmea(d / "drive.nmea", nmea)
    (d / "mti.txt").write_text("".join(mti_lines))
    return cfg_path, messages, accels


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory, pytestconfig: pytest.Config) -> Iterator[Run]:
    bind_pytest(pytestconfig)
    t0 = time.time()
    zygote = Zygote()
    try:
        import slipdaq.sim.emit  # noqa: F401

        d = tmp_path_factory.mktemp("mti")
        cfg, messages, accels = _drive(d)
        report(f"mti: drive generated {time.time() - t0:.0f} s after the start ({len(messages)} MTi messages); "
               f"zygote imports took {zygote.wait_ready():.0f} s")
        daemon = Daemon(zygote, cfg, d / "logs")
        sender = start_sender(RATE_HZ, DURATION_S, go=daemon.go, delay_s=1.5, drive=d / "drive.json",
                              nmea=d / "drive.nmea", gps_link=GPS_LINK, mti=d / "mti.txt", mti_link=MTI_LINK,
                              gps_reader_pid=daemon.pid)
        try:
            daemon.wait_log_open(600)
            r = sender_result(sender, 10 * DURATION_S + 900)
            daemon.wait_frames(r["sent"], 900)
            time.sleep(1.0)
            result = daemon.stop()
        finally:
            sender.kill()
            daemon.proc.kill()
        diffs = replay_differences(result.log, d / "replayed.mcap")
        yield Run(result, r, messages, accels, diffs)
    finally:
        zygote.close()


@pytest.fixture(autouse=True)
def _bind(pytestconfig: pytest.Config) -> None:
    bind_pytest(pytestconfig)


def test_every_byte_the_mti_sent_is_logged(run: Run) -> None:
    from slipdaq.logformat.reader import iter_topic
    from slipdaq.logformat.topics import TOPIC_IMU_RAW

    s = run.sender
    report(f"mti: sender wrote {s['mti_written']} of {len(run.messages)} messages ({s['mti_dropped']} dropped, "
           f"{s['mti_unread']} bytes unread), {s['sent']} WPT frames, {s['nmea_written']} NMEA lines")
    assert s["mti_written"] == len(run.messages) and s["mti_dropped"] == 0 and s["mti_unread"] == 0
    raw = b"".join(bytes.fromhex(d["data"]) for _t, _t2, d in iter_topic(run.result.log, (TOPIC_IMU_RAW,)))
    assert raw == b"".join(run.messages)


def test_every_acceleration_reaches_the_estimator(run: Run) -> None:
    from slipdaq.logformat.reader import iter_topic
    from slipdaq.logformat.topics import TOPIC_SENSORS

    got = [d["value"] for _t, _t2, d in iter_topic(run.result.log, (TOPIC_SENSORS,)) if d["kind"] == "imu_accel"]
    assert got == run.accel_mps2  # each message's own value, decoded as the daemon decodes it


def test_the_windows_take_their_force_from_the_mti_and_replay_equals_live(run: Run) -> None:
    from slipdaq.logformat.reader import iter_estimates

    rows = [r for r in iter_estimates(run.result.log) if r["speed_mps"] > 5 and r["force_n"] is not None]
    imu = sum(r["accel_source"] == "imu" for r in rows)
    report(f"mti: {run.result.estimates} estimates, {imu} of {len(rows)} moving windows with the IMU's force; "
           f"replay: {len(run.replay_diffs)} differences")
    assert rows and imu >= 0.9 * len(rows)
    assert not run.replay_diffs, run.replay_diffs[:5]
