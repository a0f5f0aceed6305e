"""The schemas of the log's topics: JSON Schema for the JSON topics (Foxglove plots every numeric field), ros2msg
for the CDR batches (logformat.cdr)."""

from __future__ import annotations

import dataclasses
from typing import Any

from slipdaq import WHEELS
from slipdaq.decode.nmea import DROP_REASONS
from slipdaq.logformat import cdr
from slipdaq.logformat.topics import (
    TOPIC_CAN,
    TOPIC_DIAGNOSTICS,
    TOPIC_ESTIMATE,
    TOPIC_EVENTS,
    TOPIC_FAST_SLIP,
    TOPIC_FAST_SLIP_ROW,
    TOPIC_GPS,
    TOPIC_GPS_LOCATION,
    TOPIC_IMU_RAW,
    TOPIC_MANEUVER,
    TOPIC_NMEA,
    TOPIC_RTCM,
    TOPIC_SENSORS,
    TOPIC_TEST_SET,
    TOPIC_UBX,
    TOPIC_WPT,
)
from slipdaq.maneuver.record import MANEUVER_COLUMNS
from slipdaq.maneuver.test_set import TEST_SET_COLUMNS
from slipdaq.records import GpsFix, SensorSample, SourceEvent
from slipdaq.records.columns import ESTIMATE_COLUMNS, FAST_SLIP_COLUMNS, Column, ColumnGroup

_NUM = {"type": "number"}
_NUM_OR_NULL = {"type": ["number", "null"]}
_INT = {"type": "integer"}
_INT_OR_NULL = {"type": ["integer", "null"]}


def _obj(title: str, props: dict[str, Any], optional: tuple[str, ...] = ()) -> dict[str, Any]:
    """An object schema: every field the writer emits, all of them required but the optional ones."""
    return {"title": title, "type": "object", "properties": props,
            "required": [k for k in props if k not in optional]}


_COLUMN_KINDS: dict[str, dict[str, Any]] = {
    "number": _NUM, "number?": _NUM_OR_NULL, "integer": _INT, "integer?": _INT_OR_NULL, "bool": {"type": "boolean"},
    "text": {"type": "string"}, "text?": {"type": ["string", "null"]},
    "texts": {"type": "array", "items": {"type": "string"}},
    "integers": {"type": "array", "items": {"type": "integer"}},
    "excluded": {"type": "array", "items": {"type": "object", "properties": {"index": {"type": "integer"},
                                                                            "reason": {"type": "string"}},
                                            "required": ["index", "reason"]}},
}


def _column(c: Column) -> dict[str, Any]:
    return {"type": "string", "enum": list(c.values)} if c.kind == "enum" else _COLUMN_KINDS[c.kind]


def columns_schema(title: str, groups: tuple[ColumnGroup, ...]) -> dict[str, Any]:
    """The JSON Schema of a flat record declared as column groups (records.ESTIMATE_COLUMNS), for WHEELS; each
    property with its column's description."""
    return _obj(title, {c.key(w) if g.per_wheel else c.name: _column(c) | ({"description": c.describe(w)}
                                                                           if c.description else {})
                        for g in groups for w in (WHEELS if g.per_wheel else ("",)) for c in g.columns})


def columnar_schema(title: str, groups: tuple[ColumnGroup, ...]) -> dict[str, Any]:
    """The JSON Schema of a run of such records as columns (json_codec.ColumnsJson.columns): each property the
    list of its column's values, one per record."""
    flat = columns_schema(title, groups)
    for name, prop in flat["properties"].items():
        item = {k: v for k, v in prop.items() if k != "description"}
        flat["properties"][name] = {"type": "array", "items": item} | (
            {"description": prop["description"]} if "description" in prop else {})
    return flat


_TIME = {"type": "object", "title": "time", "properties": {
    "sec": {"type": "integer", "minimum": 0}, "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}}}
HEADER = {"type": "object", "properties": {"stamp": _TIME | {"description": "the record's instant (time_s)"},
                                           "frame_id": {"type": "string"}}, "required": ["stamp", "frame_id"]}
"""A ROS-style header: Foxglove's Plot panel orders and places a message by header.stamp (timestamp "header stamp")."""


def stamped_schema(title: str, groups: tuple[ColumnGroup, ...]) -> dict[str, Any]:
    """columns_schema with a header (HEADER) first."""
    flat = columns_schema(title, groups)
    return _obj(title, {"header": HEADER} | flat["properties"])


def _per_wheel(title: str) -> dict[str, Any]:
    return _obj(title, {w: _INT for w in WHEELS})


BATCH_SCHEMAS: dict[str, tuple[str, str]] = {
    TOPIC_CAN: (cdr.CAN_BATCH_SCHEMA_NAME, cdr.CAN_BATCH_SCHEMA),
    TOPIC_WPT: (cdr.WHEEL_BATCH_SCHEMA_NAME, cdr.WHEEL_BATCH_SCHEMA),
}
"""The batched topics (ros2msg schema, CDR messages; logformat.cdr)."""


_CAN_INDEX = {"type": "integer", "description": "CAN frames processed before this record (its place among them)"}

_BOOL = {"type": "boolean"}
_TEXT = {"type": "string"}
_FIELD_TYPES: dict[str, dict[str, Any]] = {
    "float": _NUM, "float | None": _NUM_OR_NULL, "int": _INT, "int | None": _INT_OR_NULL, "bool": _BOOL, "str": _TEXT,
    "dict[str, int]": {"type": "object", "additionalProperties": _INT},
}


def dataclass_schema(title: str, cls: type) -> dict[str, Any]:
    """The JSON Schema of a record dataclass, from its fields' types (a field's metadata "enum": its values)."""
    props: dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        enum = f.metadata.get("enum")
        props[f.name] = {"type": "string", "enum": list(enum)} if enum else _FIELD_TYPES[str(f.type)]
    return _obj(title, props)


_TEXT_OR_NULL = {"type": ["string", "null"]}

LIVE_DIAGNOSTICS: dict[str, Any] = {
    # the GPS port (sources.serial_gps.SerialGpsSource.status)
    "gps_connected": _BOOL, "gps_state": {"type": "string", "enum": ["connected", "disconnected", "silent",
                                                                       "unreadable"]},
    "gps_gaps": _INT, "gps_gap_s": _NUM_OR_NULL, "gps_last_gap_s": _NUM_OR_NULL, "gps_reconnects": _INT,
    "gps_bytes": _INT, "gps_unreadable_periods": _INT, "gps_error": _TEXT_OR_NULL,
    # the log itself (McapLogSink.log_status)
    "log_path": _TEXT, "log_segments": _INT, "log_write_failures": _INT, "log_dropped_messages": _INT,
    "log_error": _TEXT_OR_NULL,
    # the CAN reader (sources.can_bus.CanBusSource.status)
    "can_reader_errors": _INT, "can_outages": _INT, "can_receiving": _BOOL, "can_last_error": _TEXT_OR_NULL,
    "can_last_outage_s": _NUM_OR_NULL,
    # the Foxglove live server (sinks.foxglove_live.FoxgloveLive.status), when the run has one
    "live_address": _TEXT, "live_clients": _INT, "live_published_messages": _INT, "live_dropped_messages": _INT,
}
"""Keys a live run adds to /diagnostics (declared, not required)."""
LOCATION_FIX_SCHEMA: dict[str, Any] = {
    "title": "foxglove.LocationFix", "description": "A navigation satellite fix for any Global Navigation Satellite System",
    "type": "object",
    "properties": {
        "timestamp": {"type": "object", "title": "time", "description": "Timestamp of the message",
                      "properties": {"sec": {"type": "integer", "minimum": 0},
                                     "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999}}},
        "frame_id": {"type": "string", "description": "Frame for the sensor"},
        "latitude": {"type": "number", "description": "Latitude in degrees"},
        "longitude": {"type": "number", "description": "Longitude in degrees"},
        "altitude": {"type": "number", "description": "Altitude in meters"},
        "position_covariance": {"type": "array", "items": {"type": "number"}, "minItems": 9, "maxItems": 9,
                                "description": "Position covariance (m^2), ENU, row-major"},
        "position_covariance_type": {"title": "foxglove.PositionCovarianceType", "oneOf": [
            {"title": t, "const": i} for i, t in enumerate(("UNKNOWN", "APPROXIMATED", "DIAGONAL_KNOWN", "KNOWN"))]},
    },
    "required": ["timestamp", "frame_id", "latitude", "longitude", "altitude", "position_covariance",
                 "position_covariance_type"],
}
"""/gps/location: Foxglove's published foxglove.LocationFix JSON Schema (its optional heading, velocity, color and
metadata left out), so that Foxglove's Map panel shows the track live and on the file."""
SCHEMAS: dict[str, dict[str, Any]] = {
    TOPIC_NMEA: _obj("slipdaq.NmeaLine", {"timestamp_s": _NUM, "line": {"type": "string"}, "can_index": _CAN_INDEX}),
    TOPIC_UBX: _obj("slipdaq.UbxFrame", {
        "timestamp_s": _NUM, "data": {"type": "string", "description": "the whole UBX frame as hex"},
        "can_index": _CAN_INDEX,
    }),
    TOPIC_GPS: dataclass_schema("slipdaq.GpsFix", GpsFix),
    TOPIC_ESTIMATE: columns_schema("slipdaq.Estimate", ESTIMATE_COLUMNS),
    TOPIC_DIAGNOSTICS: _obj("slipdaq.Diagnostics", {
        "time_s": _NUM, "can_frames": _INT, "wpt_frames": _per_wheel("frames"), "lost_frames": _per_wheel("lost"),
        "count_wraps": _per_wheel("wraps"),
        "counter_resets": _per_wheel("resets"), "unknown_frames": _INT, "error_frames": _INT, "bad_frames": _INT,
        "nmea_lines": _INT, "bad_sentences": _INT, "gps_fixes": _INT, "ubx_frames": _INT, "bad_ubx_frames": _INT,
        "estimates": _INT, "dropped_sentences": _obj("dropped_sentences", dict.fromkeys(DROP_REASONS, _INT)),
        "estimator": _obj("estimator", {
            "gps_latency_s": _NUM, "latency_source": {"type": "string"}, "gps_latency_utc_s": _NUM_OR_NULL,
            "gps_latency_wheels_s": _NUM_OR_NULL, "gps_latency_wheels_sigma_s": _NUM_OR_NULL,
            "r0_m": _obj("r0", {w: _NUM for w in WHEELS}),
            "r0_source": _obj("r0_source", {w: {"type": "string", "enum": [
                "tire_size", "configured", "other_wheels", "calibrating", "calibrated", "stored"]} for w in WHEELS}),
            "r0_se_m": _obj("r0_se", {w: _NUM_OR_NULL for w in WHEELS}),
            "cx_fit_n": _obj("cx_fit", {w: _NUM_OR_NULL for w in WHEELS}),
            "cx_fit_conf": _obj("cx_fit_conf", {w: _NUM for w in WHEELS}), "rejected_fixes": _INT,
        }),
    } | LIVE_DIAGNOSTICS, optional=tuple(LIVE_DIAGNOSTICS)),
    TOPIC_EVENTS: dataclass_schema("slipdaq.SourceEvent", SourceEvent),
    TOPIC_FAST_SLIP: columnar_schema("slipdaq.FastSlipRows", FAST_SLIP_COLUMNS),
    TOPIC_FAST_SLIP_ROW: stamped_schema("slipdaq.FastSlipRow", FAST_SLIP_COLUMNS),
    TOPIC_SENSORS: dataclass_schema("slipdaq.SensorSample", SensorSample),
    TOPIC_MANEUVER: columns_schema("slipdaq.Maneuver", MANEUVER_COLUMNS),
    TOPIC_GPS_LOCATION: LOCATION_FIX_SCHEMA,
    TOPIC_IMU_RAW: _obj("slipdaq.XbusBytes", {
        "timestamp_s": _NUM, "data": {"type": "string", "description": "an Xbus message (or the bytes between two) as hex"},
        "can_index": _CAN_INDEX,
    }),
    TOPIC_RTCM: _obj("slipdaq.RtcmFrame", {
        "timestamp_s": _NUM, "data": {"type": "string", "description": "the whole RTCM 3 frame as hex"},
        "can_index": _CAN_INDEX,
    }),
    TOPIC_TEST_SET: columns_schema("slipdaq.TestSet", TEST_SET_COLUMNS),
}
"""The JSON topics (all but BATCH_SCHEMAS), in the order their channels are registered."""
