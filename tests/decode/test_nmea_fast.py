"""The NMEA fast path (sentences split and checked in nmea.py) against the pynmea2 path: the same fixes and counters
for every line, on generated sentences, on the gpsd captures (and mutations of them), and on arbitrary input."""

from __future__ import annotations

import functools
import operator
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from slipdaq.decode.nmea import _UNKNOWN, NmeaDecoder, _parse_plain, _xor_checksum
from slipdaq.records import NmeaLine

DATA = Path(__file__).parents[1] / "data"
CAPTURES = sorted((DATA / "gpsd-nmea").glob("*.log")) + [DATA / "rav4-comma2k19" / "rav4_ublox.nmea"]


def _capture_lines(path: Path) -> list[str]:
    return [raw.rstrip(b"\r").decode("latin-1") for raw in path.read_bytes().split(b"\n")]


CAPTURE_LINES = [line for p in CAPTURES for line in _capture_lines(p)]


def _counters(d: NmeaDecoder) -> dict[str, object]:
    return {k: v for k, v in vars(d).items() if k != "_fast_path"}


def assert_same(lines: list[NmeaLine]) -> NmeaDecoder:
    """Both paths give equal fixes line by line and equal state (every counter) after each line."""
    fast, ref = NmeaDecoder(), NmeaDecoder(fast_path=False)
    for line in lines:
        assert fast.decode(line) == ref.decode(line), line
        assert _counters(fast) == _counters(ref), line
    return fast


def _checksum(body: str) -> int:
    return functools.reduce(operator.xor, map(ord, body), 0)


# ---- generated sentences ----------------------------------------------------------------------------

TALKERS = st.one_of(
    st.sampled_from(["GP", "GN", "GL", "GA", "BD", "GB", "QZ", "GI", "IN", "gp", "Gn", "P1", "PG", "EC", "_1"]),
    st.text("ABCDEFGHIJKLMNOPQRSTUVWXYZabcz019_", min_size=2, max_size=2),
)
TYPES = st.one_of(
    st.sampled_from(["RMC", "VTG", "GGA", "GNS", "GLL", "ZDA", "GSV", "GSA", "TXT", "HDT", "GST", "XYZ", "rmc", "Vtg",
                     "GGQ", "RMQ"]),
    st.text("ABCDEFGHIJKLMNOPQRSTUVWXYZaqz_09", min_size=3, max_size=3),
)
TIME = st.builds(lambda h, m, s, frac: f"{h:02d}{m:02d}{s:02d}{frac}", st.integers(0, 25), st.integers(0, 61),
                 st.integers(0, 62), st.sampled_from(["", ".", ".0", ".00", ".123", ".5"]))
DATE = st.builds(lambda d, m, y: f"{d:02d}{m:02d}{y:02d}", st.integers(0, 32), st.integers(0, 13), st.integers(0, 99))
NUMBER = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(str),
    st.decimals(min_value=-1000, max_value=20000, places=3, allow_nan=False).map(str),
    st.integers(-5, 20).map(str),
)
FIELD = st.one_of(
    st.just(""), TIME, DATE, NUMBER, st.sampled_from(["A", "V", "N", "E", "D", "S", "W", "T", "M", "K", "a", "n", " A",
                                                     "4807.038", "01131.000", "5200.00000", "-0", "nan", "1e400"]),
    st.text(st.characters(codec="latin-1", exclude_characters="*,"), max_size=6),
)


LAT, LON = st.sampled_from(["4807.038", "5200.00000", "0000.0", "9000.0", "9100.0", "12.5"]), st.sampled_from(
    ["01131.000", "00959.99999", "18000.0", "17960.0", "1131"])
SPEED = st.sampled_from(["0.0", "12.345", "99.9", "-1.0", "0", "1e3"])
TEMPLATES = {  # the estimator's sentences with their fields in place, each field sometimes anything
    "RMC": [TIME, st.sampled_from("AVa"), LAT, st.sampled_from("NS"), LON, st.sampled_from("EW"), SPEED, SPEED, DATE,
            st.just(""), st.just(""), st.sampled_from(["A", "D", "N", "E", ""]), st.sampled_from(["V", "A", ""])],
    "GGA": [TIME, LAT, st.sampled_from("NS"), LON, st.sampled_from("EW"), st.sampled_from("0124568"),
            st.sampled_from(["12", "04", "x"]), st.just("0.8"), st.sampled_from(["100.0", "-5.5", "nan", ""]),
            st.just("M"), st.just("0.0"), st.just("M"), st.just(""), st.just("")],
    "VTG": [SPEED, st.just("T"), st.just(""), st.just("M"), SPEED, st.just("N"), SPEED, st.just("K"),
            st.sampled_from(["A", "N", "E", ""])],
    "ZDA": [TIME, st.integers(0, 32).map(str), st.integers(0, 13).map(str), st.sampled_from(["2026", "1979", "x"]),
            st.just("00"), st.just("00")],
    "GNS": [TIME, LAT, st.just("N"), LON, st.just("E"), st.just("AAN"), st.just("12")],
    "GLL": [LAT, st.just("N"), LON, st.just("E"), TIME, st.just("A"), st.just("A")],
}


@st.composite
def sentence(draw: st.DrawFn) -> str:
    if draw(st.booleans()):
        kind = draw(st.sampled_from(sorted(TEMPLATES)))
        fields = [draw(st.one_of(f, FIELD) if draw(st.integers(0, 9)) == 0 else f) for f in TEMPLATES[kind]]
        fields = fields[: draw(st.integers(0, len(fields)))] if draw(st.integers(0, 9)) == 0 else fields
        body = f"{draw(TALKERS)}{kind}," + ",".join(fields)
    else:
        body = f"{draw(TALKERS)}{draw(TYPES)}," + ",".join(draw(st.lists(FIELD, max_size=16)))
    cs = _checksum(body)
    tail = draw(st.sampled_from(["upper", "upper", "upper", "lower", "none", "wrong", "short", "double"]))
    if tail == "upper":
        line = f"${body}*{cs:02X}"
    elif tail == "lower":
        line = f"${body}*{cs:02x}"
    elif tail == "none":
        line = f"${body}"
    elif tail == "wrong":
        line = f"${body}*{(cs ^ draw(st.integers(1, 255))):02X}"
    elif tail == "short":
        line = f"${body}*{cs:X}"[:-1]
    else:
        line = f"${body}*{cs:02X}*{cs:02X}"
    prefix = draw(st.sampled_from(["", "", "", "", "", "r", "$", "junk$GPRMC,", "  ", "\x00", "#"]))
    suffix = draw(st.sampled_from(["", "", "", "", "", " ", "\t", "\r", "x"]))
    return prefix + line + suffix


@st.composite
def timed(draw: st.DrawFn, lines: st.SearchStrategy[list[str]]) -> list[NmeaLine]:
    t = 1000.0
    out = []
    for line in draw(lines):
        t += draw(st.sampled_from([0.0, 0.01, 0.05, 0.1, 0.5, 1.0, 2.0, -0.1]))
        out.append(NmeaLine(t, line))
    return out


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(timed(st.lists(sentence(), max_size=30)))
def test_generated_sentences_same_as_pynmea2(lines: list[NmeaLine]) -> None:
    assert_same(lines)


def test_generated_sentences_make_fixes() -> None:
    """The generator above reaches the fix-making code (not only rejections)."""
    fixes = []

    @settings(max_examples=200, deadline=None, database=None)
    @given(timed(st.lists(sentence(), min_size=10, max_size=30)))
    def run(lines: list[NmeaLine]) -> None:
        fixes.append(assert_same(lines).fixes)

    run()
    assert sum(fixes) > 50


@given(st.lists(FIELD, max_size=16), TALKERS.filter(lambda t: t[0] not in "Pp"),
       TYPES.filter(lambda t: t[2] not in "Qq"), st.booleans())
def test_plain_sentences_take_the_fast_path(fields: list[str], talker: str, kind: str, lower: bool) -> None:
    """A sentence in the plain form is decided by the fast path (so the comparisons above test it)."""
    body = f"{talker}{kind}," + ",".join(fields)
    line = f"${body}*{_checksum(body):02{'x' if lower else 'X'}}"
    got = _parse_plain(line)
    assert got == _UNKNOWN or got == (talker.upper(), kind.upper(), ",".join(fields).split(","))


@given(st.text(max_size=120))
def test_checksum_is_pynmea2s(text: str) -> None:
    assert _xor_checksum(text) == _checksum(text)


# ---- the real captures ------------------------------------------------------------------------------

@pytest.mark.parametrize("path", CAPTURES, ids=lambda p: p.name)
def test_captures_same_as_pynmea2(path: Path) -> None:
    lines = [NmeaLine(1000.0 + 0.05 * k, line) for k, line in enumerate(_capture_lines(path))]
    d = assert_same(lines)
    assert d.sentences > 0


@st.composite
def mutated_capture_line(draw: st.DrawFn) -> str:
    line = draw(st.sampled_from(CAPTURE_LINES))
    for _ in range(draw(st.integers(0, 3))):
        if not line:
            break
        i = draw(st.integers(0, len(line) - 1))
        op = draw(st.sampled_from(["replace", "delete", "insert", "lower", "cut"]))
        ch = draw(st.characters(codec="latin-1"))
        if op == "replace":
            line = line[:i] + ch + line[i + 1:]
        elif op == "delete":
            line = line[:i] + line[i + 1:]
        elif op == "insert":
            line = line[:i] + ch + line[i:]
        elif op == "lower":
            line = line.lower()
        else:
            line = line[:i]
    return line


@settings(max_examples=300, deadline=None)
@given(timed(st.lists(mutated_capture_line(), max_size=40)))
def test_mutated_captures_same_as_pynmea2(lines: list[NmeaLine]) -> None:
    assert_same(lines)


# ---- arbitrary input --------------------------------------------------------------------------------

@settings(max_examples=300, deadline=None)
@given(timed(st.lists(st.one_of(st.text(max_size=100), st.binary(max_size=100).map(lambda b: b.decode("latin-1")),
                                st.text("$GPRMCVTAgnr0123456789abcdefABCDEF,.*", max_size=90)), max_size=20)))
def test_arbitrary_lines_same_as_pynmea2(lines: list[NmeaLine]) -> None:
    assert_same(lines)
