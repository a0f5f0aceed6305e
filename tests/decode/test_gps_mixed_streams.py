"""Receivers that mix binary (UBX, RTCM) and NMEA on one port: gpsd's captures in tests/data/gpsd-ubx-mixed, played
through a real pseudo-terminal into the live serial reader and imported from the file, give the same records and the
same fixes, and those are the ones an independent reader finds in the bytes (pyubx2 with pynmeagps) and gpsd printed.

In these captures every epoch's RMC follows a block of UBX (and RTCM) bytes with no line end in between. The
bytes are written to the pty in seeded chunks of 1 to max_chunk bytes.
"""

from __future__ import annotations

import asyncio
import calendar
import datetime as dt
import io
import json
import zlib
from functools import cache
from pathlib import Path

import pytest
from mcap.reader import make_reader
from pyubx2 import NMEA_PROTOCOL, UBX_PROTOCOL, UBXReader

from slipdaq.cli import main
from slipdaq.decode.nmea import DROP_REASONS, KNOT_MPS, NmeaDecoder
from slipdaq.decode.ubx import UbxDecoder
from slipdaq.records import GpsFix, NmeaLine, UbxFrame
from slipdaq.sources.files import iter_nmea_log
from support.gpsd_captures import ms, play_through_pty, tpv_speeds
from support.paths import CONFIG, DATA, write_config

CAPTURES = sorted((DATA / "gpsd-ubx-mixed").glob("*.log"))
SPEED_TOL_MPS = 0.001
"""gpsd prints speeds to the mm/s."""
_FIX_MODES = ("A", "D", "F", "P", "R")


def _utc(date: dt.date, time: dt.time) -> float:
    return calendar.timegm(date.timetuple()) + time.hour * 3600 + time.minute * 60 + time.second \
        + time.microsecond * 1e-6


@cache
def identities(capture: Path) -> dict[str, int]:
    """How many messages of each kind (NMEA sentence type, UBX message) pyubx2 and pynmeagps find in the bytes."""
    out: dict[str, int] = {}
    for _raw, msg in UBXReader(io.BytesIO(capture.read_bytes()), protfilter=NMEA_PROTOCOL | UBX_PROTOCOL, quitonerror=0):
        kind = msg.identity[2:] if len(msg.identity) == 5 else msg.identity  # GNRMC -> RMC, NAV-PVT
        out[kind] = out.get(kind, 0) + 1
    return out


@cache
def reference(capture: Path) -> tuple[list[bytes], list[tuple[float, float]], list[tuple[float, float]]]:
    """Every UBX frame, and (UTC time, speed m/s) of every valid RMC and of every NAV-PVT, as pyubx2 and pynmeagps
    read the bytes."""
    frames, rmc, pvt = [], [], []
    reader = UBXReader(io.BytesIO(capture.read_bytes()), protfilter=NMEA_PROTOCOL | UBX_PROTOCOL, quitonerror=0)
    for raw, msg in reader:
        if raw[:2] == b"\xb5\x62":
            frames.append(raw)
        if msg.identity.endswith("RMC") and msg.status == "A" and msg.spd != "" and msg.posMode in _FIX_MODES:
            rmc.append((_utc(msg.date, msg.time), msg.spd * KNOT_MPS))
        elif msg.identity == "NAV-PVT":
            when = dt.datetime(msg.year, msg.month, msg.day, msg.hour, msg.min, msg.second, tzinfo=dt.UTC)
            pvt.append((when.timestamp() + msg.nano * 1e-9, msg.gSpeed / 1000.0))
    return frames, rmc, pvt


def decode(records: list[NmeaLine | UbxFrame]) -> list[GpsFix]:
    nmea, ubx = NmeaDecoder(), UbxDecoder()
    fixes = [nmea.decode(r) if isinstance(r, NmeaLine) else ubx.decode(r) for r in records]
    return [f for f in fixes if f is not None]


def _content(r: NmeaLine | UbxFrame) -> str | bytes:
    return r.line if isinstance(r, NmeaLine) else r.data


def _values(f: GpsFix) -> tuple[object, ...]:
    """A fix without its host arrival time (live: the reader's clock; import: the sentence's own time)."""
    return (f.sentence, f.valid, f.speed_mps, f.fix_time_utc_s, f.course_deg, f.latitude_deg, f.longitude_deg)


@pytest.mark.parametrize("capture", CAPTURES, ids=lambda p: p.stem)
@pytest.mark.parametrize("max_chunk", [16, 4096])
def test_live_and_import_keep_every_fix(capture: Path, max_chunk: int) -> None:
    data = capture.read_bytes()
    want_frames, want_rmc, want_pvt = reference(capture)
    assert want_rmc and want_pvt

    imported = list(iter_nmea_log(capture))
    played = asyncio.run(play_through_pty(data, len(imported), zlib.crc32(capture.name.encode()), max_chunk))
    assert played.reconnects == 0 and played.last_error is None
    assert [_content(r) for r in played.records] == [_content(r) for r in imported]
    assert [r.data for r in played.records if isinstance(r, UbxFrame)] == want_frames

    live, offline = decode(played.records), decode(imported)
    assert [_values(f) for f in live] == [_values(f) for f in offline]

    rmc = [f for f in live if f.sentence == "RMC" and f.valid]
    assert len(rmc) == len(want_rmc)
    for f, (utc, speed) in zip(rmc, want_rmc):
        assert f.fix_time_utc_s == pytest.approx(utc, abs=1e-6) and f.speed_mps == pytest.approx(speed, abs=1e-9)
    pvt = [f for f in live if f.sentence == "NAV-PVT"]
    assert len(pvt) == len(want_pvt)
    for f, (utc, speed) in zip(pvt, want_pvt):
        assert f.fix_time_utc_s == pytest.approx(utc, abs=1e-6) and f.speed_mps == pytest.approx(speed, abs=1e-9)

    # gpsd's own output for the same capture: a TPV with the same speed at the time of every RMC but the first (gpsd
    # reports from its second epoch on, once it has seen where a receiver's cycle ends)
    tpv = tpv_speeds(capture.with_name(capture.name + ".chk"))
    assert sorted(tpv) == [ms(f.fix_time_utc_s) for f in rmc[1:]]  # type: ignore[arg-type]
    for f in rmc[1:]:
        assert abs(tpv[ms(f.fix_time_utc_s)] - f.speed_mps) <= SPEED_TOL_MPS  # type: ignore[arg-type]


@pytest.mark.parametrize("capture", CAPTURES, ids=lambda p: p.stem)
def test_import_logs_every_frame_and_counts_every_dropped_sentence(capture: Path, tmp_path: Path) -> None:
    """`slipdaq import` of the raw capture: every UBX frame in /gps/ubx/raw, and /diagnostics counts the sentences
    that gave the estimator nothing by reason, as many as pyubx2 finds of each kind."""
    can = tmp_path / "one.log"
    can.write_text("(1700000000.000000) can0 123#00\n")  # the verb wants a CAN log; one frame of no wheel
    out = tmp_path / "mixed.mcap"
    assert main(["import", "--can", str(can), "--nmea", str(capture), "-o", str(out)]) == 0
    with open(out, "rb") as f:
        messages = [(ch.topic, msg.data) for _schema, ch, msg in make_reader(f).iter_messages()]
    ubx = [bytes.fromhex(json.loads(data)["data"]) for topic, data in messages if topic == "/gps/ubx/raw"]
    assert ubx == reference(capture)[0]
    diag = [json.loads(data) for topic, data in messages if topic == "/diagnostics"][-1]
    dropped = diag["dropped_sentences"]
    kinds = identities(capture)
    assert set(dropped) == set(DROP_REASONS)
    assert dropped["unsupported"] == sum(kinds.get(k, 0) for k in ("GSV", "GSA", "GST", "GBS"))
    assert dropped["duplicate"] == kinds["VTG"]  # VTG beside RMC, one per epoch
    assert diag["bad_sentences"] == dropped["bad_checksum"] + dropped["unparsable"]  # noise between the frames
    assert dropped["status_void"] == dropped["mode_invalid"] == dropped["empty_speed"] == 0
    assert diag["gps_fixes"] == kinds["RMC"] + kinds["NAV-PVT"]


@pytest.mark.parametrize("capture", CAPTURES, ids=lambda p: p.stem)
def test_import_of_ubx_alone_gives_the_nav_pvt_fixes(capture: Path, tmp_path: Path) -> None:
    """A capture of UBX frames only (the frames pyubx2 finds in the receiver's bytes), imported with
    gps.velocity = "ubx": every NAV-PVT is a fix, each record at its own UTC time (a bare capture has no other)."""
    frames, _rmc, pvt = reference(capture)
    ubx_only = tmp_path / "ubx-only.ubx"
    ubx_only.write_bytes(b"".join(frames))
    can = tmp_path / "one.log"
    can.write_text("(1700000000.000000) can0 123#00\n")
    cfg = write_config(tmp_path, CONFIG.read_text().replace('latency_s = "auto"', 'latency_s = "auto"\nvelocity = "ubx"'))
    out = tmp_path / "ubx.mcap"
    assert main(["import", "--config", str(cfg), "--can", str(can), "--nmea", str(ubx_only), "-o", str(out)]) == 0
    with open(out, "rb") as f:
        messages = [(ch.topic, json.loads(msg.data)) for _s, ch, msg in make_reader(f).iter_messages()
                    if ch.topic in ("/gps/fix", "/gps/ubx/raw")]
    fixes = [m for topic, m in messages if topic == "/gps/fix"]
    assert len(fixes) == len(pvt)
    for f, (utc, speed) in zip(fixes, pvt):
        assert f["fix_time_utc_s"] == pytest.approx(utc, abs=1e-6) and f["speed_mps"] == pytest.approx(speed)
    assert all(f["timestamp_s"] == f["fix_time_utc_s"] for f in fixes)
    assert len([m for topic, m in messages if topic == "/gps/ubx/raw"]) == len(frames)
