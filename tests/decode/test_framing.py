"""The one framing rule for a GPS receiver's bytes (decode/framing.py): UBX frames and NMEA lines, a line cut before
every `$`, `!` and UBX sync as well as at LF; the same records however the bytes are split into reads."""

from __future__ import annotations

from pathlib import Path

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pyubx2 import UBXReader

from slipdaq.decode.framing import MAX_FRAME_BYTES, MAX_LINE_BYTES, GpsFramer, crc24q
from slipdaq.decode.nmea import NmeaDecoder
from slipdaq.decode.ubx import ubx_checksum
from slipdaq.records import NmeaLine, RtcmFrame, UbxFrame


def sentence(start: str, body: str) -> str:
    cs = 0
    for ch in body:
        cs ^= ord(ch)
    return f"{start}{body}*{cs:02X}"


RMC = sentence("$", "GNRMC,120000.00,A,5200.00000,N,01000.00000,E,20.000,90.0,010126,,,A,V")
GGA = sentence("$", "GNGGA,120000.00,5200.00000,N,01000.00000,E,1,12,0.6,100.0,M,45.0,M,,")
AIVDM = sentence("!", "AIVDM,1,1,,A,13u?etPv2;0n:dDPwUM1U1Cb069D,0")
RTCM_1006 = bytes.fromhex("d300153ee029030a69d8280301669a14088a75c3f8270316c7f7d9")
"""An RTCM 3 message 1006 (station position) from the ZED-F9R capture: binary, with a 0x0A (LF) byte in it."""


def ubx(cls: int, msg_id: int, payload: bytes) -> bytes:
    body = bytes((cls, msg_id)) + len(payload).to_bytes(2, "little") + payload
    return b"\xb5\x62" + body + ubx_checksum(body)


def content(records: list[NmeaLine | UbxFrame]) -> list[str | bytes]:
    return [r.line if isinstance(r, NmeaLine) else r.data for r in records]


def frame_all(data: bytes, step: int | None = None) -> list[NmeaLine | UbxFrame]:
    framer = GpsFramer()
    if step is None:
        return framer.feed(data, 0.0) + framer.flush()
    return [r for i in range(0, len(data), step) for r in framer.feed(data[i : i + step], 0.0)] + framer.flush()


def test_sentence_right_after_binary_bytes_is_kept() -> None:
    nav_sig = ubx(0x01, 0x43, bytes(range(256)) * 4 + bytes(232))  # 1,264 bytes, as the ZED-F9R's largest NAV-SIG
    noise = bytes(b for b in range(256) if b not in b"\n$!\xb5\xd3") * 2  # 502 bytes of binary with no delimiter
    stream = (nav_sig + RMC.encode() + b"\r\n" + RTCM_1006 + GGA.encode() + b"\r\n"
              + noise + RMC.encode() + b"\r\n")
    for step in (None, 1, 7, 100):
        records = frame_all(stream, step)
        assert content(records) == [nav_sig, RMC, RTCM_1006, GGA, noise[:MAX_LINE_BYTES].decode("latin-1"), RMC]
        assert isinstance(records[2], RtcmFrame)
    assert UBXReader.parse(records[0].data).identity == "NAV-SIG"  # type: ignore[union-attr]
    decoder = NmeaDecoder()
    fixes = [f for r in records if isinstance(r, NmeaLine) and (f := decoder.decode(r)) is not None]
    assert len(fixes) == 2 and all(f.valid for f in fixes)


def test_a_line_is_cut_before_each_start_delimiter() -> None:
    records = frame_all(b"r" + RMC.encode() + GGA.encode() + AIVDM.encode() + b"\r\n")
    assert content(records) == ["r", RMC, GGA, AIVDM]


def test_a_record_takes_the_time_its_last_byte_came() -> None:
    framer = GpsFramer()
    frame = ubx(0x01, 0x07, bytes(92))
    assert framer.feed(RMC.encode(), 1.0) == []  # its end is not known yet
    out = framer.feed(b"\r\n" + GGA.encode(), 2.0)  # the LF ends the RMC
    assert [(r.timestamp_s, r.line) for r in out] == [(2.0, RMC)]  # type: ignore[union-attr]
    out = framer.feed(frame[:50], 3.0) + framer.feed(frame[50:] + b"\xb5", 4.0) + framer.feed(b"\x62", 5.0)
    assert [(type(r), r.timestamp_s) for r in out] == [(NmeaLine, 2.0), (UbxFrame, 4.0)]  # the GGA ended by the frame
    assert framer.pending_bytes == 2


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(
        st.one_of(
            st.binary(max_size=300),
            st.sampled_from([RMC.encode(), GGA.encode(), b"\r\n", b"\n", b"$", b"!", b"\xb5", b"\xb5\x62", RTCM_1006,
                             ubx(0x01, 0x07, bytes(92)), ubx(0x01, 0x43, bytes(1200)), b"\xb5\x62\x01\x07\x5c\x00"]),
        ),
        max_size=30,
    ),
    st.lists(st.integers(min_value=0, max_value=4000), max_size=20),
)
def test_records_do_not_depend_on_reads(parts: list[bytes], cuts: list[int]) -> None:
    data = b"".join(parts)
    whole = frame_all(data)
    bounds = sorted({0, len(data), *(c for c in cuts if c <= len(data))})
    framer, split = GpsFramer(), []
    for a, b in zip(bounds, bounds[1:]):
        split += framer.feed(data[a:b], float(a))
        assert framer.pending_bytes <= MAX_FRAME_BYTES
    split += framer.flush()
    assert content(split) == content(whole)
    for r in split:
        if isinstance(r, NmeaLine):
            assert len(r.line) <= MAX_LINE_BYTES and "\n" not in r.line
        elif isinstance(r, RtcmFrame):
            assert r.data[0] == 0xD3 and crc24q(r.data[:-3]) == r.data[-3:]
        else:
            assert r.data[:2] == b"\xb5\x62" and ubx_checksum(r.data[2:-2]) == r.data[-2:]


def test_rtcm3_frames_of_a_real_capture_are_records_equal_to_pyrtcm_s() -> None:
    """The ZED-F9R capture (gpsd's, UBX + RTCM 3 + NMEA): every RTCM 3 frame in it is one RtcmFrame, whose CRC-24Q
    pyrtcm checks and whose message pyrtcm parses; no RTCM bytes end up in NMEA lines."""
    from pyrtcm import RTCMReader
    from pyrtcm.rtcmhelpers import calc_crc24q

    data = (Path(__file__).parents[1] / "data" / "gpsd-ubx-mixed" / "ublox-zed-f9r.log").read_bytes()
    records = frame_all(data, 97)
    rtcm = [r for r in records if isinstance(r, RtcmFrame)]
    assert len(rtcm) >= 10
    for r in rtcm:
        assert calc_crc24q(r.data) == 0
        assert RTCMReader.parse(r.data).identity.isdigit()
    assert not any(isinstance(r, NmeaLine) and "\xd3" in r.line for r in records)
    assert crc24q(RTCM_1006[:-3]) == RTCM_1006[-3:]


def test_rtcm3_frames_are_logged_on_their_topic_and_read_back(tmp_path: Path) -> None:
    """The receiver's RTCM 3 frames go to /gps/rtcm/raw as they came (not counted as bad sentences) and come back as
    raw records in their place."""
    from conftest import CONFIG
    from slipdaq.config import load_config
    from slipdaq.logformat.reader import iter_raw_records, iter_topic
    from slipdaq.pipeline import Pipeline
    from slipdaq.sinks.mcap_log import McapLogSink

    data = (Path(__file__).parents[1] / "data" / "gpsd-ubx-mixed" / "ublox-zed-f9r.log").read_bytes()
    records = frame_all(data)
    cfg = load_config(CONFIG)
    sink = McapLogSink(tmp_path / "gps.mcap", cfg, "import")
    pipeline = Pipeline(cfg, [sink])
    for k, r in enumerate(records):
        pipeline.process(type(r)(1_767_225_600.0 + 0.001 * k, r.line if isinstance(r, NmeaLine) else r.data))
    pipeline.finish()
    sink.close()
    logged = [bytes.fromhex(d["data"]) for _t, _t2, d in iter_topic(tmp_path / "gps.mcap", ("/gps/rtcm/raw",))]
    assert logged == [r.data for r in records if isinstance(r, RtcmFrame)] and logged
    back = [r for r in iter_raw_records(tmp_path / "gps.mcap") if isinstance(r, RtcmFrame)]
    assert [r.data for r in back] == logged
    assert pipeline.nmea.bad_sentences == 0
