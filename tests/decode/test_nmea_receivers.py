"""NMEA as receivers send it: gpsd's twelve regression captures played gpsfake-style through a real pseudo-terminal
into SerialGpsSource, decoded with NmeaDecoder and checked against gpsd's own output (.chk); the decoder's rules on
small hand-made streams; and property tests (any bytes: no exception, bounded buffer, framing independent of reads).

The captures (tests/data/gpsd-nmea, see tests/data/README.md) are played like gpsfake does: bytes written to the master
side of a pty in chunks of 1 to 200 bytes (seeded), the reader on the slave path as in a live run.
"""

from __future__ import annotations

import asyncio
import calendar
import re
import zlib
from dataclasses import dataclass
from pathlib import Path

import pynmea2
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from slipdaq.cli import main
from slipdaq.decode.framing import MAX_FRAME_BYTES, MAX_LINE_BYTES, GpsFramer
from slipdaq.decode.nmea import DROP_REASONS, KNOT_MPS, NmeaDecoder
from slipdaq.records import GpsFix, NmeaLine
from support.gpsd_captures import STALL_S, ms, play_through_pty, tpv_speeds
from support.paths import DATA

CAPTURES = DATA / "gpsd-nmea"

SPEED_TOL_MPS = 0.001

GPS_ROLLOVER_S = 1024 * 7 * 86400


@dataclass(frozen=True)
class Expect:
    lines: int
    """Lines the framer makes of the file (comments included)."""
    valid_rmc: int
    """RMC sentences with a good checksum, status A and a speed."""
    unmatched: int = 0
    """Valid RMC epochs for which gpsd printed no TPV at all (see below)."""
    shift_s: float = 0.0
    """gpsd's TPV time minus the RMC's own time."""


# unmatched: gpsd printed no TPV with that time. bt451 (2) and ublox-lea-4h (1): the last RMC of a recorded section
# (before a `#` section break or at the end of the file). haicom-305N (1): 09:53:04.802, whose TPV gpsd never printed
# (its next TPV already carries the next GGA's time).
# rst39: the RMC says 2014-02-19 (as its ZDA does, and the capture was submitted in 2015); gpsd's TPVs say 2033-10-05,
# exactly 1024 GPS weeks later: gpsd's week-rollover guess moved the receiver's date. So RMC and TPV times do not line
# up as absolute times (tests/data/README.md); shifted by 1024 weeks they do, and that is what is asserted for rst39:
# every RMC decoded with the date it sends, its speed equal to gpsd's at the shifted time.
EXPECTED = {
    "bt451": Expect(156, 13, unmatched=2),
    "garmin15x": Expect(66, 7),
    "haicom-305N": Expect(335, 68, unmatched=1),
    "nl2008u": Expect(145, 9),
    "nmea-rtk": Expect(253, 122),
    "quectel-eg25-g": Expect(870, 23),
    "quectel-l76k-nmea": Expect(2296, 150),
    "rst39": Expect(158, 4, shift_s=GPS_ROLLOVER_S),
    "sirfstarv-nmea": Expect(377, 59),
    "sl869": Expect(177, 8),
    "tomtom-mkII": Expect(72, 4),
    "ublox-lea-4h": Expect(118, 9, unmatched=1),
}


def nmea(body: str) -> str:
    cs = 0
    for ch in body:
        cs ^= ord(ch)
    return f"${body}*{cs:02X}"


_RMC_RE = re.compile(r"\$(?P<body>[A-Z]{2}RMC,[^*$]*)\*(?P<cs>[0-9A-Fa-f]{2})\s*$")


def oracle_rmc(lines: list[str]) -> tuple[int, int]:
    """RMC sentences in the lines, counted without the decoder: (valid: checksum good, status A, a speed, a mode of a
    GNSS fix if it has one, navigational status not U; void: checksum good, status not A)."""
    valid = void = 0
    for text in lines:
        m = _RMC_RE.search(text)
        if m is None:
            continue
        cs = 0
        for ch in m["body"]:
            cs ^= ord(ch)
        if cs != int(m["cs"], 16):
            continue
        f = m["body"].split(",")
        void += f[2] != "A"
        valid += f[2] == "A" and f[7] != "" and (len(f) < 13 or f[12] in "ADFPR" and f[12] != "") \
            and (len(f) < 14 or f[13] != "U")
    return valid, void


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_capture_through_pty_matches_gpsd(name: str) -> None:
    exp = EXPECTED[name]
    data = (CAPTURES / f"{name}.log").read_bytes()
    direct = [x.line for x in GpsFramer().feed(data, 0.0)]
    assert len(direct) == exp.lines

    played = asyncio.run(play_through_pty(data, len(direct), zlib.crc32(name.encode())))

    # the reader: no stall (asserted while playing), every line delivered as a direct framing makes it
    assert played.reconnects == 0 and played.last_error is None
    assert [x.line for x in played.records] == direct
    d, fixes = NmeaDecoder(), []
    for line in played.records:
        fix = d.decode(line)  # type: ignore[arg-type]
        if fix is not None:
            fixes.append(fix)
    assert d.lines == exp.lines == d.ignored_lines + d.bad_sentences + d.sentences
    assert d.fixes == len(fixes)

    # one fix per epoch; every valid RMC decoded
    times = [f.fix_time_utc_s for f in fixes if f.fix_time_utc_s is not None]
    assert len(times) == len(set(times)), "an epoch gave two fixes"
    rmc = [f for f in fixes if f.sentence == "RMC" and f.valid]
    valid, void = oracle_rmc(direct)
    assert len(rmc) == valid == exp.valid_rmc
    assert d.dropped["status_void"] == void  # every RMC without a fix counted, none more
    assert all(f.fix_time_utc_s is not None for f in rmc)

    # speed and UTC time equal gpsd's TPV at that time
    tpv = tpv_speeds(CAPTURES / f"{name}.log.chk")
    matched = 0
    for f in rmc:
        want = tpv.get(ms(f.fix_time_utc_s + exp.shift_s))  # type: ignore[operator]
        if want is None:
            continue
        matched += 1
        assert abs(f.speed_mps - want) <= SPEED_TOL_MPS, (name, f)
    assert matched == exp.valid_rmc - exp.unmatched
    if exp.shift_s:  # rst39: without gpsd's 1024-week shift no RMC time is a TPV time
        assert not any(ms(f.fix_time_utc_s) in tpv for f in rmc)  # type: ignore[arg-type]
    assert played.seconds < STALL_S


# ---- the decoder's rules, on small streams ----

RMC_T = "GPRMC,120000.00,A,5200.00000,N,01000.00000,E,20.000,90.0,010126,,,A"


def decode_all(lines: list[str], t0: float = 0.0, dt_s: float = 0.0) -> tuple[NmeaDecoder, list[GpsFix]]:
    d = NmeaDecoder()
    fixes = [f for i, s in enumerate(lines) if (f := d.decode(NmeaLine(t0 + i * dt_s, s))) is not None]
    assert d.lines == d.ignored_lines + d.bad_sentences + d.sentences
    return d, fixes


@pytest.mark.parametrize("talker", ["GP", "GN", "GL", "GA", "BD", "GB", "QZ", "GI"])
def test_every_talker(talker: str) -> None:
    _, fixes = decode_all([nmea(talker + RMC_T[2:])])
    assert len(fixes) == 1 and fixes[0].valid and fixes[0].speed_mps == pytest.approx(20 * KNOT_MPS)


def test_two_talkers_one_epoch_one_fix() -> None:
    lines = [
        nmea("GNRMC,120000.00,A,5200.0,N,01000.0,E,20.0,90.0,010126,,,A,V"),
        nmea("GPRMC,120000.00,A,5200.0,N,01000.0,E,20.1,90.0,010126,,,A,V"),
        nmea("GNRMC,120000.10,A,5200.0,N,01000.0,E,20.0,90.0,010126,,,A,V"),
        nmea("GPRMC,120000.10,A,5200.0,N,01000.0,E,20.1,90.0,010126,,,A,V"),
    ]
    d, fixes = decode_all(lines)
    assert [f.speed_mps for f in fixes] == [20 * KNOT_MPS] * 2  # the first talker's, once per epoch
    assert d.duplicate_sentences == 2


def test_vtg_before_rmc_in_an_epoch_is_not_counted_twice() -> None:
    # Quectel EG25-G order: GNS, VTG, GGA, RMC; the receiver has sent RMC before, so VTG is not used
    epoch = [
        "GNGNS,191500.00,4500.0,N,03000.0,E,AAN,10,0.8,10.0,30.0,,",
        "GPVTG,90.0,T,,M,20.000,N,37.040,K,A",
        "GPGGA,191500.00,4500.0,N,03000.0,E,1,10,0.8,10.0,M,30.0,M,,",
        "GPRMC,191500.00,A,4500.0,N,03000.0,E,20.000,90.0,110922,,,A,V",
    ]
    two = [nmea(s) for s in epoch] + [nmea(s.replace("191500", "191501")) for s in epoch]
    d, fixes = decode_all(two, dt_s=0.1)
    # the first epoch's VTG came before any RMC: it gives that epoch's fix and the RMC is the duplicate
    assert [f.sentence for f in fixes] == ["VTG", "RMC"] and d.bad_sentences == 0 and d.duplicate_sentences == 2
    assert fixes[1].fix_quality == 1 and fixes[1].satellites == 10


def test_vtg_alone_and_with_gga() -> None:
    vtg = nmea("GPVTG,90.0,T,,M,10.000,N,18.520,K,A")
    d, fixes = decode_all([vtg, vtg, vtg], dt_s=1.0)
    assert len(fixes) == 3 and all(f.sentence == "VTG" and f.fix_time_utc_s is None for f in fixes)
    gn = nmea("GNVTG,90.0,T,,M,10.000,N,18.520,K,A")
    gga = "GPGGA,120001.00,5200.0,N,01000.0,E,1,09,0.8,100.0,M,0.0,M,,"
    d, fixes = decode_all([nmea(gga), vtg, gn, nmea(gga.replace("120001", "120002")), vtg, gn], dt_s=0.3)
    assert len(fixes) == 2 and d.duplicate_sentences == 2 and d.bad_sentences == 0  # GNVTG beside GPVTG: one fix


def test_nmea41_nav_status_and_mode_indicators() -> None:
    def valid(tail: str) -> bool:
        _, fixes = decode_all([nmea("GNRMC,120000.00,A,5200.0,N,01000.0,E,1.0,90.0,010126,," + tail)])
        return fixes[0].valid

    assert valid(",A,V")  # NMEA 4.1 nav status V = "not provided" (u-blox, L76K send it always)
    assert valid(",D,S") and valid(",A") and valid("") and valid(",R,C")
    assert not valid(",N,V")  # no fix
    assert not valid(",E,V")  # dead reckoning
    _, fixes = decode_all([nmea("GPRMC,120000.00,V,5200.0,N,01000.0,E,1.0,90.0,010126,,,A")])
    assert not fixes[0].valid
    _, fixes = decode_all([nmea("GPVTG,90.0,T,,M,1.0,N,1.852,K,N")])
    assert not fixes[0].valid


def test_gga_quality_zero_invalidates_its_epoch_only() -> None:
    gga0 = nmea("GPGGA,120000.00,5200.0,N,01000.0,E,0,03,9.9,100.0,M,0.0,M,,")
    rmc = nmea(RMC_T)
    _, fixes = decode_all([gga0, rmc])  # GGA first, same time: quality 0 -> invalid
    assert fixes[0].fix_quality == 0 and not fixes[0].valid
    # RMC-first receivers (u-blox): the GGA comes after; the previous epoch's quality 0 does not invalidate the next fix
    rmc2 = nmea(RMC_T.replace("120000.00", "120001.00"))
    _, fixes = decode_all([rmc, gga0, rmc2], dt_s=0.5)
    assert fixes[0].fix_quality is None and fixes[0].valid
    assert fixes[1].fix_quality == 0 and fixes[1].satellites == 3 and fixes[1].valid
    gga6 = nmea("GPGGA,120000.00,5200.0,N,01000.0,E,6,03,9.9,100.0,M,0.0,M,,")
    _, fixes = decode_all([gga6, rmc])
    assert not fixes[0].valid  # 6 = estimated


def test_two_gga_talkers_first_used() -> None:
    # SiRFstarV: GPGGA (GPS satellites) and GLGGA (GLONASS) for one epoch, then GNRMC
    lines = [
        nmea("GPGGA,020935.000,4404.1351,N,12118.8556,W,1,08,0.9,1123.9,M,-19.6,M,,0000"),
        nmea("GLGGA,020935.000,4404.1351,N,12118.8556,W,1,02,0.9,1123.9,M,-19.6,M,,0000"),
        nmea("GNRMC,020935.000,A,4404.1351,N,12118.8556,W,0.04,359.11,050219,,,A"),
    ]
    d, fixes = decode_all(lines)
    assert fixes[0].satellites == 8 and d.duplicate_sentences == 1


def test_rmc_without_date() -> None:
    nodate = [nmea("GPRMC,235959.00,A,5200.0,N,01000.0,E,1.0,90.0,,,,A")]
    _, fixes = decode_all(nodate)
    assert fixes[0].fix_time_utc_s is None  # no date known: the time of day alone is not a UTC time
    zda = nmea("GPZDA,235958.00,31,12,2025,00,00")
    after_midnight = nmea("GPRMC,000001.00,A,5200.0,N,01000.0,E,1.0,90.0,,,,A")
    _, fixes = decode_all([zda, *nodate, after_midnight], dt_s=1.0)
    assert fixes[0].fix_time_utc_s == calendar.timegm((2025, 12, 31, 23, 59, 59))
    assert fixes[1].fix_time_utc_s == calendar.timegm((2026, 1, 1, 0, 0, 1))
    dated = nmea("GPRMC,120000.00,A,5200.0,N,01000.0,E,1.0,90.0,150326,,,A")
    _, fixes = decode_all([dated, nmea("GPRMC,120001.50,A,5200.0,N,01000.0,E,1.0,90.0,,,,A")], dt_s=1.0)
    assert fixes[1].fix_time_utc_s == calendar.timegm((2026, 3, 15, 12, 0, 1)) + 0.5


def test_lines_counted_by_kind() -> None:
    lines = [
        "# a comment \x00\xff binary in it",
        "",
        "\x00\xff\x13\x7f garbage",
        nmea(RMC_T)[:-2] + f"{int(nmea(RMC_T)[-2:], 16) ^ 1:02X}",  # checksum wrong
        nmea(RMC_T)[:40],  # cut
        "$GPTXT,TELIT SW Version: SL869",  # no checksum
        "r" + nmea(RMC_T),  # noise before a good sentence (tomtom-mkII has one)
        nmea("GPGSV,1,1,00"),
        nmea("PGRME,7.6,M,41.7,M,42.4,M"),
        nmea("GPXYZ,1,2,3"),  # a type pynmea2 does not know
        nmea("GPHDT,25.50,T"),
    ]
    d, fixes = decode_all(lines)
    assert (d.ignored_lines, d.comment_lines, d.bad_sentences, d.sentences) == (2, 1, 4, 5)
    assert {k: v for k, v in d.dropped.items() if v} == {"unparsable": 1, "bad_checksum": 3, "unsupported": 4}
    assert (d.resynced_lines, d.unused_sentences, d.fixes, len(fixes)) == (1, 4, 1, 1)


# ---- validity and what is dropped, against pynmea2's own RMC validity cases ----

# pynmea2's test_types.py test_RMC_valid: 39 RMC sentences, all without a speed, in its order (status, mode indicator,
# navigational status; None = the sentence does not have that field), with pynmea2's verdict (is_valid) and
# slipdaq's reason to drop it. Then cases pynmea2 does not have. With a speed the same sentences give a fix whose
# `valid` is True exactly when the only reason was the missing speed.
_A, _V, _X = "A", "V", ""
_PYNMEA2_RMC = [
    # status, mode, nav, pynmea2 is_valid, slipdaq's reason without a speed
    (_A, None, None, True, "empty_speed"),  # status A and no mode: valid, but no speed, so no fix
    (_V, None, None, False, "status_void"),
    (_X, None, None, False, "status_void"),
    (_A, "S", None, True, "mode_invalid"),  # S = the receiver's simulator, not a measurement (pynmea2: valid)
    (_A, "N", None, False, "mode_invalid"),
    (_A, "", None, False, "mode_invalid"),  # the field sent empty: no fix mode stated (pynmea2: invalid; gpsd: ignored)
    *[(st, m, None, False, "status_void") for st in (_V, _X) for m in ("S", "N", "")],
    *[(st, m, nav, st == _A and m == "S" and nav == "S", "status_void" if st != _A else "mode_invalid")
      for st in (_A, _V, _X) for m, nav in (("S", "S"), ("S", "V"), ("S", ""), ("N", "A"), ("N", "V"), ("N", ""),
                                            ("", "A"), ("", "V"), ("", ""))],
]
_MORE_RMC = [
    (_A, "A", "V", False, "empty_speed"),  # nav status V = not provided (every u-blox, Quectel): valid (pynmea2: not)
    (_A, "D", "C", True, "empty_speed"),  # caution: still valid
    (_A, "R", "S", True, "empty_speed"),
    (_A, "F", "", False, "empty_speed"),  # nav status sent empty: not provided (pynmea2: invalid)
    (_A, "A", "U", True, "nav_status_unsafe"),  # unsafe: invalid (pynmea2: valid)
    (_A, "E", "V", False, "mode_invalid"),  # dead reckoning (pynmea2: valid, without the V)
    (_A, "M", None, True, "mode_invalid"),  # manual input (pynmea2: valid)
    (_V, "A", "V", False, "status_void"),
]


def _rmc(status: str, mode: str | None, nav: str | None, speed: str = "") -> str:
    fields = ["GPRMC", "123519.00", status, "4807.038", "N", "01131.000", "E", speed, "84.4" if speed else "",
              "230394", "", ""]
    fields += [mode] if mode is not None else []
    fields += [nav] if nav is not None else []
    return nmea(",".join(fields))


def test_pynmea2_rmc_cases_are_its_own() -> None:
    assert len(_PYNMEA2_RMC) == 39
    assert [i for i, case in enumerate(_PYNMEA2_RMC) if case[3]] == [0, 3, 12]  # "only the first of each section"
    assert _rmc(*_PYNMEA2_RMC[0][:3]) == "$GPRMC,123519.00,A,4807.038,N,01131.000,E,,,230394,,*33"  # as in its file
    assert _rmc(*_PYNMEA2_RMC[-1][:3]) == "$GPRMC,123519.00,,4807.038,N,01131.000,E,,,230394,,,,*72"
    for status, mode, nav, pynmea2_valid, _reason in _PYNMEA2_RMC + _MORE_RMC:
        assert pynmea2.parse(_rmc(status, mode, nav), check=True).is_valid == pynmea2_valid


@pytest.mark.parametrize("case", _PYNMEA2_RMC + _MORE_RMC, ids=lambda c: f"{c[0] or '-'}{c[1] or '-'}{c[2] or '-'}")
def test_rmc_validity_decisions_and_drop_reasons(case: tuple[str, str | None, str | None, bool, str]) -> None:
    status, mode, nav, _pynmea2_valid, reason = case
    d, fixes = decode_all([_rmc(status, mode, nav)])
    assert fixes == [] and d.fixes == 0
    assert {k: v for k, v in d.dropped.items() if v} == {reason: 1}  # no speed: no fix, and counted
    d, fixes = decode_all([_rmc(status, mode, nav, speed="22.4")])
    assert len(fixes) == 1 and fixes[0].speed_mps == pytest.approx(22.4 * KNOT_MPS)
    assert fixes[0].valid == (reason == "empty_speed")  # a fix the estimator takes exactly when only the speed lacked
    assert {k: v for k, v in d.dropped.items() if v} == ({} if fixes[0].valid else {reason: 1})


def test_import_without_a_fix_says_why(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """pynmea2's 39 cases as an NMEA log: `import` has no fix to use, exit 1, and its line gives the reasons."""
    nmea_log = tmp_path / "pynmea2-rmc.nmea"
    nmea_log.write_text("".join(f"(1700000000.{i:02d}) {_rmc(*case[:3])}\n" for i, case in enumerate(_PYNMEA2_RMC)))
    can = tmp_path / "one.log"
    can.write_text("(1700000000.000000) can0 123#00\n")
    assert main(["import", "--can", str(can), "--nmea", str(nmea_log), "-o", str(tmp_path / "out.mcap")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"slipdaq: {nmea_log}: no usable NMEA: 0 fixes from 39 lines (0 bad sentences; dropped: "
                   "status_void 26, mode_invalid 12, empty_speed 1) (--allow-empty accepts it)"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["one.log", "pynmea2-rmc.nmea"]


@pytest.mark.parametrize(
    ("vtg", "valid", "reason"),
    [
        ("GPVTG,84.4,T,,M,22.4,N,41.5,K", True, None),  # NMEA 2.2: no mode field
        ("GPVTG,84.4,T,,M,22.4,N,41.5,K,D", True, None),
        ("GPVTG,84.4,T,,M,22.4,N,41.5,K,", False, "mode_invalid"),
        ("GPVTG,84.4,T,,M,22.4,N,41.5,K,S", False, "mode_invalid"),
        ("GPVTG,,T,,M,,N,,K,N", None, "mode_invalid"),  # a receiver without a fix
        ("GPVTG,,T,,M,,N,,K,A", None, "empty_speed"),
    ],
)
def test_vtg_validity_and_drop_reasons(vtg: str, valid: bool | None, reason: str | None) -> None:
    d, fixes = decode_all([nmea(vtg)])
    assert [f.valid for f in fixes] == ([] if valid is None else [valid])
    assert {k: v for k, v in d.dropped.items() if v} == ({} if reason is None else {reason: 1})


def test_every_dropped_line_is_counted_once_with_its_reason() -> None:
    gga0 = nmea("GPGGA,120000.00,5200.0,N,01000.0,E,0,03,9.9,100.0,M,0.0,M,,")
    rmc = nmea(RMC_T)
    lines = [
        "# a comment",  # ignored, not dropped
        "",
        "\x00\xff\x13\x7f garbage",  # unparsable
        "$GPRMC,1,2*00",  # bad_checksum: wrong
        "$GPTXT,TELIT SW Version: SL869",  # bad_checksum: missing
        nmea("GPGSV,1,1,00"),  # unsupported
        gga0,  # used: this epoch's GGA
        rmc,  # gga_invalid: its epoch's GGA, first, says quality 0 (a fix, valid=False)
        nmea(RMC_T.replace("GPRMC", "GNRMC")),  # duplicate: the epoch has its fix
        nmea("GPRMC,120001.00,A,5200.0,N,01000.0,E,,90.0,010126,,,A"),  # empty_speed
        nmea("GPRMC,120002.00,V,,,,,,,010126,,,N"),  # status_void
        nmea("GPRMC,120003.00,A,5200.0,N,01000.0,E,20.0,90.0,010126,,,A,V"),  # a valid fix
    ]
    d, fixes = decode_all(lines, dt_s=0.1)
    assert [f.valid for f in fixes] == [False, True]
    assert d.dropped == dict.fromkeys(DROP_REASONS, 0) | {
        "unparsable": 1, "bad_checksum": 2, "unsupported": 1, "gga_invalid": 1, "duplicate": 1, "empty_speed": 1,
        "status_void": 1,
    }
    assert d.bad_sentences == d.dropped["bad_checksum"] + d.dropped["unparsable"] == 3
    assert (d.unused_sentences, d.duplicate_sentences) == (d.dropped["unsupported"], d.dropped["duplicate"]) == (1, 1)
    # every line: ignored, dropped for one reason, or used (the GGA, the valid fix)
    assert d.lines == d.ignored_lines + sum(d.dropped.values()) + 2


def test_framer_cuts_overlong_lines_the_same_however_read() -> None:
    data = b"$" + b"A" * 300 + b"\r\n" + nmea(RMC_T).encode() + b"\r\n"
    whole = GpsFramer()
    one = [x.line for x in whole.feed(data, 0.0)]
    split = GpsFramer()
    two = [x.line for i in range(0, len(data), 7) for x in split.feed(data[i : i + 7], 0.0)]
    assert one == two == ["$" + "A" * (MAX_LINE_BYTES - 1), nmea(RMC_T)]
    assert whole.overlong_lines == split.overlong_lines == 1


# ---- properties: whatever comes, nothing raises and nothing grows ----

FAST = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@FAST
@given(st.lists(st.binary(max_size=600), max_size=30))
def test_any_bytes_never_raise_and_buffer_stays_bounded(chunks: list[bytes]) -> None:
    framer, decoder = GpsFramer(), NmeaDecoder()
    for i, chunk in enumerate(chunks):
        for line in framer.feed(chunk, float(i)):
            if isinstance(line, NmeaLine):
                assert len(line.line) <= MAX_LINE_BYTES and "\n" not in line.line
                decoder.decode(line)
        assert framer.pending_bytes <= MAX_FRAME_BYTES
    assert decoder.lines == decoder.ignored_lines + decoder.bad_sentences + decoder.sentences


_FIELD = st.text(alphabet=st.characters(min_codepoint=0, max_codepoint=255, exclude_characters="*$\r\n"), max_size=14)
_NUMERIC = st.one_of(
    st.sampled_from(["", "A", "V", "N", "E", "D", "0", "-1", "nan", "inf", "1e400", "99", "235960", "310299"]),
    st.sampled_from(["9999.99", "-0.0", "1_0", "0x1F", " 1.5 "]),
    st.sampled_from(["120000.00", "235959.999", "000000", "010126", "290224", "300224", "2026", "12", "4807.038", "W"]),
    st.floats(allow_nan=True, allow_infinity=True).map(str),
    st.integers(min_value=-(10**9), max_value=10**9).map(str),
    _FIELD,
)


@FAST
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["GP", "GN", "GL", "GA", "BD", "GB", "QZ", "P"]),
            st.sampled_from(["RMC", "VTG", "GGA", "ZDA", "GNS", "GLL", "GSV", "TXT", "HDT", "XYZ"]),
            st.lists(_NUMERIC, max_size=14),
            st.floats(min_value=-1e6, max_value=1e6, allow_nan=False),
        ),
        max_size=12,
    )
)
def test_checked_sentences_with_any_fields_never_raise(
    sentences: list[tuple[str, str, list[str], float]],
) -> None:
    # random bytes almost never pass the checksum; these do, so the field handling behind it gets any content
    d = NmeaDecoder()
    for talker, kind, fields, t in sentences:
        fix = d.decode(NmeaLine(t, nmea(",".join([talker + kind, *fields]))))
        if fix is not None:
            assert fix.speed_mps >= 0 and fix.speed_mps == fix.speed_mps
    assert d.lines == d.ignored_lines + d.bad_sentences + d.sentences


_REAL_LINES = [
    x.line for p in sorted(CAPTURES.glob("*.log")) for x in GpsFramer().feed(p.read_bytes(), 0.0)
][::7]


@FAST
@given(st.lists(st.tuples(st.sampled_from(_REAL_LINES), st.integers(0, 120), st.integers(0, 255)), max_size=40))
def test_damaged_real_lines_never_raise(edits: list[tuple[str, int, int]]) -> None:
    d = NmeaDecoder()
    for line, at, byte in edits:
        damaged = line[:at] + chr(byte) + line[at + 1 :]
        d.decode(NmeaLine(0.0, damaged))
    assert d.lines == d.ignored_lines + d.bad_sentences + d.sentences
