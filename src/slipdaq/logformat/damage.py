"""Damage inside an MCAP log, record by record: one record parsed and checked, resynchronisation after bytes that are
no record, and what a damaged byte range held (its messages by topic, its log time) as far as the file says.

A record is parsed with the mcap library's StreamReader over its own bytes only (its length from its 9-byte
header), so a damaged length never reads into the records after it; a chunk is checked by its CRC (and
decompressed) with mcap's get_chunk_data_stream, its records read by logformat.chunk_read. Every other record must
also write back to the same bytes (mcap.records' write()): a misparse, as a chunk whose opcode byte was flipped into
a data-end or index record's, then fails instead of hiding what follows. Where a record's header itself is damaged,
reading goes on at the next offset where a whole record parses, checks out and is followed by another record's
header (resync()). The file is read with pread, never mapped.
"""

from __future__ import annotations

import io
import os
import re
import struct
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass, field
from typing import Any

import zstandard
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Message, MessageIndex, Schema
from mcap.stream_reader import CRCValidationError, StreamReader

from slipdaq.logformat.chunk_read import chunk_messages

MAGIC = b"\x89MCAP0\r\n"
KNOWN_OPCODES = frozenset(int(o) for o in Opcode)
MAX_RECORD = 1 << 31
"""A record longer than this (2 GiB) is garbage, not data: slipdaq's chunks are about a megabyte."""
MAX_CHUNK = 1 << 28
"""A chunk that says it holds more than this (256 MiB) uncompressed is damaged (slipdaq's hold about 1 MiB)."""
NO_MESSAGES = frozenset({Opcode.HEADER, Opcode.FOOTER, Opcode.MESSAGE_INDEX, Opcode.CHUNK_INDEX,
                         Opcode.ATTACHMENT_INDEX, Opcode.STATISTICS, Opcode.METADATA_INDEX, Opcode.SUMMARY_OFFSET,
                         Opcode.DATA_END})
"""Records that hold no message: losing one loses nothing (the output's indexes are written anew)."""
_HEAD = struct.Struct("<BQ")
_INDEX_HEAD = struct.Struct("<HI")
_CANDIDATE = re.compile(rb"(?=[\x01-\x0f][\x00-\xff]{4}\x00\x00\x00\x00)", re.DOTALL)
"""Where a record may start: a known opcode, then a length under 4 GiB (its high four bytes zero)."""

_WINDOW = 1 << 20


class FileBytes:
    """A file's bytes, read on demand (pread): `buf[a:b]` and `buf[i]` as on bytes, shorter at the end of the file.
    Not an mmap: a file cut shorter while it is read (a live log's writer after a failed write) must not crash the
    reader (SIGBUS)."""

    def __init__(self, fd: int, size: int) -> None:
        self.fd, self.size = fd, size

    def __getitem__(self, key: int | slice) -> Any:
        if isinstance(key, slice):
            start, stop = max(key.start or 0, 0), self.size if key.stop is None else min(key.stop, self.size)
            return os.pread(self.fd, stop - start, start) if stop > start else b""
        b = os.pread(self.fd, 1, key) if 0 <= key < self.size else b""
        if not b:
            raise IndexError(key)
        return b[0]


Buffer = FileBytes | bytes
"""The file's bytes."""


class BadRecord(Exception):
    """The record at `pos` is not whole and valid. `opcode`: its header's opcode when that is a known one; `end`: where
    it ends by its header's length when that is inside the file; `chunk`: the chunk record when only its content
    failed (CRC, decompression, records)."""

    def __init__(self, pos: int, why: str, opcode: int | None = None, end: int | None = None,
                 chunk: Chunk | None = None) -> None:
        super().__init__(why)
        self.pos, self.why, self.opcode, self.end, self.chunk = pos, why, opcode, end, chunk


def _name(opcode: int) -> str:
    return Opcode(opcode).name.lower().replace("_", " ")


def parse_record(buf: Buffer, pos: int, size: int, *, index_entries: bool = True) -> tuple[Any, int]:
    """The record at `pos` (an mcap.records record) and the offset where it ends. Chunks come as Chunk records, their
    content unchecked (chunk_records() checks it); a message index without its entries unless `index_entries` (its
    layout is checked: they fill it exactly). Raises BadRecord."""
    head = buf[pos:pos + 9]
    if len(head) < 9:
        raise BadRecord(pos, "the file ends inside a record's header")
    opcode, length = _HEAD.unpack(head)
    if opcode not in KNOWN_OPCODES:
        raise BadRecord(pos, f"no valid record (opcode {opcode:#04x})")
    what = f"a {_name(opcode)} record"
    if length > MAX_RECORD:
        raise BadRecord(pos, f"{what} claims {length} bytes", opcode)
    end = pos + 9 + length
    if end > size:
        raise BadRecord(pos, f"{what} ({length} bytes) is cut short by the end of the file ({size} bytes)", opcode)
    if opcode == Opcode.MESSAGE_INDEX and not index_entries:
        channel_id, entries = _INDEX_HEAD.unpack(buf[pos + 9:pos + 15]) if length >= 6 else (0, -1)
        if entries != length - 6 or entries % 16:
            raise BadRecord(pos, f"{what} does not parse: its entries do not fill it exactly", opcode, end)
        return MessageIndex(channel_id=channel_id, records=[]), end
    data = buf[pos:end]
    try:
        record = next(iter(StreamReader(io.BytesIO(data), skip_magic=True, emit_chunks=True,
                                        record_size_limit=MAX_RECORD).records))
        if opcode != Opcode.CHUNK:
            out = RecordBuilder()
            record.write(out)
            if out.end() != data:
                raise ValueError("its fields do not fill it exactly")
    except Exception as e:  # any field cut short or out of range
        raise BadRecord(pos, f"{what} does not parse: {e}", opcode, end) from None
    return record, end


def chunk_records(chunk: Chunk, pos: int, end: int, topics: Collection[str] | None = None,
                  topic_of: Callable[[int], str | None] = lambda _: None) -> list[Any]:
    """The schema, channel and message records of a chunk, decompressed and checked against its CRC; with topics
    (and topic_of: a channel id's topic, None where unknown), a message of another topic as its (channel id, log
    time) (chunk_read.chunk_messages). Raises BadRecord (with the chunk's extent) when the chunk is damaged."""
    try:
        if chunk.uncompressed_size > MAX_CHUNK:
            raise ValueError(f"it claims {chunk.uncompressed_size} bytes uncompressed")
        if chunk.compression == "zstd":
            content = zstandard.frame_content_size(chunk.data)
            if content != -1 and content != chunk.uncompressed_size:
                raise ValueError(f"its zstd frame claims {content} bytes, its header {chunk.uncompressed_size}")
        elif chunk.compression not in ("", "lz4"):
            raise ValueError(f"unknown compression {chunk.compression[:20]!r}")
        return chunk_messages(chunk, topics, topic_of)
    except CRCValidationError:
        why = "fails its CRC check"
    except zstandard.ZstdError as e:
        why = f"does not decompress: {e}"
    except Exception as e:
        why = f"does not decode: {e}"
    raise BadRecord(pos, f"a chunk that {why}", Opcode.CHUNK, end, chunk)


def chunk_at(buf: Buffer, pos: int, end: int) -> tuple[Chunk, list[Any]] | None:
    """The chunk whose body is bytes pos+9 to `end` and its records, whatever its record header says (a damaged
    opcode or length), when its fields fill that exactly and its content checks out against its CRC; else None."""
    body = buf[pos + 9:end]
    try:
        chunk = Chunk.read(ReadDataStream(io.BytesIO(body)))
        out = RecordBuilder()
        chunk.write(out)
        if not chunk.uncompressed_crc or out.end()[9:] != body:
            return None
        return chunk, chunk_records(chunk, pos, end)
    except Exception:  # BadRecord, or fields cut short
        return None


def _header_follows(buf: Buffer, at: int, size: int) -> bool:
    """A record's header (a known opcode) or the closing magic starts at `at`, or the file ends there."""
    return at == size or buf[at] in KNOWN_OPCODES or buf[at:at + len(MAGIC)] == MAGIC


def valid_at(buf: Buffer, pos: int, size: int, known_channel: Callable[[int], bool]) -> bool:
    """A whole, valid record starts at `pos` (a chunk that checks out, or a record followed by a record's header;
    a message only on a channel the file defines)."""
    try:
        record, end = parse_record(buf, pos, size)
        if isinstance(record, Chunk):
            chunk_records(record, pos, end)
            if record.uncompressed_crc:
                return True
        elif isinstance(record, Message) and not known_channel(record.channel_id):
            return False
    except BadRecord:
        return False
    return _header_follows(buf, end, size)


def resync(buf: Buffer, start: int, size: int, known_channel: Callable[[int], bool]) -> int | None:
    """The first offset from `start` where a whole, valid record starts (valid_at), or None."""
    pos = start
    while pos < size:
        block = buf[pos:min(size, pos + _WINDOW + 8)]  # a window, and the 8 bytes a candidate at its end needs
        for m in _CANDIDATE.finditer(block):
            if m.start() >= _WINDOW:
                break
            if valid_at(buf, pos + m.start(), size, known_channel):
                return pos + m.start()
        pos += _WINDOW
    return None


@dataclass
class Damage:
    """A byte range of a log that could not be read: [start, end), `end` where reading resumed (the file's size for
    a torn tail)."""

    start: int
    end: int
    why: str
    opcode: int | None = None
    """The opcode its first record's header gives, when known."""
    tail: bool = False
    """Nothing valid follows it: the file is torn (cut, or zeros or garbage at its end) from `start`."""
    holds_messages: bool | None = None
    """True: a chunk, message or metadata record was in it; False: nothing lost (indexes, or a record header whose
    content was read all the same); None: unknown."""
    lost: dict[str, int] = field(default_factory=dict)
    """Messages lost by topic, from the message index (or the summary's chunk indexes)."""
    counted_by: str = ""
    first_ns: int | None = None
    last_ns: int | None = None
    time_from: str = ""
    before_ns: int | None = None
    """Log time of the last message read before it."""
    after_ns: int | None = None
    """Log time of the first message read after it."""
    header_times: tuple[int, int] | None = None
    """(message start, end time) from a damaged chunk's own header (not covered by its CRC)."""
    index_times: tuple[int, int] | None = None
    """(first, last) log time of the lost messages, from the message index."""

    @property
    def loses_data(self) -> bool:
        return self.holds_messages is not False

    @property
    def lost_messages(self) -> int | None:
        return sum(self.lost.values()) if self.counted_by else None

    def count(self, index: MessageIndex, topic: str, source: str) -> None:
        """A message index record of what it held."""
        self.holds_messages = True
        self.lost[topic] = self.lost.get(topic, 0) + len(index.records)
        times = [t for t, _ in index.records]
        if times:
            lo, hi = self.index_times or (min(times), max(times))
            self.index_times = (min(lo, *times), max(hi, *times))
        self.counted_by = source

    def settle_times(self, chunk_times: tuple[int, int] | None = None) -> None:
        """Its log-time range from the best source there is: its message index, the chunk's own header (when it lies
        between the neighbouring messages), the summary's chunk index, else the neighbouring messages."""
        lo = self.before_ns if self.before_ns is not None else -1
        hi = self.after_ns if self.after_ns is not None else 1 << 64
        if self.index_times:
            (self.first_ns, self.last_ns), self.time_from = self.index_times, "message index"
        elif self.header_times and lo <= self.header_times[0] <= self.header_times[1] <= hi:
            (self.first_ns, self.last_ns), self.time_from = self.header_times, "chunk's header"
        elif chunk_times is not None:
            (self.first_ns, self.last_ns), self.time_from = chunk_times, "summary's chunk index"
        else:
            self.first_ns, self.last_ns, self.time_from = self.before_ns, self.after_ns, "neighbouring messages"


def kind_of(e: BadRecord, next_ok: bool) -> bool | None:
    """Whether a bad record held data, from its header: a chunk, message or metadata record did; a record of
    NO_MESSAGES did not when its whole extent is known (reading resumed right after it); anything else is unknown."""
    if e.opcode in (Opcode.CHUNK, Opcode.MESSAGE, Opcode.METADATA):
        return True
    if e.opcode in NO_MESSAGES and next_ok:
        return False
    return None


def fmt_time(ns: int | None) -> str:
    import datetime as dt

    if ns is None:
        return "?"
    return f"{dt.datetime.fromtimestamp(ns / 1e9, dt.UTC):%Y-%m-%d %H:%M:%S.%f}"[:-3]


def time_text(d: Damage) -> str:
    if d.first_ns is None and d.last_ns is None:
        return "log time unknown"
    if d.time_from == "neighbouring messages":
        if d.last_ns is None:
            return f"log time after {fmt_time(d.first_ns)} UTC (the last message before it)"
        if d.first_ns is None:
            return f"log time before {fmt_time(d.last_ns)} UTC (the first message after it)"
        return f"log time between {fmt_time(d.first_ns)} and {fmt_time(d.last_ns)} UTC (the neighbouring messages)"
    return f"log time {fmt_time(d.first_ns)} to {fmt_time(d.last_ns)} UTC (from the {d.time_from})"


def lost_text(d: Damage) -> str:
    if not d.loses_data:
        return "nothing lost (no messages in it)"
    if d.opcode == Opcode.METADATA and not d.counted_by and d.holds_messages:
        return "a metadata record lost"
    if not d.counted_by:
        return "messages lost: unknown (no message index for it)"
    by_topic = ", ".join(f"{t} {n}" for t, n in sorted(d.lost.items()))
    return f"{d.lost_messages} messages lost ({by_topic}; from the {d.counted_by})"


def range_text(d: Damage) -> str:
    """'bytes A-B (why)': B is where reading resumed (the file's end for a torn tail)."""
    return f"bytes {d.start}-{d.end} ({d.why})"


def damaged_chunk_indexes(summary: Any, d: Damage) -> list[Any]:
    """The summary's chunk indexes of the chunks that overlap the range."""
    return [c for c in getattr(summary, "chunk_indexes", None) or []
            if c.chunk_start_offset < d.end and c.chunk_start_offset + c.chunk_length > d.start]


def index_records(buf: Buffer, size: int, offsets: Iterable[int]) -> list[MessageIndex]:
    """The message index records at these offsets (those that parse)."""
    out = []
    for off in offsets:
        try:
            record, _ = parse_record(buf, off, size)
        except BadRecord:
            continue
        if isinstance(record, MessageIndex):
            out.append(record)
    return out


def definitions(summary: Any) -> tuple[dict[int, Schema], dict[int, Channel]]:
    if summary is None:
        return {}, {}
    return dict(summary.schemas), dict(summary.channels)
