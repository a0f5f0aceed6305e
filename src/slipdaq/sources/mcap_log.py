"""Read a slipdaq MCAP log back: its config, its metadata and its raw records in recorded order."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mcap.reader import make_reader

from slipdaq.config import Config, parse_config
from slipdaq.records import NmeaLine, RawRecord
from slipdaq.sinks.mcap_log import (
    METADATA_NAME, RAW_TOPICS, TOPIC_CAN, TOPIC_ESTIMATE, can_frame_from_dict,
)


class LogError(Exception):
    """A file that is not a readable slipdaq log."""


def read_metadata(path: str | Path) -> dict[str, str]:
    with open(path, "rb") as f:
        try:
            for m in make_reader(f).iter_metadata():
                if m.name == METADATA_NAME:
                    return dict(m.metadata)
        except Exception as e:
            raise LogError(f"{path}: not a readable MCAP file: {e}") from None
    raise LogError(f"{path}: no '{METADATA_NAME}' metadata: not a slipdaq log")


def config_from_log(path: str | Path) -> Config:
    """The config stored in the log (with its DBC text), so that replay needs no other input."""
    meta = read_metadata(path)
    source = meta.get("config_path") or None
    return parse_config(meta.get("config_toml", ""), Path(source) if source else None, dbc_text=meta.get("dbc"))


def iter_topic(path: str | Path, topics: tuple[str, ...]) -> Iterator[tuple[str, int, dict[str, Any]]]:
    """(topic, log_time_ns, decoded JSON) in the order the messages were written."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        for _schema, channel, message in reader.iter_messages(topics=list(topics), log_time_order=False):
            yield channel.topic, message.log_time, json.loads(message.data)


def iter_raw_records(path: str | Path) -> Iterator[RawRecord]:
    """The raw CAN frames and NMEA lines in the order the pipeline processed them when recording."""
    for topic, _t, d in iter_topic(path, RAW_TOPICS):
        if topic == TOPIC_CAN:
            yield can_frame_from_dict(d)
        else:
            yield NmeaLine(d["timestamp_s"], d["line"])


def iter_estimates(path: str | Path) -> Iterator[dict[str, Any]]:
    for _topic, _t, d in iter_topic(path, (TOPIC_ESTIMATE,)):
        yield d


def raw_record_count(path: str | Path) -> int | None:
    """Number of raw CAN and NMEA messages, from the file's summary (None when it has none)."""
    with open(path, "rb") as f:
        try:
            summary = make_reader(f).get_summary()
        except Exception:
            return None
    if summary is None or summary.statistics is None:
        return None
    ids = [c.id for c in summary.channels.values() if c.topic in RAW_TOPICS]
    return sum(summary.statistics.channel_message_counts.get(i, 0) for i in ids)
