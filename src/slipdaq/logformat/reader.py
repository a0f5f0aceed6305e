"""Read a slipdaq MCAP log back: its config, its metadata and its raw records in recorded order.

Every log is read record by record (logformat.salvage.scan: each record parsed with mcap's StreamReader, each
chunk checked against its CRC), in the order it was written: a finished log to its data end, a log that was never
finished (the daemon was killed, or lost power) up to its last complete chunk; pass a ScanResult to learn how far
that got. Its metadata and summary are read with the standard MCAP reader. Damage inside a log (a chunk that fails
its CRC, bytes that are no record) is never read past silently: the reader raises DamageError (a LogError) naming
the damaged byte ranges, and the torn tail too when there is one, and the `slipdaq recover` command that writes
everything else.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

from mcap.reader import make_reader

from slipdaq import WHEELS
from slipdaq.config import Config, parse_logged_config
from slipdaq.logformat import cdr
from slipdaq.logformat.errors import LogError
from slipdaq.logformat.json_codec import (
    can_frame_from_dict,
    can_frame_to_dict,
    loads,
    rows_of_columns,
    wheel_sample_to_dict,
)
from slipdaq.logformat.salvage import DamageError, ScanResult, scan, scan_metadata, summary_intact
from slipdaq.logformat.topics import (
    MAX_BATCH_FRAMES,
    METADATA_NAME,
    RAW_TOPICS,
    TOPIC_CAN,
    TOPIC_ESTIMATE,
    TOPIC_FAST_SLIP,
    TOPIC_IMU_RAW,
    TOPIC_RTCM,
    TOPIC_SENSORS,
    TOPIC_UBX,
    TOPIC_WPT,
    log_time_ns,
)
from slipdaq.records import CanFrame, CanFrameBatch, NmeaLine, RawRecord, RtcmFrame, UbxFrame, XbusBytes

__all__ = ["DamageError", "LogError", "ScanResult", "can_channels", "config_from_log", "data_bytes", "is_finished",
           "iter_estimates", "iter_raw_batches", "iter_raw_messages", "iter_raw_records", "iter_topic", "raw_batches",
           "raw_record_count", "read_metadata"]


def _open(path: str | Path):
    try:
        return open(path, "rb")
    except OSError as e:
        raise LogError(f"{path}: cannot read: {e.strerror}") from None


def is_finished(path: str | Path) -> bool:
    """True when the file has a footer pointing to its summary, and the summary checks out against its CRC: closed
    properly, readable by index."""
    with _open(path) as f:
        try:
            summary = make_reader(f).get_summary()
        except Exception:  # no footer at the end (torn), or not MCAP at all
            return False
        return summary is not None and bool(summary.chunk_indexes) and summary_intact(f)


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


def can_channels(metadata: dict[str, str], source: str | Path = "<metadata>") -> tuple[str | None, ...]:
    """The CAN channel names a log's /can/raw frames index (its can_channels; a log from before it: one, unnamed).
    LogError when it is not a JSON list of names (metadata records carry no CRC: a flipped bit stays)."""
    text = metadata.get("can_channels")
    if text is None:
        return (None,)
    try:
        names = json.loads(text)
    except ValueError:
        names = None
    if not isinstance(names, list) or not all(n is None or isinstance(n, str) for n in names):
        raise LogError(f"{source}: its metadata's can_channels is not a list of CAN channel names: {text[:60]!r}")
    return tuple(names)


def config_from_log(path: str | Path) -> Config:
    """The config stored in the log (with its DBC text), so that replay needs no other input (parse_logged_config)."""
    meta = read_metadata(path)
    source = meta.get("config_path") or None
    return parse_logged_config(meta.get("config_toml", ""), Path(source) if source else None, dbc_text=meta.get("dbc"))


def _indexed_metadata(path: str | Path) -> list[tuple[str, dict[str, str]]] | None:
    """The metadata records of a finished log through its summary's index (None when it has none that reads)."""
    if not is_finished(path):
        return None
    try:
        with _open(path) as f:
            return [(m.name, dict(m.metadata)) for m in make_reader(f).iter_metadata()]
    except Exception:  # a damaged metadata record: the scan finds it
        return None


def iter_messages(
    path: str | Path, topics: tuple[str, ...], scan_result: ScanResult | None = None,
    on_metadata: Callable[[str, dict[str, str]], None] | None = None,
) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, message encoding, log_time_ns, data) in the order the messages were written.

    Every log is read record by record (salvage.scan), each chunk checked against its CRC: a finished log to its
    data end, a log that was not finished up to its last complete chunk (scan_result, if given, then tells how far).
    Damage before data that is whole raises DamageError, once the rest of the file is scanned, naming every damaged
    byte range (and the torn tail). on_metadata(name, metadata) gets each metadata record before the messages
    written after it (a finished log's: all of them first, through its index)."""
    indexed = _indexed_metadata(path) if on_metadata is not None else None
    if on_metadata is not None and indexed is not None:
        for name, metadata in indexed:
            on_metadata(name, metadata)
    for kind, item in scan(path, scan_result, topics=topics):
        if kind == "metadata":
            if on_metadata is not None and indexed is None:
                on_metadata(item.name, dict(item.metadata))
        elif kind == "message":
            channel, message = item
            if channel.topic in topics:
                yield channel.topic, channel.message_encoding, message.log_time, message.data


def iter_topic(
    path: str | Path, topics: tuple[str, ...], scan_result: ScanResult | None = None
) -> Iterator[tuple[str, int, dict[str, Any]]]:
    """(topic, log_time_ns, decoded JSON) in the order the messages were written. Batches (/can/raw, /wpt/count)
    come one dict per frame or sample, with the keys of the old per-frame JSON and the frame's time as log time;
    /slip/fast one dict per row (a message of rows, or an older log's message per row), at its message's log time.

    A log that was not finished is read up to its last complete chunk; scan_result (if given) then tells how far."""
    for topic, encoding, log_time, data in iter_messages(path, topics, scan_result):
        if encoding != cdr.ENCODING:
            d = loads(data)
            if topic == TOPIC_FAST_SLIP and isinstance(d.get("time_s"), list):  # a message of rows (columns)
                for row in rows_of_columns(d):
                    yield topic, log_time, row
            else:
                yield topic, log_time, d
        elif topic == TOPIC_CAN:
            for f in cdr.decode_can_batch(data)[1].frames():
                yield topic, log_time_ns(f.timestamp_s), can_frame_to_dict(f)
        elif topic == TOPIC_WPT:
            for s in cdr.decode_wheel_batch(data)[1].samples(WHEELS):
                yield topic, log_time_ns(s.timestamp_s), wheel_sample_to_dict(s)


RawMessage = tuple[tuple[str | None, ...], str, str, bytes]
"""A raw topic's message as a replay reads it: (the log's CAN channel names, topic, message encoding, data)."""
RawItem = CanFrameBatch | NmeaLine | UbxFrame | XbusBytes | RtcmFrame


def iter_raw_messages(path: str | Path, scan_result: ScanResult | None = None) -> Iterator[RawMessage]:
    """The raw topics' messages in the order they were written, each with the CAN channel names of the log's
    metadata (iter_messages: checked as it reads them)."""
    channels: list[tuple[str | None, ...]] = [(None,)]

    def on_metadata(name: str, metadata: dict[str, str]) -> None:
        if name == METADATA_NAME:
            channels[0] = can_channels(metadata, path)

    for topic, encoding, _t, data in iter_messages(path, RAW_TOPICS, scan_result, on_metadata):
        yield channels[0], topic, encoding, data


def raw_batches(messages: Iterable[RawMessage]) -> Iterator[RawItem]:
    """The raw records of raw messages (iter_raw_messages), CAN frames as batches: the logged batches as they are,
    or (a log from before the batches) runs of up to MAX_BATCH_FRAMES per-frame messages."""
    run: list[CanFrame] = []
    for channels, topic, encoding, data in messages:
        if topic == TOPIC_CAN:
            if encoding == cdr.ENCODING:
                if run:
                    yield CanFrameBatch.from_frames(run)
                    run = []
                yield cdr.decode_can_batch(data, channels)[1]
            else:
                run.append(can_frame_from_dict(loads(data)))
                if len(run) >= MAX_BATCH_FRAMES:
                    yield CanFrameBatch.from_frames(run)
                    run = []
            continue
        if run:
            yield CanFrameBatch.from_frames(run)
            run = []
        d = loads(data)
        if topic == TOPIC_UBX:
            yield UbxFrame(d["timestamp_s"], bytes.fromhex(d["data"]))
        elif topic == TOPIC_IMU_RAW:
            yield XbusBytes(d["timestamp_s"], bytes.fromhex(d["data"]))
        elif topic == TOPIC_RTCM:
            yield RtcmFrame(d["timestamp_s"], bytes.fromhex(d["data"]))
        else:
            yield NmeaLine(d["timestamp_s"], d["line"])
    if run:
        yield CanFrameBatch.from_frames(run)


def iter_raw_batches(path: str | Path, scan_result: ScanResult | None = None) -> Iterator[RawItem]:
    """The raw records in the order the pipeline processed them when recording (raw_batches of
    iter_raw_messages)."""
    yield from raw_batches(iter_raw_messages(path, scan_result))


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


def _summary(path: str | Path) -> Any:
    """The file's summary (mcap's Summary), None when it has none or it does not read."""
    with _open(path) as f:
        try:
            return make_reader(f).get_summary()
        except Exception:
            return None


def raw_record_count(path: str | Path) -> int | None:
    """Number of raw CAN and NMEA messages (a batch is one), from the file's summary (None when it has none)."""
    summary = _summary(path)
    if summary is None or summary.statistics is None:
        return None
    ids = [c.id for c in summary.channels.values() if c.topic in RAW_TOPICS]
    return sum(summary.statistics.channel_message_counts.get(i, 0) for i in ids)


def data_bytes(path: str | Path) -> int | None:
    """The messages' records' size uncompressed, every topic, from the file's chunk indexes (None without a summary,
    or with messages outside any indexed chunk)."""
    summary = _summary(path)
    if summary is None or (not summary.chunk_indexes and (summary.statistics is None or
                                                           summary.statistics.message_count)):
        return None
    return sum(c.uncompressed_size for c in summary.chunk_indexes)
