"""Writes a log in slipdaq's format from before the batches (one JSON message per CAN frame, NMEA lines without
can_index), which slipdaq still reads: for the compatibility tests (tests/test_batch_log.py) and
benchmarks/replay_check.py. The old format is frozen here, so this runs under any slipdaq revision."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from mcap.writer import CompressionType, Writer

_NUM, _INT = {"type": "number"}, {"type": "integer"}
CAN_SCHEMA = {
    "title": "slipdaq.CanFrame", "type": "object",
    "properties": {"timestamp_s": _NUM, "id": _INT, "extended": {"type": "boolean"}, "error": {"type": "boolean"},
                   "dlc": _INT, "data": {"type": "string", "description": "payload bytes as hex"}},
    "required": ["timestamp_s", "id", "extended", "error", "dlc", "data"],
}
NMEA_SCHEMA = {
    "title": "slipdaq.NmeaLine", "type": "object",
    "properties": {"timestamp_s": _NUM, "line": {"type": "string"}}, "required": ["timestamp_s", "line"],
}


def _dumps(payload: dict[str, Any]) -> bytes:
    return json.dumps(payload, separators=(",", ":")).encode()


def write_old_format_log(path: Path, cfg: Any, records: list[Any]) -> None:
    """CAN frames and NMEA lines (records, in order) as a live log of the old per-frame format, with cfg's config."""
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile="slipdaq", library="slipdaq 0.x")
        ch = {}
        for topic, schema in (("/can/raw", CAN_SCHEMA), ("/nmea/raw", NMEA_SCHEMA)):
            sid = w.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
            ch[topic] = w.register_channel(topic, "json", sid)
        w.add_metadata("slipdaq", {"version": "0.x", "mode": "live", "config_toml": cfg.to_toml(),
                                   "dbc": cfg.load_dbc_text()})
        for seq, r in enumerate(records):
            ns = int(round(r.timestamp_s * 1e9))
            if hasattr(r, "arbitration_id"):
                data = _dumps({"timestamp_s": r.timestamp_s, "id": r.arbitration_id, "extended": r.is_extended_id,
                               "error": r.is_error_frame, "dlc": len(r.data), "data": bytes(r.data).hex()})
                w.add_message(ch["/can/raw"], log_time=ns, publish_time=ns, sequence=seq, data=data)
            else:
                data = _dumps({"timestamp_s": r.timestamp_s, "line": r.line})
                w.add_message(ch["/nmea/raw"], log_time=ns, publish_time=ns, sequence=seq, data=data)
        w.finish()
