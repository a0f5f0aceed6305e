"""The per-epoch JSON written directly (estimate_json, fix_json) is byte for byte json.dumps of the records' dicts."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from slipdaq import WHEELS
from slipdaq.logformat.json_codec import dumps, estimate_json, fix_json
from slipdaq.records import Estimate, GpsFix, WheelEstimate

FLOAT = st.floats(allow_nan=True, allow_infinity=True)
OPT_FLOAT = st.one_of(st.none(), FLOAT, st.integers(-(2**70), 2**70), FLOAT.map(np.float64))
TEXT = st.one_of(st.sampled_from(["calibrated", "tire_size", "other_wheels", "cruise", "gps", "utc", "none"]),
                 st.text(max_size=8))

WHEEL = st.builds(WheelEstimate, OPT_FLOAT, OPT_FLOAT, FLOAT, OPT_FLOAT, OPT_FLOAT, OPT_FLOAT, TEXT, OPT_FLOAT,
                  OPT_FLOAT, OPT_FLOAT)
WHEEL_NAMES = st.one_of(st.permutations(WHEELS), st.lists(st.sampled_from(WHEELS), unique=True),
                        st.lists(st.text(max_size=4), unique=True, max_size=4))


@st.composite
def estimates(draw: st.DrawFn) -> Estimate:
    wheels = {w: draw(WHEEL) for w in draw(WHEEL_NAMES)}
    return Estimate(draw(FLOAT), draw(FLOAT), draw(OPT_FLOAT), draw(OPT_FLOAT), draw(FLOAT), wheels, draw(TEXT),
                    draw(TEXT), draw(FLOAT), draw(TEXT))


@given(estimates())
def test_estimate_json_is_json_dumps(e: Estimate) -> None:
    assert estimate_json(e) == dumps(e.as_row())


@given(st.builds(GpsFix, FLOAT, FLOAT, OPT_FLOAT, st.booleans(), OPT_FLOAT, OPT_FLOAT, OPT_FLOAT, OPT_FLOAT,
                 st.one_of(st.none(), st.integers(-5, 2**40)), st.one_of(st.none(), st.integers(0, 99)),
                 st.one_of(st.sampled_from(["RMC", "VTG", "UBX"]), st.text(max_size=5)), OPT_FLOAT))
def test_fix_json_is_json_dumps(fix: GpsFix) -> None:
    assert fix_json(fix) == dumps({k: getattr(fix, k) for k in fix.__slots__})


@given(st.one_of(FLOAT, FLOAT.map(np.float64)), st.one_of(st.text(max_size=90), st.sampled_from(
    ["$GPRMC,000012.10,A,5200.00000,N,01000.00000,E,25.123,90.0,010126,,,A*6B", 'a"b\\c\u00e9\u2028\x00'])),
       st.integers(0, 2**63))
def test_nmea_line_json_is_json_dumps(t: float, line: str, can_index: int) -> None:
    from slipdaq.logformat.json_codec import nmea_line_json
    from slipdaq.records import NmeaLine

    assert nmea_line_json(NmeaLine(t, line), can_index) == dumps({"timestamp_s": t, "line": line,
                                                                   "can_index": can_index})
