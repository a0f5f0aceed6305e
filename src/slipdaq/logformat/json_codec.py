"""The JSON messages of the log: records to dicts and to bytes (byte for byte what json.dumps with compact
separators gives, written directly for the topics written at high rate or once per GPS epoch), and back."""

from __future__ import annotations

import json
import math
from typing import Any

from slipdaq import WHEELS
from slipdaq.columns import ESTIMATE_COLUMNS, FAST_SLIP_COLUMNS, ColumnGroup
from slipdaq.logformat.topics import log_time_ns
from slipdaq.records import CanFrame, GpsFix, NmeaLine, WheelSample


def can_frame_to_dict(f: CanFrame) -> dict[str, Any]:
    return {"timestamp_s": f.timestamp_s, "id": f.arbitration_id, "extended": f.is_extended_id,
            "error": f.is_error_frame, "dlc": len(f.data), "data": f.data.hex()}


def can_frame_from_dict(d: dict[str, Any]) -> CanFrame:
    return CanFrame(d["timestamp_s"], d["id"], bytes.fromhex(d["data"]), d["extended"], d["error"])



def _jnum(x: object) -> str:
    """A JSON number, null or boolean as json.dumps writes it."""
    if x is None:
        return "null"
    if x is True:
        return "true"
    if x is False:
        return "false"
    if type(x) is float:
        return float.__repr__(x) if x - x == 0.0 else json.dumps(x)  # nan/inf: json's NaN/Infinity
    if type(x) is int:
        return int.__repr__(x)
    return json.dumps(x)


_JSON_STR = {w: json.dumps(w) for w in WHEELS}
_json_string = json.encoder.encode_basestring_ascii
"""A str as json.dumps writes it (ensure_ascii: json's C function when there is one)."""




def wheel_sample_to_dict(s: WheelSample) -> dict[str, Any]:
    return {"timestamp_s": s.timestamp_s, "wheel": s.wheel, "revolutions": s.revolutions, "count": s.count,
            "raw": s.raw, "seq": s.seq, "lost_frames": s.lost_frames}


def dumps(payload: dict[str, Any]) -> bytes:
    return json.dumps(payload, separators=(",", ":")).encode()


# ---- fixes and estimates, once per GPS epoch: written directly, byte for byte what dumps of their dicts gives ----

_JSON_TEXT = {t: json.dumps(t) for t in (
    "standstill", "accelerate", "cruise", "brake", "gps", "wheels", "fixed", "utc", "none", "calibrated",
    "calibrating", "other_wheels", "tire_size", "configured", "stored", "RMC", "VTG", "UBX", "ok", "uncalibrated",
    "disturbed", "imu", "CAN")}


def _jval(x: object) -> str:
    """_jnum, and the known texts without json.dumps."""
    return _JSON_TEXT[x] if type(x) is str and x in _JSON_TEXT else _jnum(x)


_FIX_KEYS = tuple((k, json.dumps(k) + ":") for k in GpsFix.__slots__)


def _json_key(name: str) -> str:
    return json.dumps(name) + ":"


class ColumnsJson:
    """The JSON of a record declared as column groups (records.ESTIMATE_COLUMNS, FAST_SLIP_COLUMNS): equal to
    dumps(record.as_row()), written directly (the keys encoded once)."""

    def __init__(self, groups: tuple[ColumnGroup, ...]) -> None:
        self.groups = groups
        self._scalar = [None if g.per_wheel else [(_json_key(c.name), c.attribute) for c in g.columns]
                        for g in groups]
        self._wheel: dict[str, list[list[tuple[str, str]]]] = {}

    def _wheel_keys(self, wheel: str) -> list[list[tuple[str, str]]]:
        """Per column group: (JSON key and colon, attribute) of this wheel's columns."""
        keys = self._wheel.get(wheel)
        if keys is None:
            keys = self._wheel[wheel] = [[(_json_key(c.key(wheel)), c.attribute) for c in g.columns] if g.per_wheel
                                         else [] for g in self.groups]
        return keys

    def __call__(self, record: Any) -> bytes:
        j = _jval
        wheels = [(self._wheel_keys(w), we) for w, we in record.wheels.items()]
        parts: list[str] = []
        for g, scalar in enumerate(self._scalar):
            if scalar is not None:
                parts += [k + j(getattr(record, a)) for k, a in scalar]
            else:
                for keys, we in wheels:
                    parts += [k + j(getattr(we, a)) for k, a in keys[g]]
        return ("{" + ",".join(parts) + "}").encode()


estimate_json = ColumnsJson(ESTIMATE_COLUMNS)
"""/estimate payload: equal to dumps(e.as_row())."""
fast_slip_json = ColumnsJson(FAST_SLIP_COLUMNS)
"""/slip/fast payload: equal to dumps(row.as_row())."""


def nmea_line_json(line: NmeaLine, can_index: int) -> bytes:
    """/nmea/raw payload: equal to dumps({"timestamp_s": ..., "line": ..., "can_index": can_index})."""
    t, text = line.timestamp_s, line.line
    if type(t) is float and type(text) is str and type(can_index) is int:
        return f'{{"timestamp_s":{_jnum(t)},"line":{_json_string(text)},"can_index":{can_index}}}'.encode()
    return dumps({"timestamp_s": t, "line": text, "can_index": can_index})


def fix_json(fix: GpsFix) -> bytes:
    """/gps/fix payload: equal to dumps of the fix's fields in order."""
    return ("{" + ",".join([key + _jval(getattr(fix, name)) for name, key in _FIX_KEYS]) + "}").encode()


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
