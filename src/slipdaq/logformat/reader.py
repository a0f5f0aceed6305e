"""Read a slipdaq MCAP log back: its config, its metadata and its raw records in recorded order.

A finished log (with its summary) is read with the standard MCAP reader. A log that was never finished (the daemon
was killed, or lost power) is read record by record up to its last complete chunk (logformat.salvage.scan); pass a
ScanResult to learn how far that got.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from mcap.reader import make_reader

from slipdaq import WHEELS
from slipdaq.config import Config, parse_config
from slipdaq.logformat import cdr
from slipdaq.logformat.errors import LogError
from slipdaq.logformat.json_codec import can_frame_from_dict, can_frame_to_dict, wheel_sample_to_dict
from slipdaq.logformat.salvage import ScanResult, scan, scan_messages, scan_metadata
from slipdaq.logformat.topics import (
    MAX_BATCH_FRAMES,
    METADATA_NAME,
    RAW_TOPICS,
    TOPIC_CAN,
    TOPIC_ESTIMATE,
    TOPIC_FAST_SLIP,
    TOPIC_SENSORS,
    TOPIC_UBX,
    TOPIC_WPT,
    log_time_ns,
)
from slipdaq.records import CanFrame, CanFrameBatch, NmeaLine, RawRecord, UbxFrame

__all__ = ["LogError", "ScanResult", "can_channels", "config_from_log", "is_finished", "iter_estimates", "iter_raw_batches",
           "iter_raw_records", "iter_topic", "raw_record_count", "read_metadata"]


def _open(path: str | Path):
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
    """The log's `slipdaq` metadata record (the last one: a log whose CAN channels were not all known at its start
    has copies of it with a longer can_channels list)."""
    found: dict[str, str] | None = None
    try:
        with _open(path) as f:
            for m in make_reader(f).iter_metadata():
                if m.name == METADATA_NAME:
                    found = dict(m.metadata)
    except LogError:
        raise
    except Exception:  # not finished: read it record by record
        for m in scan_metadata(path):
            if m.name == METADATA_NAME:
                found = dict(m.metadata)
    if found is None:
        raise LogError(f"{path}: no '{METADATA_NAME}' metadata: not a slipdaq log")
    return found


def can_channels(metadata: dict[str, str]) -> tuple[str | None, ...]:
    """The CAN channel names a log's /can/raw frames index (its can_channels; a log from before it: one, unnamed)."""
    text = metadata.get("can_channels")
    return tuple(json.loads(text)) if text is not None else (None,)


def config_from_log(path: str | Path) -> Config:
    """The config stored in the log (with its DBC text), so that replay needs no other input."""
    meta = read_metadata(path)
    source = meta.get("config_path") or None
    return parse_config(meta.get("config_toml", ""), Path(source) if source else None, dbc_text=meta.get("dbc"))


def iter_messages(
    path: str | Path, topics: tuple[str, ...], scan_result: ScanResult | None = None,
    on_metadata: Callable[[str, dict[str, str]], None] | None = None,
) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, message encoding, log_time_ns, data) in the order the messages were written.

    A log that was not finished is read up to its last complete chunk; scan_result (if given) then tells how far.
    on_metadata(name, metadata) gets each metadata record before the messages written after it."""
    if is_finished(path):
        if scan_result is not None:
            scan_result.finished = scan_result.has_summary = True
        with _open(path) as f:
            reader = make_reader(f, validate_crcs=True)
            if on_metadata is not None:
                for m in reader.iter_metadata():
                    on_metadata(m.name, dict(m.metadata))
            for _schema, channel, message in reader.iter_messages(topics=list(topics), log_time_order=False):
                yield channel.topic, channel.message_encoding, message.log_time, message.data
        return
    if on_metadata is None:
        for channel, message in scan_messages(path, topics, scan_result):
            yield channel.topic, channel.message_encoding, message.log_time, message.data
        return
    for kind, item in scan(path, scan_result):
        if kind == "metadata":
            on_metadata(item.name, dict(item.metadata))  # type: ignore[attr-defined]  # a 'metadata' item is a Metadata record
        elif kind == "message":
            channel, message = item  # type: ignore[misc]  # a 'message' item is (Channel, Message)
            if channel.topic in topics:
                yield channel.topic, channel.message_encoding, message.log_time, message.data


def iter_topic(
    path: str | Path, topics: tuple[str, ...], scan_result: ScanResult | None = None
) -> Iterator[tuple[str, int, dict[str, Any]]]:
    """(topic, log_time_ns, decoded JSON) in the order the messages were written. Batches (/can/raw, /wpt/count)
    come one dict per frame or sample, with the keys of the old per-frame JSON and the frame's time as log time.

    A log that was not finished is read up to its last complete chunk; scan_result (if given) then tells how far."""
    for topic, encoding, log_time, data in iter_messages(path, topics, scan_result):
        if encoding != cdr.ENCODING:
            yield topic, log_time, json.loads(data)
        elif topic == TOPIC_CAN:
            for f in cdr.decode_can_batch(data)[1].frames():
                yield topic, log_time_ns(f.timestamp_s), can_frame_to_dict(f)
        elif topic == TOPIC_WPT:
            for s in cdr.decode_wheel_batch(data)[1].samples(WHEELS):
                yield topic, log_time_ns(s.timestamp_s), wheel_sample_to_dict(s)


def iter_raw_batches(
    path: str | Path, scan_result: ScanResult | None = None
) -> Iterator[CanFrameBatch | NmeaLine | UbxFrame]:
    """The raw records in the order the pipeline processed them when recording, CAN frames as batches: the logged
    batches as they are, or (a log from before the batches) runs of up to MAX_BATCH_FRAMES per-frame messages."""
    run: list[CanFrame] = []
    channels: list[tuple[str | None, ...]] = [(None,)]

    def on_metadata(name: str, metadata: dict[str, str]) -> None:
        if name == METADATA_NAME:
            channels[0] = can_channels(metadata)

    for topic, encoding, _t, data in iter_messages(path, RAW_TOPICS, scan_result, on_metadata):
        if topic == TOPIC_CAN:
            if encoding == cdr.ENCODING:
                if run:
                    yield CanFrameBatch.from_frames(run)
                    run = []
                yield cdr.decode_can_batch(data, channels[0])[1]
            else:
                run.append(can_frame_from_dict(json.loads(data)))
                if len(run) >= MAX_BATCH_FRAMES:
                    yield CanFrameBatch.from_frames(run)
                    run = []
            continue
        if run:
            yield CanFrameBatch.from_frames(run)
            run = []
        d = json.loads(data)
        if topic == TOPIC_UBX:
            yield UbxFrame(d["timestamp_s"], bytes.fromhex(d["data"]))
        else:
            yield NmeaLine(d["timestamp_s"], d["line"])
    if run:
        yield CanFrameBatch.from_frames(run)


def iter_raw_records(path: str | Path, scan_result: ScanResult | None = None) -> Iterator[RawRecord]:
    """The raw CAN frames and NMEA lines in the order the pipeline processed them when recording, one by one."""
    for item in iter_raw_batches(path, scan_result):
        if isinstance(item, CanFrameBatch):
            yield from item.frames()
        else:
            yield item


def iter_fast_slip(path: str | Path, scan_result: ScanResult | None = None) -> Iterator[dict[str, Any]]:
    """The /slip/fast rows (FAST_SLIP_COLUMNS) in log order."""
    for _topic, _t, d in iter_topic(path, (TOPIC_FAST_SLIP,), scan_result):
        yield d


def iter_sensors(path: str | Path, scan_result: ScanResult | None = None) -> Iterator[dict[str, Any]]:
    """The /can/sensors samples (records.SensorSample's fields) in log order."""
    for _topic, _t, d in iter_topic(path, (TOPIC_SENSORS,), scan_result):
        yield d


def iter_estimates(path: str | Path, scan_result: ScanResult | None = None) -> Iterator[dict[str, Any]]:
    for _topic, _t, d in iter_topic(path, (TOPIC_ESTIMATE,), scan_result):
        yield d


def raw_record_count(path: str | Path) -> int | None:
    """Number of raw CAN and NMEA messages (a batch is one), from the file's summary (None when it has none)."""
    with _open(path) as f:
        try:
            summary = make_reader(f).get_summary()
        except Exception:
            return None
    if summary is None or summary.statistics is None:
        return None
    ids = [c.id for c in summary.channels.values() if c.topic in RAW_TOPICS]
    return sum(summary.statistics.channel_message_counts.get(i, 0) for i in ids)
