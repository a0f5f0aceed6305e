"""Read a slipdaq MCAP log back: its config, its metadata and its raw records in recorded order.

A finished log (with its summary) is read with the standard MCAP reader. A log that was never finished (the daemon
was killed, or lost power) is read record by record up to its last complete chunk (slipdaq.recover.scan); pass a
ScanResult to learn how far that got.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mcap.reader import make_reader

from slipdaq.config import Config, parse_config
from slipdaq.recover import LogError, ScanResult, scan_messages, scan_metadata
from slipdaq.records import NmeaLine, RawRecord, UbxFrame
from slipdaq.sinks.mcap_log import (
    METADATA_NAME, RAW_TOPICS, TOPIC_CAN, TOPIC_ESTIMATE, TOPIC_UBX, can_frame_from_dict,
)

__all__ = ["LogError", "ScanResult", "config_from_log", "is_finished", "iter_estimates", "iter_raw_records",
           "iter_topic", "raw_record_count", "read_metadata"]


def _open(path: str | Path):  # type: ignore[no-untyped-def]
    try:
        return open(path, "rb")
    except OSError as e:
        raise LogError(f"{path}: cannot read: {e.strerror}") from None


def is_finished(path: str | Path) -> bool:
    """True when the file has a footer pointing to its summary: closed properly, readable by index."""
    with _open(path) as f:
        try:
            summary = make_reader(f).get_summary()
        except Exception:  # no footer at the end (torn), or not MCAP at all
            return False
    return summary is not None and bool(summary.chunk_indexes)


def read_metadata(path: str | Path) -> dict[str, str]:
    try:
        with _open(path) as f:
            for m in make_reader(f).iter_metadata():
                if m.name == METADATA_NAME:
                    return dict(m.metadata)
    except LogError:
        raise
    except Exception:  # not finished: read it record by record
        for m in scan_metadata(path):
            if m.name == METADATA_NAME:
                return dict(m.metadata)
    raise LogError(f"{path}: no '{METADATA_NAME}' metadata: not a slipdaq log")


def config_from_log(path: str | Path) -> Config:
    """The config stored in the log (with its DBC text), so that replay needs no other input."""
    meta = read_metadata(path)
    source = meta.get("config_path") or None
    return parse_config(meta.get("config_toml", ""), Path(source) if source else None, dbc_text=meta.get("dbc"))


def iter_topic(
    path: str | Path, topics: tuple[str, ...], scan_result: ScanResult | None = None
) -> Iterator[tuple[str, int, dict[str, Any]]]:
    """(topic, log_time_ns, decoded JSON) in the order the messages were written.

    A log that was not finished is read up to its last complete chunk; scan_result (if given) then tells how far."""
    if is_finished(path):
        if scan_result is not None:
            scan_result.finished = scan_result.has_summary = True
        with _open(path) as f:
            reader = make_reader(f)
            for _schema, channel, message in reader.iter_messages(topics=list(topics), log_time_order=False):
                yield channel.topic, message.log_time, json.loads(message.data)
        return
    for channel, message in scan_messages(path, topics, scan_result):
        yield channel.topic, message.log_time, json.loads(message.data)


def iter_raw_records(path: str | Path, scan_result: ScanResult | None = None) -> Iterator[RawRecord]:
    """The raw CAN frames and NMEA lines in the order the pipeline processed them when recording."""
    for topic, _t, d in iter_topic(path, RAW_TOPICS, scan_result):
        if topic == TOPIC_CAN:
            yield can_frame_from_dict(d)
        elif topic == TOPIC_UBX:
            yield UbxFrame(d["timestamp_s"], bytes.fromhex(d["data"]))
        else:
            yield NmeaLine(d["timestamp_s"], d["line"])


def iter_estimates(path: str | Path, scan_result: ScanResult | None = None) -> Iterator[dict[str, Any]]:
    for _topic, _t, d in iter_topic(path, (TOPIC_ESTIMATE,), scan_result):
        yield d


def raw_record_count(path: str | Path) -> int | None:
    """Number of raw CAN and NMEA messages, from the file's summary (None when it has none)."""
    with _open(path) as f:
        try:
            summary = make_reader(f).get_summary()
        except Exception:
            return None
    if summary is None or summary.statistics is None:
        return None
    ids = [c.id for c in summary.channels.values() if c.topic in RAW_TOPICS]
    return sum(summary.statistics.channel_message_counts.get(i, 0) for i in ids)
