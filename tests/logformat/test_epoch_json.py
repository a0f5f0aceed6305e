"""The log's JSON (json_codec, written with orjson) holds the values json.dumps writes, bit for bit: floats of every
kind (NaN, infinities, -0.0, subnormals, numpy scalars), integers beyond 64 bits, texts; a /slip/fast message of rows
reads back as the rows."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from slipdaq import WHEELS
from slipdaq.logformat.json_codec import (
    dumps,
    estimate_json,
    fast_slip_json,
    fast_slip_messages,
    fast_slip_row_json,
    fix_json,
    loads,
    nmea_line_json,
    rows_of_columns,
    std_dumps,
)
from slipdaq.records import Estimate, FastSlip, FastWheel, GpsFix, NmeaLine, WheelEstimate
from slipdaq.records.columns import ESTIMATE_COLUMNS, FAST_SLIP_COLUMNS, ColumnGroup

FLOAT = st.floats(allow_nan=True, allow_infinity=True)
OPT_FLOAT = st.one_of(st.none(), FLOAT, st.integers(-(2**70), 2**70), FLOAT.map(np.float64))
TEXT = st.one_of(st.sampled_from(["calibrated", "tire_size", "other_wheels", "cruise", "gps", "utc", "none", "null"]),
                 st.text(max_size=8))

WHEEL = st.builds(WheelEstimate, OPT_FLOAT, OPT_FLOAT, FLOAT, OPT_FLOAT, OPT_FLOAT, OPT_FLOAT, TEXT, OPT_FLOAT,
                  OPT_FLOAT, OPT_FLOAT)
WHEEL_NAMES = st.one_of(st.permutations(WHEELS), st.lists(st.sampled_from(WHEELS), unique=True),
                        st.lists(st.text(max_size=4), unique=True, max_size=4))
JSON_VALUES = st.recursive(
    st.one_of(st.none(), st.booleans(), FLOAT, st.integers(-(2**70), 2**70), TEXT, FLOAT.map(np.float64)),
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(TEXT, inner, max_size=4)), max_leaves=12)


def exact(data: bytes) -> Any:
    """A JSON message's values, each float by its bits (NaN, infinities and -0.0 included)."""
    def canon(x: Any) -> Any:
        if isinstance(x, float):
            return ("float", x.hex())
        if isinstance(x, dict):
            return {k: canon(v) for k, v in x.items()}
        if isinstance(x, list):
            return [canon(v) for v in x]
        return x
    return canon(json.loads(data, parse_constant=lambda name: float(name.replace("Infinity", "inf"))))


@given(JSON_VALUES)
def test_dumps_keeps_what_json_dumps_writes(payload: Any) -> None:
    assert exact(dumps(payload)) == exact(std_dumps(payload))


def same_values(a: Any, b: Any) -> bool:
    """Equal, of the same types, floats bit for bit (NaN equal to NaN, -0.0 not 0.0)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, float):
        return np.float64(a).tobytes() == np.float64(b).tobytes() or (a != a and b != b)
    if isinstance(a, list):
        return len(a) == len(b) and all(same_values(x, y) for x, y in zip(a, b))
    if isinstance(a, dict):
        return list(a) == list(b) and all(same_values(a[k], b[k]) for k in a)
    return bool(a == b)


@given(JSON_VALUES)
def test_loads_reads_what_json_loads_reads(payload: Any) -> None:
    """What the log's messages hold (dumps: orjson's bytes, or json.dumps's with NaN, Infinity and big integers)
    reads back by loads as json.loads reads it, every float bit for bit; and json's own indented text too."""
    for data in (dumps(payload), std_dumps(payload), json.dumps(payload, indent=1).encode()):
        assert same_values(loads(data), json.loads(data))


@st.composite
def estimates(draw: st.DrawFn) -> Estimate:
    wheels = {w: draw(WHEEL) for w in draw(WHEEL_NAMES)}
    return Estimate(draw(FLOAT), draw(FLOAT), draw(OPT_FLOAT), draw(OPT_FLOAT), draw(FLOAT), wheels, draw(TEXT),
                    draw(TEXT), draw(FLOAT), draw(TEXT))


def _row_by_hand(record: Any, groups: tuple[ColumnGroup, ...]) -> dict[str, Any]:
    """The flat mapping as its definition says, one column at a time (columns.record_row builds getters once)."""
    row: dict[str, Any] = {}
    for group in groups:
        for w, part in (record.wheels.items() if group.per_wheel else [("", record)]):
            for c in group.columns:
                row[c.key(w) if group.per_wheel else c.name] = getattr(part, c.attribute)
    return row


@given(estimates())
def test_estimate_json_is_json_dumps_of_the_row(e: Estimate) -> None:
    row = e.as_row()
    assert list(row) == list(_row_by_hand(e, ESTIMATE_COLUMNS))
    assert exact(std_dumps(row)) == exact(std_dumps(_row_by_hand(e, ESTIMATE_COLUMNS)))
    assert exact(estimate_json(e)) == exact(std_dumps(row))


@given(st.builds(GpsFix, FLOAT, FLOAT, OPT_FLOAT, st.booleans(), OPT_FLOAT, OPT_FLOAT, OPT_FLOAT, OPT_FLOAT,
                 st.one_of(st.none(), st.integers(-5, 2**40)), st.one_of(st.none(), st.integers(0, 99)),
                 st.one_of(st.sampled_from(["RMC", "VTG", "UBX"]), st.text(max_size=5)), OPT_FLOAT))
def test_fix_json_is_json_dumps(fix: GpsFix) -> None:
    assert exact(fix_json(fix)) == exact(std_dumps({k: getattr(fix, k) for k in fix.__slots__}))


@given(st.one_of(FLOAT, FLOAT.map(np.float64)), st.one_of(st.text(max_size=90), st.sampled_from(
    ["$GPRMC,000012.10,A,5200.00000,N,01000.00000,E,25.123,90.0,010126,,,A*6B", 'a"b\\c\u00e9\u2028\x00'])),
       st.integers(0, 2**63))
def test_nmea_line_json_is_json_dumps(t: float, line: str, can_index: int) -> None:
    assert exact(nmea_line_json(NmeaLine(t, line), can_index)) == exact(std_dumps(
        {"timestamp_s": t, "line": line, "can_index": can_index}))


FAST_WHEEL = st.builds(FastWheel, OPT_FLOAT, OPT_FLOAT)


@given(st.lists(st.builds(FastSlip, FLOAT, FLOAT, FLOAT, st.sampled_from(["imu", "gps"]),
                          st.tuples(*[FAST_WHEEL] * len(WHEELS)).map(lambda ws: dict(zip(WHEELS, ws)))),
                min_size=1, max_size=12))
def test_fast_slip_rows_as_columns_read_back_as_the_rows(rows: list[FastSlip]) -> None:
    message = fast_slip_json.columns(rows)
    assert [exact(std_dumps(r)) for r in rows_of_columns(json.loads(message))] == \
        [exact(std_dumps(r.as_row())) for r in rows]
    assert exact(fast_slip_json(rows[0])) == exact(std_dumps(rows[0].as_row()))
    assert [exact(std_dumps(r.as_row())) for r in rows] == [exact(std_dumps(_row_by_hand(r, FAST_SLIP_COLUMNS)))
                                                            for r in rows]


BIG = st.floats(min_value=1e307, max_value=1.7e308)  # finite values whose sum overflows


def fast_slip_messages_one_by_one(rows: list[FastSlip]) -> tuple[list[bytes], list[bytes]]:
    """The /slip/fast messages of rows as written record by record: fast_slip_json.columns of each run of rows with
    the same wheels, and each row's /slip/fast/row payload from its own as_row."""
    runs: list[bytes] = []
    i = 0
    while i < len(rows):
        k = i + 1
        while k < len(rows) and tuple(rows[k].wheels) == tuple(rows[i].wheels):
            k += 1
        runs.append(fast_slip_json.columns(rows[i:k]))
        i = k
    return runs, [row_by_row(r) for r in rows]


def row_by_row(r: FastSlip) -> bytes:
    ns = round(r.time_s * 1e9)
    return dumps({"header": {"stamp": {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}, "frame_id": ""}}
                 | r.as_row())


@given(st.lists(st.builds(FastSlip, st.floats(-1e10, 1e10), st.one_of(FLOAT, BIG), st.one_of(FLOAT, BIG),
                          st.sampled_from(["imu", "gps"]),
                          st.one_of(st.tuples(*[FAST_WHEEL] * len(WHEELS)).map(lambda ws: dict(zip(WHEELS, ws))),
                                    st.tuples(FAST_WHEEL, FAST_WHEEL).map(lambda ws: dict(zip(("RL", "RR"), ws))))),
                min_size=1, max_size=12))
def test_fast_slip_messages_are_each_rows_own(rows: list[FastSlip]) -> None:
    """fast_slip_messages (each row's values taken once) gives the bytes of a message of columns per run of rows with
    the same wheels and of each row's /slip/fast/row payload, written one by one."""
    assert fast_slip_messages(rows) == fast_slip_messages_one_by_one(rows)
    assert [fast_slip_row_json(r) for r in rows] == [row_by_row(r) for r in rows]
