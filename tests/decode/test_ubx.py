"""u-blox UBX: framing a stream that mixes UBX and NMEA, NAV-PVT decoding, and NAV-PVT as the velocity source."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slipdaq.decode.framing import MAX_FRAME_BYTES, GpsFramer
from slipdaq.decode.ubx import UbxDecoder, ubx_checksum
from slipdaq.pipeline import Pipeline
from slipdaq.records import NmeaLine, UbxFrame
from slipdaq.sim.emit import SimSettings, generate, nav_pvt_frame
from slipdaq.sim.truth import slip_error, truth_series
from slipdaq.sinks import CollectingSink
from support.live_drive import drive_live

SETTINGS = SimSettings(gps_latency_s=0.085, gps_noise_mps=0.03, seed=5)


def _frames(cfg, protocol: str, seconds: float = 3.0):  # type: ignore[no-untyped-def]
    return [e for e in generate(cfg, "accelerate", "paved", replace(SETTINGS, gps_protocol=protocol), seconds)]


def test_framer_splits_mixed_stream_any_chunking(cfg) -> None:  # type: ignore[no-untyped-def]
    records = [e.record for e in _frames(cfg, "both") if isinstance(e.record, (NmeaLine, UbxFrame))]
    stream = b"".join(r.data if isinstance(r, UbxFrame) else (r.line + "\r\n").encode() for r in records)
    rng = np.random.default_rng(0)
    for _ in range(3):
        framer, out, pos = GpsFramer(), [], 0
        while pos < len(stream):
            n = int(rng.integers(1, 150))
            out += framer.feed(stream[pos : pos + n], 0.0)
            pos += n
        assert [type(r) for r in out] == [type(r) for r in records]
        assert [getattr(r, "data", getattr(r, "line", None)) for r in out] == \
            [getattr(r, "data", getattr(r, "line", None)) for r in records]


def test_corrupt_frame_is_skipped_and_counted() -> None:
    good = bytes.fromhex("b5620107") + (4).to_bytes(2, "little") + b"\x01\x02\x03\x04"
    good += ubx_checksum(good[2:])
    bad = bytearray(good)
    bad[7] ^= 0xFF
    framer = GpsFramer()
    out = framer.feed(bytes(bad) + b"$GPTXT\r\n" + good, 1.0)
    assert framer.bad_frames >= 1
    assert any(isinstance(r, UbxFrame) and r.data == good for r in out)
    assert any(isinstance(r, NmeaLine) and r.line.endswith("$GPTXT") for r in out)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.binary(max_size=300), max_size=20))
def test_framer_never_raises_and_stays_bounded(chunks: list[bytes]) -> None:
    framer, decoder = GpsFramer(), UbxDecoder()
    for c in chunks:
        for r in framer.feed(b"\xb5b" + c if len(c) % 3 == 0 else c, 0.0):
            if isinstance(r, UbxFrame):
                decoder.decode(r)
        assert framer.pending_bytes <= MAX_FRAME_BYTES + 300


def test_nav_pvt_decodes_speed_accuracy_and_utc(cfg) -> None:  # type: ignore[no-untyped-def]
    events = _frames(cfg, "ubx", 2.0)
    ubx = [e for e in events if isinstance(e.record, UbxFrame)]
    assert len(ubx) == 20
    dec = UbxDecoder()
    fix = dec.decode(ubx[10].record)
    assert fix is not None and fix.valid and fix.sentence == "NAV-PVT"
    assert fix.speed_accuracy_mps == pytest.approx(0.03)
    assert fix.fix_time_utc_s == pytest.approx(SETTINGS.start_utc_s + 1.0, abs=1e-6)
    assert fix.timestamp_s - fix.fix_time_utc_s == pytest.approx(0.085, abs=1e-6)
    truth = {round(e.time_s, 6): e.truth for e in events if e.truth is not None}
    assert fix.speed_mps == pytest.approx(truth[1.0].speed_mps, abs=4 * 0.03 + 0.001)
    assert dec.decode(UbxFrame(0.0, b"\xb5\x62\x01\x07\x00\x00\x08\x19")) is None  # a NAV-PVT poll: no payload


def test_ubx_velocity_drives_the_estimator(cfg) -> None:  # type: ignore[no-untyped-def]
    ubx_cfg = cfg.with_overrides(gps={"velocity": "ubx"})
    events = list(generate(ubx_cfg, "cycle", "paved", replace(SETTINGS, gps_protocol="both"), 30.0,
                           r0_offset_m=-0.008))
    sink = CollectingSink()
    p = Pipeline(ubx_cfg, [sink])
    p.run([e.record for e in events if e.record is not None])
    assert sink.fixes and all(f.sentence == "NAV-PVT" for f in sink.fixes)  # NMEA decoded but not used
    assert p.nmea.fixes > 0 and p.diagnostics().ubx_frames == 300
    status = p.estimator.status()
    assert status["latency_source"] == "utc" and status["gps_latency_s"] == pytest.approx(0.085, abs=0.005)
    rows = [e.as_row() | {"window_s": e.window_s} for e in sink.estimates]
    truth = truth_series([e.truth for e in events if e.truth is not None], SETTINGS.start_utc_s)
    assert slip_error(rows, truth, only_calibrated=True).rms_points < 0.25


def test_sim_frame_helper_round_trip(cfg) -> None:  # type: ignore[no-untyped-def]
    from slipdaq.sim.vehicle import VehicleSim

    sim = VehicleSim(cfg, "cycle", "paved")
    sim.advance_to(5.0)
    frame = nav_pvt_frame(sim.state, 12.345, SETTINGS)
    fix = UbxDecoder().decode(UbxFrame(0.0, frame))
    assert fix is not None and fix.speed_mps == pytest.approx(12.345)


def test_ubx_frames_logged_raw_and_replayed_identically(cfg, tmp_path) -> None:  # type: ignore[no-untyped-def]
    import os

    from slipdaq.cli import main
    from slipdaq.logformat.reader import iter_estimates, iter_raw_records
    from slipdaq.offline.run import process_to_log

    ubx_cfg = cfg.with_overrides(gps={"velocity": "ubx"})
    records = [e.record for e in generate(ubx_cfg, "cycle", "paved", replace(SETTINGS, gps_protocol="both"), 12.0)
               if e.record is not None]
    log = tmp_path / "ubx.mcap"
    with open(os.devnull, "w") as quiet:
        process_to_log(ubx_cfg, records, log, "import", stream=quiet)
    raw = list(iter_raw_records(log))
    assert [r for r in raw if isinstance(r, UbxFrame)] == [r for r in records if isinstance(r, UbxFrame)]
    out = tmp_path / "replayed.mcap"
    assert main(["replay", str(log), "-o", str(out)]) == 0
    est = list(iter_estimates(log))
    assert len(est) > 50 and list(iter_estimates(out)) == est


def test_live_daemon_reads_ubx_from_a_pty(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """`gps.velocity = "ubx"`: the daemon's serial reader splits UBX frames from NMEA on a real pty."""
    from slipdaq.live.demo import demo_config
    from slipdaq.live.simulate import PtyGps
    from slipdaq.logformat.reader import iter_estimates, iter_raw_records, iter_topic

    gps = PtyGps()
    channel = f"ubx-live-{id(gps)}"
    cfg = demo_config(gps.path, channel).with_overrides(gps={"velocity": "ubx"})
    log = tmp_path / "live.mcap"

    drive_live(cfg, gps, channel, log, "cycle", replace(SETTINGS, gps_protocol="both"), 8.0, 9.0)
    raw = list(iter_raw_records(log))
    ubx = [r for r in raw if isinstance(r, UbxFrame)]
    assert len(ubx) >= 70 and all(UbxDecoder().decode(r) is not None for r in ubx)
    assert sum(isinstance(r, NmeaLine) for r in raw) >= 3 * 70  # the NMEA in between is framed and logged too
    fixes = [d for _, _, d in iter_topic(log, ("/gps/fix",))]
    assert fixes and all(f["sentence"] == "NAV-PVT" and f["speed_accuracy_mps"] == 0.03 for f in fixes)
    assert any(r["slip_FL"] is not None for r in iter_estimates(log))
