"""The JSON messages of the log: records to bytes and back. Written and read with orjson: compact JSON whose values
are those json.dumps writes (a float's shortest repr, read back bit for bit); where orjson cannot keep a value (a NaN
or an infinity, which it writes as null; an integer over 64 bits; a numpy scalar; a key that is not a str) the message
is json.dumps's (NaN, Infinity) instead, so every value reads back as it was."""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable, Sequence
from operator import attrgetter
from typing import Any

import orjson

from slipdaq.logformat.topics import log_time_ns
from slipdaq.records import CanFrame, GpsFix, NmeaLine, WheelSample
from slipdaq.records.columns import ESTIMATE_COLUMNS, FAST_SLIP_COLUMNS, ColumnGroup, record_values
from slipdaq.records.fast_rows import FastSlipBatch


def can_frame_to_dict(f: CanFrame) -> dict[str, Any]:
    return {"timestamp_s": f.timestamp_s, "id": f.arbitration_id, "extended": f.is_extended_id,
            "error": f.is_error_frame, "dlc": len(f.data), "data": f.data.hex()}


def can_frame_from_dict(d: dict[str, Any]) -> CanFrame:
    return CanFrame(d["timestamp_s"], d["id"], bytes.fromhex(d["data"]), d["extended"], d["error"])


def wheel_sample_to_dict(s: WheelSample) -> dict[str, Any]:
    return {"timestamp_s": s.timestamp_s, "wheel": s.wheel, "revolutions": s.revolutions, "count": s.count,
            "raw": s.raw, "seq": s.seq, "lost_frames": s.lost_frames}


def std_dumps(payload: object) -> bytes:
    """json.dumps with compact separators: NaN and infinities as NaN, Infinity."""
    return json.dumps(payload, separators=(",", ":")).encode()


def _non_finite(x: object) -> bool:
    """A NaN or an infinity anywhere in x (dicts' values, lists' and tuples' items)."""
    if isinstance(x, float):
        return not math.isfinite(x)
    if isinstance(x, dict):
        return any(_non_finite(v) for v in x.values())
    if isinstance(x, list | tuple):
        return any(_non_finite(v) for v in x)
    return False


def _flat_non_finite(values: Iterable[object]) -> bool:
    """A NaN or an infinity among values (numbers, None, texts; lists of texts) that orjson wrote: their floats are
    floats, not subclasses (orjson refuses those). Their sum is finite only if they all are (a sum too large for a
    float says True too: the message is then json.dumps's, the same values)."""
    total = sum([v for v in values if type(v) is float], 0.0)
    return total - total != 0.0


def dumps(payload: object) -> bytes:
    """payload as compact JSON, every value as json.dumps writes it (see the module docstring)."""
    try:
        out = orjson.dumps(payload)
    except TypeError:  # orjson.JSONEncodeError: a big integer, a numpy scalar, a key not a str
        return std_dumps(payload)
    if b"null" in out and _non_finite(payload):
        return std_dumps(payload)
    return out


_LONG_DIGITS = re.compile(rb"\d{19}")
"""19 digits in a row: maybe an integer beyond 64 bits, which orjson reads as a float (json: an int)."""


def loads(data: bytes) -> Any:
    """A message's JSON read back, as json.loads reads it: by orjson, or by json where orjson refuses the text (NaN
    and Infinity, which json.dumps writes; a lone surrogate) or where it may hold an integer beyond 64 bits."""
    if _LONG_DIGITS.search(data) is None:
        try:
            return orjson.loads(data)
        except orjson.JSONDecodeError:
            pass
    return json.loads(data)


def _dumps_row(row: dict[str, Any], values: Sequence[object]) -> bytes:
    """dumps(row), row's values given flat (no nested dicts)."""
    try:
        out = orjson.dumps(row)
    except TypeError:
        return std_dumps(row)
    if b"null" in out and _flat_non_finite(values):
        return std_dumps(row)
    return out


class ColumnsJson:
    """The JSON of a record declared as column groups (ESTIMATE_COLUMNS, FAST_SLIP_COLUMNS): dumps(record.as_row());
    `columns` gives a run of records as one message of columns (each name: its values in the records' order)."""

    def __init__(self, groups: tuple[ColumnGroup, ...]) -> None:
        self.groups = groups

    def __call__(self, record: Any) -> bytes:
        keys, values = record_values(record, self.groups)
        return _dumps_row(dict(zip(keys, values)), values)

    def columns(self, records: Sequence[Any]) -> bytes:
        """Records with the same wheels (in the same order) as one JSON object of lists: name -> the records' values
        (rows_of_columns gives the rows back)."""
        wheels = tuple(records[0].wheels)
        if any(tuple(r.wheels) != wheels for r in records):
            raise ValueError("records with other wheels (or in another order) in one message of columns")
        return self._columns([record_values(r, self.groups) for r in records])

    @staticmethod
    def _columns(table: Sequence[tuple[list[str], list[Any]]]) -> bytes:
        """columns() of the records' record_values (the same names)."""
        columns = dict(zip(table[0][0], (list(c) for c in zip(*[values for _keys, values in table]))))
        return _dumps_row(columns, [v for _keys, values in table for v in values])


def rows_of_columns(columns: dict[str, list[Any]]) -> list[dict[str, Any]]:
    """The rows of a columnar message (ColumnsJson.columns), each a dict in the columns' order."""
    keys = list(columns)
    return [dict(zip(keys, values)) for values in zip(*columns.values())]


estimate_json = ColumnsJson(ESTIMATE_COLUMNS)
"""/estimate payload: dumps(e.as_row())."""
fast_slip_json = ColumnsJson(FAST_SLIP_COLUMNS)
"""/slip/fast: fast_slip_json.columns(rows) is a message of rows (one row: dumps(row.as_row()) for the old per-row
message)."""


def fast_slip_row_json(row: Any) -> bytes:
    """/slip/fast/row payload: {"header": {"stamp": {"sec", "nsec"}, "frame_id": ""}} and then the row's columns
    (FAST_SLIP_COLUMNS): the stamp is the row's instant, time_s, to the nanosecond."""
    return _fast_slip_row(row.time_s, *record_values(row, FAST_SLIP_COLUMNS))


def _fast_slip_row(time_s: float, keys: list[str], values: Sequence[Any]) -> bytes:
    """fast_slip_row_json of the row at time_s, of its record_values."""
    ns = round(time_s * 1e9)
    payload: dict[str, Any] = {"header": {"stamp": {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000},
                                          "frame_id": ""}}
    payload.update(zip(keys, values))  # as dict(zip(keys, values)): a name twice keeps its last value
    try:
        out = orjson.dumps(payload)
    except TypeError:
        return std_dumps(payload)
    # the header holds no float: a non-finite value is among values (the sum's test, confirmed: it also says True
    # for finite values whose sum overflows)
    if b"null" in out and _flat_non_finite(values) and _non_finite(payload):
        return std_dumps(payload)
    return out


def fast_slip_messages(rows: Sequence[Any]) -> tuple[list[bytes], list[bytes]]:
    """The /slip/fast messages of rows (fast_slip_json.columns of each run of rows with the same wheels) and their
    /slip/fast/row payloads (fast_slip_row_json): FastSlip records, or a FastSlipBatch read as its columns."""
    if isinstance(rows, FastSlipBatch):
        return _fast_slip_batch_messages(rows)
    runs: list[bytes] = []
    each: list[bytes] = []
    i, n = 0, len(rows)
    while i < n:
        wheels, k = tuple(rows[i].wheels), i + 1
        while k < n and tuple(rows[k].wheels) == wheels:
            k += 1
        run, row_payloads = _fast_slip_batch_messages(FastSlipBatch.of_rows(rows[i:k], wheels))
        runs += run
        each += row_payloads
        i = k
    return runs, each


def _fast_slip_batch_messages(batch: FastSlipBatch) -> tuple[list[bytes], list[bytes]]:
    """fast_slip_messages of a batch's rows (one run: every row has the batch's wheels), from its columns."""
    if not len(batch):
        return [], []
    columns = batch.columns()
    keys = list(columns)
    table = list(zip(*columns.values()))
    run = _dumps_row(columns, [v for values in table for v in values])  # the values row by row, as _columns sums them
    return [run], [_fast_slip_row(t, keys, values) for t, values in zip(columns["time_s"], table)]


def nmea_line_json(line: NmeaLine, can_index: int) -> bytes:
    """/nmea/raw payload: dumps({"timestamp_s": ..., "line": ..., "can_index": can_index})."""
    return dumps({"timestamp_s": line.timestamp_s, "line": line.line, "can_index": can_index})


_FIX_FIELDS = GpsFix.__slots__
_fix_values = attrgetter(*_FIX_FIELDS)


def fix_json(fix: GpsFix) -> bytes:
    """/gps/fix payload: dumps of the fix's fields in order."""
    values = _fix_values(fix)
    return _dumps_row(dict(zip(_FIX_FIELDS, values)), values)


LOCATION_FRAME_ID = "gps"
_NO_COVARIANCE = [0.0] * 9


def location_fix_json(fix: GpsFix) -> bytes | None:
    """/gps/location payload (foxglove.LocationFix) of a valid fix with a position, else None: timestamp the fix's log
    time, altitude 0 when the receiver gave none, covariance unknown (type 0)."""
    lat, lon = fix.latitude_deg, fix.longitude_deg
    if not fix.valid or lat is None or lon is None or not (math.isfinite(lat) and math.isfinite(lon)):
        return None
    alt = fix.altitude_m if fix.altitude_m is not None and math.isfinite(fix.altitude_m) else 0.0
    sec, nsec = divmod(log_time_ns(fix.timestamp_s), 1_000_000_000)
    return dumps({"timestamp": {"sec": sec, "nsec": nsec}, "frame_id": LOCATION_FRAME_ID, "latitude": float(lat),
                  "longitude": float(lon), "altitude": float(alt), "position_covariance": _NO_COVARIANCE,
                  "position_covariance_type": 0})
