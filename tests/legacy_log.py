"""A log in slipdaq's format before the batches (one JSON message per CAN frame, NMEA lines without can_index), for
the compatibility tests (tests/test_batch_log.py) and benchmarks/replay_check.py."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from mcap.writer import CompressionType, Writer

from slipdaq.records import CanFrame
from slipdaq.sinks.mcap_log import LEGACY_SCHEMAS, METADATA_NAME, SCHEMAS, TOPIC_CAN, TOPIC_NMEA, can_frame_json


def write_old_format_log(path: Path, cfg: Any, records: list[Any]) -> None:
    """CAN frames and NMEA lines (records, in order) as a live log of the old per-frame format, with cfg's config."""
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.ZSTD)
        w.start(profile="slipdaq", library="slipdaq 0.x")
        ch = {}
        for topic, schema in (LEGACY_SCHEMAS | {TOPIC_NMEA: SCHEMAS[TOPIC_NMEA]}).items():
            sid = w.register_schema(schema["title"], "jsonschema", json.dumps(schema).encode())
            ch[topic] = w.register_channel(topic, "json", sid)
        w.add_metadata(METADATA_NAME, {"version": "0.x", "mode": "live", "config_toml": cfg.to_toml(),
                                       "dbc": cfg.load_dbc_text()})
        for seq, r in enumerate(records):
            ns = int(round(r.timestamp_s * 1e9))
            if isinstance(r, CanFrame):
                w.add_message(ch[TOPIC_CAN], log_time=ns, publish_time=ns, sequence=seq, data=can_frame_json(r))
            else:
                data = json.dumps({"timestamp_s": r.timestamp_s, "line": r.line}, separators=(",", ":")).encode()
                w.add_message(ch[TOPIC_NMEA], log_time=ns, publish_time=ns, sequence=seq, data=data)
        w.finish()
