"""Decoding: WPT frames by DBC names (wrap, Seq gaps, other IDs), NMEA framing and sentences (bad input counted)."""

from __future__ import annotations

import struct

import cantools
import pytest

from slipdaq.config import load_config
from slipdaq.decode.can_wheels import DbcError, WheelDecoder
from slipdaq.decode.framing import MAX_LINE_BYTES, GpsFramer
from slipdaq.decode.nmea import KNOT_MPS, NmeaDecoder
from slipdaq.records import CanFrame, CanFrameBatch, NmeaLine
from support.paths import ROOT

DBC = (ROOT / "config" / "wpt.dbc").read_text()
CFG = load_config(ROOT / "config" / "slipdaq.toml")


def WptDecoder(dbc: str) -> WheelDecoder:  # noqa: N802  the default sources: WPT_<W>.PulseCount and Seq
    return WheelDecoder(CFG, dbc)


def one(samples):  # type: ignore[no-untyped-def]
    assert len(samples) <= 1
    return samples[0] if samples else None


def frame(t: float, wheel_id: int, count: int, seq: int, dlc: int = 8) -> CanFrame:
    data = struct.pack("<I3xB", count & 0xFFFFFFFF, seq & 0xFF)
    return CanFrame(t, wheel_id, data[:dlc])


def test_dbc_layout_is_the_public_contract() -> None:
    db = cantools.database.load_string(DBC)
    for i, w in enumerate(("FL", "FR", "RL", "RR")):
        m = db.get_message_by_name(f"WPT_{w}")
        assert m.frame_id == 0x310 + i and m.length == 8 and not m.is_extended_frame
        pc, seq = m.get_signal_by_name("PulseCount"), m.get_signal_by_name("Seq")
        assert (pc.start, pc.length, pc.byte_order, pc.is_signed) == (0, 32, "little_endian", False)
        assert (seq.start, seq.length) == (56, 8)
        assert m.decode(m.encode({"PulseCount": 0xDEADBEEF, "Seq": 9})) == {"PulseCount": 0xDEADBEEF, "Seq": 9}


def test_count_wraps_at_2_pow_32() -> None:
    d = WptDecoder(DBC)
    counts = [2**32 - 3, 2**32 - 1, 1, 5]
    samples = [one(d.decode(frame(i * 0.01, 0x310, c, i))) for i, c in enumerate(counts)]
    assert [s.count for s in samples] == [0, 2, 4, 8]  # type: ignore[union-attr]
    assert d.count_wraps["FL"] == 1 and d.lost_frames["FL"] == 0


def test_seq_gaps_are_lost_frames_including_seq_wrap() -> None:
    d = WptDecoder(DBC)
    seqs = [250, 251, 254, 255, 0, 3]  # lost: 2 (252, 253) + 2 (1, 2)
    for i, s in enumerate(seqs):
        d.decode(frame(i * 0.01, 0x311, 1000 * i, s))
    assert d.lost_frames["FR"] == 4
    assert d.frames["FR"] == 6


def test_unknown_id_extended_and_wrong_dlc() -> None:
    d = WptDecoder(DBC)
    assert d.decode(frame(0.0, 0x123, 1, 0)) == []
    assert d.wheel_frames(CanFrameBatch.from_frames([frame(0.0, 0x123, 1, 0)])).tolist() == [-1]
    assert d.decode(CanFrame(0.0, 0x310, bytes(8), is_extended_id=True)) == []
    assert d.decode(frame(0.0, 0x312, 1, 0, dlc=3)) == []
    assert d.bad_frames == 1


def test_another_dbc_with_the_same_names_works() -> None:
    other = DBC.replace("BO_ 784 WPT_FL", "BO_ 1024 WPT_FL").replace("CM_ BO_ 784", "CM_ BO_ 1024").replace(
        "CM_ SG_ 784", "CM_ SG_ 1024")
    d = WptDecoder(other)
    assert d.decode(frame(0.0, 0x310, 7, 0)) == []
    s = one(d.decode(frame(0.0, 1024, 7, 0)))
    assert s is not None and s.wheel == "FL" and s.raw == 7 and s.revolutions == 0.0


def test_dbc_missing_signal_names_it() -> None:
    with pytest.raises(DbcError, match="WPT_RL.Seq"):
        WptDecoder(DBC.replace(' SG_ Seq : 56|8@1+ (1,0) [0|255] "" SLIPDAQ\n\nBO_ 787', '\nBO_ 787'))


def nmea(body: str) -> str:
    cs = 0
    for ch in body:
        cs ^= ord(ch)
    return f"${body}*{cs:02X}"


RMC = nmea("GPRMC,120000.00,A,5200.00000,N,01000.00000,E,20.000,90.0,010126,,,A")
GGA = nmea("GPGGA,120000.00,5200.00000,N,01000.00000,E,1,12,0.8,100.0,M,0.0,M,,")
VTG = nmea("GPVTG,90.0,T,,M,20.000,N,37.040,K,A")


def test_rmc_speed_time_and_gga_fields() -> None:
    d = NmeaDecoder()
    assert d.decode(NmeaLine(1.0, GGA)) is None
    fix = d.decode(NmeaLine(1.1, RMC))
    assert fix is not None
    assert fix.speed_mps == pytest.approx(20.0 * 1852 / 3600)
    assert fix.fix_time_utc_s == pytest.approx(1767268800.0)  # 2026-01-01T12:00:00Z
    assert fix.satellites == 12 and fix.fix_quality == 1 and fix.altitude_m == 100.0
    assert fix.latitude_deg == pytest.approx(52.0) and fix.longitude_deg == pytest.approx(10.0)


def test_vtg_not_double_counted_but_used_alone() -> None:
    d = NmeaDecoder()
    fixes = [d.decode(NmeaLine(t, s)) for t, s in [(0.0, RMC), (0.0, VTG), (0.1, RMC), (0.1, VTG)]]
    assert sum(f is not None for f in fixes) == 2 and all(f.sentence == "RMC" for f in fixes if f)
    vtg_only = NmeaDecoder()
    fx = vtg_only.decode(NmeaLine(0.0, VTG))
    assert fx is not None and fx.sentence == "VTG" and fx.speed_mps == pytest.approx(37.04 / 3.6)


@pytest.mark.parametrize(
    "line",
    [
        RMC[:-2] + "00",  # bad checksum
        RMC[:30],  # truncated
        "\x00\xff\x13garbage",  # noise
        "$GPRMC,not,a,sentence*00",
    ],
)
def test_bad_sentences_counted_not_raised(line: str) -> None:
    d = NmeaDecoder()
    assert d.decode(NmeaLine(0.0, line)) is None
    assert d.bad_sentences == 1 and d.fixes == 0


def test_invalid_rmc_status_marks_fix_invalid() -> None:
    d = NmeaDecoder()
    fix = d.decode(NmeaLine(0.0, nmea("GPRMC,120000.00,V,,,,,0.0,,010126,,,N")))
    assert fix is not None and not fix.valid


def test_framer_splits_across_reads_and_cuts_overlong() -> None:
    f = GpsFramer()
    data = (RMC + "\r\n" + GGA + "\r\n").encode()
    out = f.feed(data[:17], 1.0) + f.feed(data[17:90], 2.0) + f.feed(data[90:], 3.0)
    assert [x.line for x in out] == [RMC, GGA]
    assert out[0].timestamp_s == 2.0  # a line takes the time its end arrived
    long = f.feed(b"$" + b"A" * (MAX_LINE_BYTES + 50), 4.0)
    assert f.overlong_lines == 1 and len(long) == 1 and len(long[0].line) == MAX_LINE_BYTES
    assert [x.line for x in f.feed(("\r\n" + RMC + "\r\n").encode(), 5.0)] == [RMC]


def test_knots() -> None:
    assert KNOT_MPS == pytest.approx(0.514444, abs=1e-6)
